"""train.run.use_all_cpu_cores adds its XLA:CPU flags only where jaxlib knows them: an unknown XLA_FLAGS entry
aborts the process at backend start-up, so on an older jaxlib the flags must stay out."""

import train.run as run


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
    assert flags.startswith("--xla_force_host_platform_device_count=1 ")
    for f in run.XLA_CPU_FLAGS:
        assert f in flags.split()


def test_flags_left_out_on_an_older_jaxlib(monkeypatch):
    assert _flags_after(monkeypatch, (0, 9, 0), None) == ""
    assert _flags_after(monkeypatch, (0, 4, 30), "--xla_force_host_platform_device_count=1") == \
        "--xla_force_host_platform_device_count=1"


def test_a_user_setting_wins(monkeypatch):
    mine = "--xla_cpu_experimental_ynn_fusion_type="
    assert _flags_after(monkeypatch, (0, 11, 2), mine) == mine


def test_jaxlib_version_is_parsed():
    v = run._jaxlib_version()
    assert len(v) == 3 and all(isinstance(x, int) for x in v)
