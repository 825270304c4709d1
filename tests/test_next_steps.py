"""The closing message of ``python -m train``: the run folder's files and next commands that the real command-line
parsers accept and that point at that folder."""

import os
import shlex

from train import __main__ as cli
from train import experiments, render
from train.next_steps import next_steps


def _run_folder(tmp_path, name="my run"):
    out = tmp_path / name
    (out / "checkpoints" / "200").mkdir(parents=True)
    (out / "checkpoints" / "400").mkdir()
    for f in ("config.json", "episodes.csv", "summary.json", "eval.csv"):
        (out / f).write_text("x" * 10)
    return str(out)


def _commands(text):
    return [shlex.split(line.split("  # ")[0]) for line in text.splitlines() if line.startswith("  python -m ")]


def test_lists_the_files_and_commands_the_parsers_accept(tmp_path):
    out = _run_folder(tmp_path)
    text = next_steps(out, {"scenario": "racetrack", "total_steps": 1048576})  # on-policy: no replay buffer
    assert text.splitlines()[0] == f"run folder: {out}"
    for f in ("config.json", "episodes.csv", "summary.json", "eval.csv", "checkpoints/400/"):
        assert f"  {f}" in text
    assert "checkpoints/200/" not in text and "2 kept" in text  # the newest checkpoint, and how many there are
    cmds = _commands(text)
    assert [c[:3] for c in cmds] == [["python", "-m", "train.render"], ["python", "-m", "train"],
                                     ["python", "-m", "train"], ["python", "-m", "train.experiments"]]
    assert render.parse_args(cmds[0][3:]).checkpoint == out  # a path with a space survives the quoting
    ev = cli.parse_args(cmds[1][3:])
    assert ev.eval_only == out and ev.eval_episodes == 20
    res = cli.parse_args(cmds[2][3:])
    assert res.out == out and res.resume and res.steps == 2 * 1048576
    assert experiments.parse_args(cmds[3][3:]).only == ["racetrack"]


def test_off_policy_run_is_not_offered_a_longer_budget_its_buffer_would_refuse(tmp_path):
    out = _run_folder(tmp_path, "m")
    cfg = {"scenario": "merge", "total_steps": 20000, "buffer_size": 500000}  # the buffer holds 20000 slots
    res = cli.parse_args(_commands(next_steps(out, cfg))[2][3:])
    assert res.resume and res.steps is None
    cfg["buffer_size"] = 10000  # full already: a longer run keeps the same state shapes
    assert cli.parse_args(_commands(next_steps(out, cfg))[2][3:]).steps == 40000


def test_missing_files_are_not_listed(tmp_path):
    out = tmp_path / "bare"
    out.mkdir()
    (out / "config.json").write_text("{}")
    text = next_steps(str(out), {"scenario": "merge", "total_steps": 100})
    assert "config.json" in text and "episodes.csv" not in text and "checkpoints" not in text
    assert os.path.exists(out / "config.json")


def test_k_agent_highway_run_is_offered_only_what_supports_it(tmp_path):
    """A K-agent traffic task: the renderer, evaluation and resumption, and no study (none covers highway)."""
    out = _run_folder(tmp_path, "hw")
    cmds = _commands(next_steps(out, {"scenario": "highway", "total_steps": 20000, "buffer_size": 500000}))
    assert [c[:3] for c in cmds] == [["python", "-m", "train.render"]] + [["python", "-m", "train"]] * 2
    from train import render

    args = render.parse_args(cmds[0][3:])
    assert args.checkpoint == out and args.seed == 0
    assert cli.parse_args(cmds[1][3:]).eval_only == out and cli.parse_args(cmds[2][3:]).resume
    cmds = _commands(next_steps(out, {"scenario": "merge-v0", "total_steps": 20000, "buffer_size": 500000}))
    assert cmds[-1] == ["python", "-m", "train.experiments", "--study", "agents"]
