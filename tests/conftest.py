import gc
import os
import shutil
import sys
import tempfile

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=1")

# One persistent compilation cache for the whole test session, shared by the xdist workers and by the training
# commands that tests start in subprocesses (they inherit the environment): the suite clears jit caches after each
# module, and many programs (the same small trainers and environments) recur across modules. The controller, which
# imports this file before it starts any worker, makes the folder; a folder the user set is used as it is.
_OWN_CACHE = None
if "JAX_COMPILATION_CACHE_DIR" not in os.environ and "PYTEST_XDIST_WORKER" not in os.environ:
    _OWN_CACHE = tempfile.mkdtemp(prefix="jaxsmarl-test-jit-cache-")
    os.environ["JAX_COMPILATION_CACHE_DIR"] = _OWN_CACHE
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.2")

import jax  # noqa: E402
import pytest  # noqa: E402

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


def _driver_class_constants() -> dict:
    """highway-env's upper-case class constants of its vehicle classes (imported here if a test has not yet: a
    test that imports highway-env first must be compared with the constants as defined, not with none)."""
    try:
        from highway_env.vehicle import behavior
    except ImportError:  # highway-env is a test dependency; without it no test can change its classes
        return {}
    return {(cls.__name__, name): value for cls in (behavior.IDMVehicle, behavior.LinearVehicle)
            for name, value in vars(cls).items() if name.isupper()}


@pytest.fixture(autouse=True)
def _highway_env_class_constants_unchanged():
    """Fail the test that leaves highway-env's driver constants changed, and put them back.

    highway-env's intersection sets IDM constants on the class at each reset; a test that runs it without
    restoring them changes how every later highway-env oracle drives in the same worker process.
    """
    before = _driver_class_constants()
    yield
    after = _driver_class_constants()
    changed = sorted(k for k in set(before) | set(after) if repr(before.get(k)) != repr(after.get(k)))
    if changed:
        behavior = sys.modules["highway_env.vehicle.behavior"]
        for cls_name, name in changed:
            cls = getattr(behavior, cls_name)
            if (cls_name, name) in before:
                setattr(cls, name, before[(cls_name, name)])
            else:
                delattr(cls, name)
        pytest.fail(f"the test changed highway-env's class constants {changed}; restore them (restored now)")


def pytest_unconfigure(config):
    if _OWN_CACHE and "PYTEST_XDIST_WORKER" not in os.environ:
        shutil.rmtree(_OWN_CACHE, ignore_errors=True)

