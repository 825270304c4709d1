"""train.xla_flags.use_all_cpu_cores adds its XLA:CPU flags only where jaxlib knows them: an unknown XLA_FLAGS entry
aborts the process at backend start-up, so on an older jaxlib the flags must stay out."""

import os

import train.xla_flags as run


def _flags_after(monkeypatch, version, xla_flags):
    monkeypatch.setattr(run, "_jaxlib_version", lambda: version)
    if xla_flags is None:
        monkeypatch.delenv("XLA_FLAGS", raising=False)
    else:
        monkeypatch.setenv("XLA_FLAGS", xla_flags)
    run.use_all_cpu_cores()  # the backend is already up in tests: only the environment variable changes
    import os

    return os.environ.get("XLA_FLAGS", "")


def test_flags_added_on_a_jaxlib_that_knows_them(monkeypatch):
    flags = _flags_after(monkeypatch, (0, 10, 2), "--xla_force_host_platform_device_count=1")
    assert flags.endswith(" --xla_force_host_platform_device_count=1")
    for f in run.XLA_CPU_FLAGS:
        assert f in flags.split()


def test_flags_left_out_on_an_older_jaxlib(monkeypatch):
    assert _flags_after(monkeypatch, (0, 9, 0), None) == ""
    assert _flags_after(monkeypatch, (0, 4, 30), "--xla_force_host_platform_device_count=1") == \
        "--xla_force_host_platform_device_count=1"


def test_a_user_setting_wins(monkeypatch):
    """A flag the user sets keeps the user's value; the other flags are still added."""
    for f in run.XLA_CPU_FLAGS:
        name = f.split("=")[0]
        mine = name + "=mine"
        flags = _flags_after(monkeypatch, (0, 11, 2), mine).split()
        assert [x for x in flags if x.startswith(name + "=")] == [mine]
        assert set(flags) == set(run.XLA_CPU_FLAGS) - {f} | {mine}


def test_jaxlib_version_is_parsed():
    v = run._jaxlib_version()
    assert len(v) == 3 and all(isinstance(x, int) for x in v)


def test_flags_survive_a_stray_word_in_the_users_flags():
    """XLA stops reading XLA_FLAGS at the first word that is not a "--" flag, so ours go first. Checked in a
    fresh process on the compiled program: with "-reduce" a batch-axis sum is not a YNNPACK fusion."""
    import subprocess
    import sys

    code = ("import jax, jax.numpy as jnp, train.xla_flags as run; run.use_all_cpu_cores(); "
            "t = jax.jit(lambda x: (x * x).sum(0)).lower(jnp.ones((512, 64))).compile().as_text(); "
            "print('ynn' in t, run._jaxlib_version() >= run.XLA_CPU_FLAGS_SINCE)")
    env = dict(os.environ, XLA_FLAGS="--xla_cpu_multi_thread_eigen=false stray_word", JAX_PLATFORMS="cpu")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120,
                         cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    assert out.returncode == 0, out.stderr[-2000:]
    ynn, known = out.stdout.split()
    if known == "True":
        assert ynn == "False", "the -reduce flag was dropped"
