import gc
import os

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=1")

import jax
import pytest

# Start the backend now, with the flags above: a test that runs the training command in-process would otherwise
# start it with the command's own XLA flags, and every later test in that worker would compile differently
# (the pinned bit-identical runs then differ in the last bits, depending on which tests ran first).
jax.devices()


@pytest.fixture
def x64():
    """Run a test with 64-bit floats (jit caches are keyed on the flag, so this is safe)."""
    with jax.enable_x64(True):
        yield


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drop every compiled program after each test module.

    Each XLA:CPU executable holds a few memory mappings until its jit cache entry goes. One process running the
    whole suite compiles thousands of programs, and past the kernel's mapping limit (``vm.max_map_count``, 65,530
    by default) the next compilation dies with a segmentation fault instead of an error.
    """
    yield
    jax.clear_caches()
    gc.collect()
