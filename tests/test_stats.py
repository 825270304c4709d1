"""IQM and the stratified bootstrap against closed forms and exhaustive enumeration of all resamples."""

import itertools

import numpy as np
import pytest

from jaxsmarl import stats


def test_iqm_closed_forms():
    # 0..7: drop 2 lowest and 2 highest -> mean(2, 3, 4, 5) = 3.5
    assert stats.iqm(np.arange(8.0)) == 3.5
    # n = 10: floor(2.5) = 2 cut each side -> mean of the 6 middle values, order does not matter
    x = np.array([100.0, -50.0, 1, 2, 3, 4, 5, 6, 7, 8])
    assert stats.iqm(x) == pytest.approx(np.mean([2, 3, 4, 5, 6, 7]))
    # fewer than 4 values: nothing is cut
    assert stats.iqm([1.0, 5.0, 9.0]) == 5.0
    assert stats.iqm([2.0, 4.0]) == 3.0
    # any shape: all scores pooled
    assert stats.iqm(np.arange(8.0).reshape(4, 2)) == 3.5
    assert np.isnan(stats.iqm([]))
    # an outlier does not move it (unlike the mean)
    assert stats.iqm([1, 2, 3, 4, 1e9, -1e9, 2.5, 3.5]) == pytest.approx(np.mean([2, 2.5, 3, 3.5]))


def test_trimmed_mean_rejects_bad_proportion():
    with pytest.raises(ValueError, match=r"proportion must lie in \[0, 0.5\)"):
        stats.trimmed_mean([1, 2], 0.5)


def _exact_distribution(cols, statistic):
    """Every stratified resample with its probability (each task: all n^n ordered draws, equally likely)."""
    per_task = [list(itertools.product(c, repeat=len(c))) for c in cols]
    values = [statistic(np.concatenate([np.asarray(d) for d in draw])) for draw in itertools.product(*per_task)]
    return np.sort(np.asarray(values))


@pytest.mark.parametrize("statistic", [stats.iqm, np.mean, np.median])
def test_stratified_bootstrap_matches_exhaustive_enumeration(statistic):
    # Two tasks (columns) of 4 runs: 4^4 * 4^4 = 65,536 equally likely resamples, enumerated exactly.
    scores = np.array([[0.0, 10.0], [1.0, 14.0], [3.0, 11.0], [7.0, 20.0]])
    exact = _exact_distribution([scores[:, 0], scores[:, 1]], statistic)
    boot = np.sort(stats.stratified_bootstrap(scores, statistic, reps=40000, seed=1))
    # Kolmogorov distance between the Monte-Carlo and the exact distribution (40k draws: ~0.007 typical)
    grid = np.unique(exact)
    cdf_exact = np.searchsorted(exact, grid, side="right") / exact.size
    cdf_boot = np.searchsorted(boot, grid, side="right") / boot.size
    assert np.max(np.abs(cdf_exact - cdf_boot)) < 0.02
    assert boot.mean() == pytest.approx(exact.mean(), abs=0.05)


def test_stratification_keeps_runs_per_task():
    # Task A is all 0, task B all 1 with 3 and 1 runs: a stratified resample always holds 3 zeros and one 1,
    # so the mean is exactly 0.25 in every replicate (an unstratified bootstrap of the 4 pooled values is not).
    boot = stats.stratified_bootstrap({"a": [0.0, 0.0, 0.0], "b": [1.0]}, np.mean, reps=500)
    assert np.all(boot == 0.25)
    point, lo, hi = stats.stratified_bootstrap_ci({"a": [0.0, 0.0, 0.0], "b": [1.0]}, np.mean)
    assert (point, lo, hi) == (0.25, 0.25, 0.25)


def test_bootstrap_of_the_mean_has_the_plug_in_variance():
    # Closed form: the bootstrap distribution of the mean of n values has variance sigma_hat^2 / n (ddof=0).
    x = np.array([3.0, 9.0, -2.0, 4.0, 7.0, 0.5, 12.0, 1.0])
    boot = stats.stratified_bootstrap(x, np.mean, reps=200000, seed=3)
    assert boot.var() == pytest.approx(x.var() / x.size, rel=0.02)


def test_ci_contains_point_and_handles_nan_and_single_seed():
    point, lo, hi = stats.iqm_ci([1.0, 2.0, np.nan, 3.0, 4.0, 10.0])
    assert point == stats.iqm([1.0, 2.0, 3.0, 4.0, 10.0])
    assert lo <= point <= hi
    assert stats.iqm_ci([5.0]) == (5.0, 5.0, 5.0)
    assert all(np.isnan(v) for v in stats.iqm_ci([np.nan, np.nan]))
    with pytest.raises(ValueError, match="confidence"):
        stats.iqm_ci([1.0, 2.0], confidence=1.0)
    with pytest.raises(ValueError, match="scores must be"):
        stats.stratified_bootstrap(np.zeros((2, 2, 2)))
