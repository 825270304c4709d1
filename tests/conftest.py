import os

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=1")

import jax
import pytest


@pytest.fixture
def x64():
    """Run a test with 64-bit floats (jit caches are keyed on the flag, so this is safe)."""
    with jax.enable_x64(True):
        yield
