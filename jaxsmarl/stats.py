"""Robust aggregates across training seeds: inter-quartile mean and stratified bootstrap intervals.

Follows Agarwal et al., *Deep RL at the Edge of the Statistical Precipice* (NeurIPS 2021, the ``rliable``
library): a score matrix ``[runs, tasks]`` (runs = seeds), the inter-quartile mean (IQM, the 25% trimmed mean of
all scores), and percentile confidence intervals from a *stratified* bootstrap, which resamples the runs with
replacement independently within each task (column), so every task keeps its number of runs.

Host-side numpy; NaN scores (a seed without episodes) are dropped per task before anything is computed.
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

__all__ = ["iqm", "trimmed_mean", "stratified_bootstrap", "stratified_bootstrap_ci", "iqm_ci", "as_score_matrix"]


def trimmed_mean(values, proportion: float = 0.25) -> float:
    """Mean after dropping ``floor(proportion * n)`` of the lowest and of the highest values.

    This is ``scipy.stats.trim_mean`` (what rliable uses for the IQM). NaN for no values.
    """
    if not 0.0 <= proportion < 0.5:
        raise ValueError(f"proportion must lie in [0, 0.5), got {proportion}")
    x = np.sort(np.asarray(values, np.float64).ravel())
    n = x.size
    if n == 0:
        return float("nan")
    k = int(proportion * n)
    return float(np.mean(x[k:n - k]))


def iqm(values) -> float:
    """Inter-quartile mean of all scores (any shape): the mean of the middle 50% (``trimmed_mean(x, 0.25)``)."""
    return trimmed_mean(values, 0.25)


def as_score_matrix(scores) -> list[np.ndarray]:
    """A score matrix as one finite 1-d array per task: ``[runs]`` -> one task, ``[runs, tasks]`` -> columns,
    ``{task: [runs]}`` -> one entry per task (tasks may have different numbers of runs). NaN / inf are dropped.
    """
    if isinstance(scores, dict):
        cols = [np.asarray(v, np.float64).ravel() for v in scores.values()]
    else:
        arr = np.asarray(scores, np.float64)
        if arr.ndim == 1:
            arr = arr[:, None]
        if arr.ndim != 2:
            raise ValueError(f"scores must be [runs] or [runs, tasks], got shape {arr.shape}")
        cols = [arr[:, j] for j in range(arr.shape[1])]
    return [c[np.isfinite(c)] for c in cols]


def stratified_bootstrap(scores, statistic: Callable[[np.ndarray], float] = iqm, reps: int = 5000,
                         seed: int = 0) -> np.ndarray:
    """``reps`` bootstrap replicates of ``statistic`` (applied to the concatenated resampled scores).

    Each replicate draws, for every task separately, as many runs as the task has, with replacement.
    Tasks without any finite score are ignored; with none at all the result is all NaN.
    """
    if reps < 1:
        raise ValueError(f"reps must be a positive integer, got {reps}")
    return _bootstrap([c for c in as_score_matrix(scores) if c.size], statistic, reps, seed)


def _bootstrap(cols: list[np.ndarray], statistic, reps: int, seed: int) -> np.ndarray:
    if not cols:
        return np.full(reps, np.nan)
    rng = np.random.default_rng(seed)
    samples = np.concatenate([c[rng.integers(0, c.size, (reps, c.size))] for c in cols], axis=1)  # [reps, N]
    if statistic is iqm:  # vectorised trimmed mean over the replicates
        n = samples.shape[1]
        k = int(0.25 * n)
        return np.sort(samples, axis=1)[:, k:n - k].mean(axis=1)
    if statistic is np.mean:
        return samples.mean(axis=1)
    return np.array([statistic(s) for s in samples], np.float64)


def stratified_bootstrap_ci(scores, statistic: Callable[[np.ndarray], float] = iqm, confidence: float = 0.95,
                            reps: int = 5000, seed: int = 0) -> tuple[float, float, float]:
    """``(point estimate, lower, upper)``: the statistic on all scores and its percentile bootstrap interval.

    With a single run per task the interval collapses onto the point estimate; with no scores all are NaN.
    """
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence}")
    if reps < 1:
        raise ValueError(f"reps must be a positive integer, got {reps}")
    cols = [c for c in as_score_matrix(scores) if c.size]
    if not cols:
        return float("nan"), float("nan"), float("nan")
    point = float(statistic(np.concatenate(cols)))
    boot = _bootstrap(cols, statistic, reps, seed)
    lo, hi = np.quantile(boot, [(1 - confidence) / 2, 1 - (1 - confidence) / 2])
    return point, float(lo), float(hi)


def iqm_ci(per_seed: Sequence[float], confidence: float = 0.95, reps: int = 5000,
           seed: int = 0) -> tuple[float, float, float]:
    """IQM of one value per seed with its 95% (stratified, here: one task) bootstrap interval."""
    return stratified_bootstrap_ci(np.asarray(per_seed, np.float64), iqm, confidence, reps, seed)
