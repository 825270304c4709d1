"""The experiments driver end to end on a tiny budget: merge CSQ + SQ, 2 seeds, 300 steps; an interrupted run
resumes, finished runs are kept, figures / GIFs / RESULTS.md are produced; --only and bad options fail cleanly."""

import json
import os

import numpy as np
import pytest

pytest.importorskip("matplotlib")
pytest.importorskip("PIL")

from train import experiments, report  # noqa: E402

TINY = {"total_steps": 300, "num_seeds": 2, "chunk_steps": 100, "checkpoint_every": 100, "eval_episodes": 2,
        "warmup": 64, "batch_size": 16}
BUDGETS = {("merge", "csq"): TINY, ("merge", "sq"): TINY}


def _read(path):
    with open(path) as f:
        return json.load(f)


@pytest.mark.slow  # long: the default suite keeps its 20-minute budget (docs/performance.md)
def test_study_end_to_end_resume_and_keep(tmp_path):
    out = str(tmp_path / "study")
    # 1. an interrupted run: one chunk of three, then stop
    item = experiments.plan(["merge/csq"], budgets=BUDGETS)[0]
    st = experiments.run_one(item, out, gifs=False, verbose=False, max_chunks=1)
    assert st["status"] == "trained (interrupted)"
    csq_dir = os.path.join(out, "runs", "merge_csq")
    assert _read(os.path.join(csq_dir, "summary.json"))["finished"] is False
    # saved before a configuration key existed (leader_rule, at its default): still the same run, resumed below
    saved = _read(os.path.join(csq_dir, "config.json"))
    with open(os.path.join(csq_dir, "config.json"), "w") as f:
        json.dump({k: v for k, v in saved.items() if k != "leader_rule"}, f)

    # 2. the study resumes it from its checkpoint and trains SQ
    study = experiments.run_study(out, only=["merge"], budgets=BUDGETS, verbose=False)
    assert study["runs"]["merge_csq"]["status"] == "resumed"
    assert study["runs"]["merge_sq"]["status"] == "trained"
    for algo in ("csq", "sq"):
        summary = _read(os.path.join(out, "runs", f"merge_{algo}", "summary.json"))
        assert summary["finished"] is True and summary["config"]["total_steps"] == 300
        assert os.path.getsize(os.path.join(out, "figures", f"merge_{algo}.gif")) > 0
    with open(os.path.join(csq_dir, "episodes.csv")) as f:
        rows = f.read().splitlines()[1:]
    end_steps = [int(r.split(",")[3]) for r in rows]
    assert max(end_steps) <= 300 and len(rows) > 2 * 300 / 25  # episodes of both seeds over all 3 chunks
    for ext in ("png", "pdf"):
        assert os.path.getsize(os.path.join(out, "figures", f"merge_curves.{ext}")) > 0

    # 3. RESULTS.md: tables with IQM intervals, the authors' values, figures, GIFs, honesty and differences
    text = open(os.path.join(out, "RESULTS.md")).read()
    assert "## merge" in text and "| CSQ |" in text and "SQ (Bi-AC" in text
    assert "56.80 ± 1.33 (n=3)" in text  # the authors' merge CSQ total return (docs/results.md)
    assert "![merge training curves](figures/merge_curves.png)" in text
    assert "(figures/merge_csq.gif)" in text and "(figures/merge_sq.gif)" in text
    assert "is CSQ safer than SQ?" in text and "not comparable: much shorter training" in text
    # verdicts from a 300-step run carry a caveat; 2 seeds: the IQM is the plain mean (not "close to" it)
    assert "Caveat: trained for 300 steps per seed, 2% of the authors' 20,000" in text
    assert "Their IQM is the plain mean of the seeds" in text
    assert "Known differences between the paper and the authors' code" in text
    assert "## roundabout" not in text  # nothing ran there

    # 4. a second invocation keeps the finished runs (no retraining)
    mtime = os.path.getmtime(os.path.join(csq_dir, "episodes.csv"))
    study = experiments.run_study(out, only=["merge/csq"], budgets=BUDGETS, verbose=False)
    assert study["runs"]["merge_csq"]["status"] == "kept"
    assert os.path.getmtime(os.path.join(csq_dir, "episodes.csv")) == mtime
    # ... also when asked for another budget: kept and reported, not overwritten
    other = {("merge", "csq"): dict(TINY, total_steps=200)}
    study = experiments.run_study(out, only=["merge/csq"], budgets=other, verbose=False, gifs=False)
    assert study["runs"]["merge_csq"]["status"] == "kept (different config)"
    assert "total_steps" in study["runs"]["merge_csq"]["reason"]
    assert os.path.getmtime(os.path.join(csq_dir, "episodes.csv")) == mtime

    # 5. the report's numbers are the IQM of the per-seed last-10% means of episodes.csv
    from train.figures import load_run

    run = load_run(csq_dir)
    per_seed = report.final_per_seed(run, "total_return")
    summary = _read(os.path.join(csq_dir, "summary.json"))
    np.testing.assert_allclose(per_seed, summary["summary"]["total_return"]["last_per_seed"], rtol=1e-6)


