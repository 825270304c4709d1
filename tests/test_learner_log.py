"""The per-chunk learner log (learner.csv): what a row holds, resume, and agreement with the training state."""

import numpy as np
import pytest

from jaxsmarl.learner_log import LearnerLog, chunk_rows
from train.config import load_config
from train.run import run


def test_chunk_rows_take_the_last_update_and_average_over_updates_only():
    # 2 seeds, 4 iterations, 2 agents; seed 1 still warms up in the first 3 iterations
    lam = np.arange(16, dtype=float).reshape(2, 4, 2)
    cost = np.arange(16, dtype=float).reshape(2, 4, 2) * 10
    updated = np.array([[True, True, True, True], [False, False, False, True]])
    rows = chunk_rows({"lam": lam, "g_actor": cost, "q_mean": cost}, 400, updated)
    by = {(r["seed"], r["agent"]): r for r in rows}
    assert set(by) == {(0, 0), (0, 1), (1, 0), (1, 1)} and all(r["env_steps"] == 400 for r in rows)
    assert by[0, 1]["lambda"] == lam[0, 3, 1] and by[0, 1]["cost_estimate"] == pytest.approx(np.mean(cost[0, :, 1]))
    assert by[1, 0]["lambda"] == lam[1, 3, 0] and by[1, 0]["cost_estimate"] == cost[1, 3, 0]
    # no update at all in a chunk: no row; a learner without a multiplier leaves the column empty
    assert chunk_rows({"g_mean": cost}, 400, np.zeros((2, 4), bool)) == []
    rows = chunk_rows({"g_mean": cost}, 400, None)
    assert all(r["lambda"] == "" for r in rows) and len(rows) == 4
    assert chunk_rows({"q_mean": cost}, 400, None) == []


def test_csv_round_trip_truncate_and_summary(tmp_path):
    log = LearnerLog()
    for step in (100, 200, 300):
        log.add([{"seed": s, "env_steps": step, "agent": i, "lambda": step * (s + 1) + i, "cost_estimate": ""}
                 for s in range(2) for i in range(2)])
    path = tmp_path / "learner.csv"
    log.write_csv(path)
    back = LearnerLog.read_csv(path)
    assert back.rows == log.rows
    assert back.summary()["lambda"][1]["per_seed"] == [301.0, 601.0] and "cost_estimate" not in back.summary()
    back.truncate(200)
    assert max(r["env_steps"] for r in back.rows) == 200


def test_multiplier_log_matches_the_state_and_survives_resume(tmp_path):
    cfg = load_config("racetrack", "cs-maddpg", dict(total_steps=600, num_seeds=2, chunk_steps=200,
                                                      checkpoint_every=200, warmup=250, batch_size=16,
                                                      buffer_size=600, eval_episodes=0, lr_lambda=0.05,
                                                      cost_threshold=[0.0, 0.0]))
    straight = run(cfg, str(tmp_path / "a"), verbose=False)
    run(cfg, str(tmp_path / "b"), verbose=False, max_chunks=2)
    resumed = run(cfg, str(tmp_path / "b"), resume=True, verbose=False)
    text_a = (tmp_path / "a" / "learner.csv").read_text()
    assert text_a == (tmp_path / "b" / "learner.csv").read_text()
    log = LearnerLog.read_csv(tmp_path / "a" / "learner.csv")
    # warm-up ends inside the second chunk: no rows for the first
    assert sorted({r["env_steps"] for r in log.rows}) == [400, 600]
    lam = np.asarray(straight["state"].agent.lam)  # [seeds, agents] after the last update
    for s in range(2):
        for i in range(2):
            row = [r for r in log.rows if r["seed"] == s and r["agent"] == i and r["env_steps"] == 600][0]
            assert row["lambda"] == pytest.approx(float(lam[s, i]), rel=1e-6)
    assert np.any(lam > 0)  # d = 0 binds, so the multipliers moved
    learner = resumed["summary"]["learner"]
    np.testing.assert_allclose([a["per_seed"] for a in learner["lambda"]], lam.T, rtol=1e-6)