def test_unregistered_algorithm_is_skipped(tmp_path):
    item = {"scenario": "racetrack", "algo": "no-such-algo", "overrides": {"num_seeds": 2}, "extra": {}}
    st = experiments.run_one(item, str(tmp_path), verbose=False)
    assert st["status"] == "skipped" and "not registered" in st["reason"]
    assert not os.path.exists(tmp_path / "runs" / "racetrack_no-such-algo")


def test_plan_budgets_and_only():
    full = experiments.plan()
    assert [(i["scenario"], i["algo"]) for i in full] == [(s, a) for s, al in experiments.STUDY.items() for a in al]
    assert all(i["overrides"]["num_seeds"] == experiments.DEFAULT_SEEDS for i in full)
    quick = {(i["scenario"], i["algo"]): i["overrides"] for i in experiments.plan(quick=True)}
    assert set(quick) == set(experiments.QUICK)
    assert quick[("merge", "csq")]["total_steps"] == experiments.QUICK[("merge", "csq")]["total_steps"]
    sel = experiments.plan(["racetrack/macpo,merge"], seeds=3, steps=500)
    assert [(i["scenario"], i["algo"]) for i in sel] == [("merge", "csq"), ("merge", "sq"), ("racetrack", "macpo")]
    assert all(i["overrides"]["num_seeds"] == 3 and i["overrides"]["total_steps"] == 500 for i in sel)
    with pytest.raises(ValueError, match="unknown scenario 'highway'"):
        experiments.parse_only(["highway"])
    with pytest.raises(ValueError, match="runs merge with csq, sq, not 'macpo'"):
        experiments.parse_only(["merge/macpo"])
    with pytest.raises(ValueError, match="--seeds must be a positive integer"):
        experiments.plan(seeds=0)


def test_cli_rejects_bad_options(capsys, tmp_path):
    assert experiments.main(["--only", "highway", "--out", str(tmp_path)]) == 2
    assert "error: --only 'highway'" in capsys.readouterr().err
    assert experiments.main(["--only", "merge", "--set", "no_such_key=1", "--out", str(tmp_path)]) == 2
    assert "no selected (registered) algorithm has this key" in capsys.readouterr().err
    assert experiments.main(["--only", "merge", "--set", "gamma=2", "--out", str(tmp_path)]) == 2
    assert "'gamma'" in capsys.readouterr().err
    assert not os.path.exists(tmp_path / "runs")


def test_evaluation_stops_at_the_time_limit_with_the_same_records():
    """The greedy evaluation scans only up to the env's time limit (merge: 20 decisions, not eval_max_steps=200);
    each record must equal the first episode of an eager step-by-step roll-out with the same keys."""
    import jax
    import jax.numpy as jnp

    from jaxsmarl import metrics
    from train.trainer import episode_step_limit, make_env, make_evaluate

    env, wrapped, params = make_env("merge")
    limit = episode_step_limit(env, params)
    assert limit == 20  # 20 s at 1 decision per second

    def act(agent_state, obs):  # a deterministic, observation-dependent policy (agent_state: an offset)
        return (jnp.floor(jnp.abs(obs).sum(-1) * 7.0 + agent_state) % env.num_actions).astype(jnp.int32)

    evaluate = make_evaluate(wrapped, params, act, episodes=3, max_steps=200)
    assert "length=20" in str(jax.make_jaxpr(evaluate)(jnp.float32(0.0), jax.random.PRNGKey(0)))
    key = jax.random.PRNGKey(7)
    step = jax.jit(wrapped.step)
    for offset in (0.0, 2.0):
        rec = jax.device_get(evaluate(jnp.float32(offset), key))
        for e, k in enumerate(jax.random.split(key, 3)):
            k_reset, k_run = jax.random.split(k)
            obs, st = wrapped.reset(k_reset, params)
            for t, kk in enumerate(jax.random.split(k_run, 200)):
                obs, st, _, _, _, info = step(kk, st, act(jnp.float32(offset), obs), params)
                truth = metrics.episode_record(info)
                if bool(truth["returned"]):
                    break
            assert t < limit and bool(rec["returned"][e])
            for f in metrics.EPISODE_FIELDS:
                np.testing.assert_allclose(rec[f][e], np.asarray(truth[f]), rtol=1e-6, err_msg=f)


def test_figure_legend_has_one_authors_entry_per_algorithm(tmp_path, monkeypatch):
    """Roundabout SQ's crash rate is recorded for one of the authors' three seeds: the legend must still show one
    authors' entry per algorithm (not a second 'SQ ... 1 seeds' entry), in one column per algorithm."""
    import matplotlib.figure

    from train import figures

    rng = np.random.default_rng(0)
    n = 40
    episodes = {"seed": np.repeat([0.0, 1.0], n), "episode": np.tile(np.arange(n, dtype=float), 2),
                "end_step": np.tile(np.linspace(10, 400, n), 2)}
    for f, _ in figures.scenario_panels("roundabout"):
        episodes[f] = rng.uniform(0, 1, 2 * n)
    run = {"config": {"total_steps": 400, "num_seeds": 2}, "episodes": episodes}
    seen = {}
    original = matplotlib.figure.Figure.legend

    def spy(self, handles, labels, **kw):
        seen.update(labels=list(labels), ncol=kw.get("ncol"),
                    xscales={ax.get_xscale() for ax in self.axes if ax.get_visible()})
        return original(self, handles, labels, **kw)

    monkeypatch.setattr(matplotlib.figure.Figure, "legend", spy)
    paths = figures.plot_scenario("roundabout", {"csq": run, "sq": run}, str(tmp_path / "r"))
    assert all(os.path.getsize(p) > 0 for p in paths)
    assert seen["labels"] == ["CSQ (ours, 2 seeds)", "CSQ: authors' record, last 10% (10k steps, 3 seeds)",
                              "SQ (Bi-AC: CSQ, d=100) (ours, 2 seeds)",
                              "SQ (Bi-AC: CSQ, d=100): authors' record, last 10% (10k steps, 3 seeds)"]
    assert seen["ncol"] == 2 and seen["xscales"] == {"linear"}
    # budgets 10x apart (quick study: MADDPG 3,000 vs MAPPO-L 32,768 steps): a log axis, not a squeezed short run
    long = dict(run, config={"total_steps": 4000, "num_seeds": 2},
                episodes=dict(episodes, end_step=episodes["end_step"] * 10))
    figures.plot_scenario("roundabout", {"csq": run, "sq": long}, str(tmp_path / "r2"))
    assert seen["xscales"] == {"log"}


def test_runs_whose_envs_ran_few_episode_limits_are_flagged():
    """512 envs x 64 steps on the racetrack (episodes up to 40 s x 5 Hz = 200 decisions): only short episodes can
    finish, so the figures and the report must flag the run; one env x 2000 steps is 10 episode limits, not flagged."""
    from train import figures

    ppo = {"config": {"algo": "macpo", "num_envs": 512, "total_steps": 32768}}
    maddpg = {"config": {"algo": "cs-maddpg", "num_envs": 1, "total_steps": 2000}}
    assert figures.episode_limit("racetrack") == 200 and figures.episode_limit("merge") == 20
    assert figures.short_runs("racetrack", {"macpo": ppo, "cs-maddpg": maddpg}) == [
        "MACPO: 512 envs x 64 steps, episodes up to 200"]
    assert figures.short_runs("intersection", {"cs-maddpg": maddpg}) == []


def test_wall_time_of_a_retrained_run_does_not_add_the_previous_one():
    """study.json's wall_s adds up the invocations of a kept or resumed run; an --overwrite (trained from scratch)
    starts again from zero."""
    prev = {"wall_s": 100.0}
    assert experiments._carried_wall(prev, "trained") == 0.0
    assert experiments._carried_wall(prev, "trained (interrupted)") == 0.0
    assert experiments._carried_wall(prev, "resumed") == 100.0
    assert experiments._carried_wall(prev, "kept (different config)") == 100.0
    assert experiments._carried_wall({}, "kept") == 0.0
