"""The statistics the published tables use (nmrl.analysis.stats), against scipy's own tests."""

from __future__ import annotations

import numpy as np
from scipy import stats as sps

from nmrl.analysis import stats


def test_mean_ci95_is_scipys_t_interval():
    x = np.array([4.18, 4.65, 4.18])
    m, h = stats.mean_ci95(x)
    lo, hi = sps.ttest_1samp(x, 0.0).confidence_interval(0.95)
    assert np.isclose(m, x.mean()) and np.isclose(m - h, lo) and np.isclose(m + h, hi)
    assert stats.mean_ci95(np.array([2.0])) == (2.0, 0.0)


def test_diff_ci95_is_scipys_welch_interval():
    rng = np.random.default_rng(0)
    for na, nb in ((3, 3), (3, 5), (10, 4)):
        a, b = rng.normal(4.3, 0.3, na), rng.normal(4.0, 1.2, nb)
        d, h = stats.diff_ci95(a, b)
        lo, hi = sps.ttest_ind(b, a, equal_var=False).confidence_interval(0.95)
        assert np.isclose(d, b.mean() - a.mean()) and np.isclose(d - h, lo) and np.isclose(d + h, hi)
    assert np.isnan(stats.diff_ci95(np.array([1.0]), np.array([1.0, 2.0]))[0])
    assert stats.diff_ci95(np.array([1.0, 1.0]), np.array([2.0, 2.0])) == (1.0, 0.0)


def test_at_milestone_averages_the_last_tenth_before_it():
    rows = [{"trials": t, "avg_reward": float(t) / 1000} for t in range(500, 12_001, 500)]
    # (9,000, 10,000]: 9,500 and 10,000
    assert np.isclose(stats.at_milestone(rows, 10_000), (9.5 + 10.0) / 2)
    assert stats.at_milestone(rows, 20_000) is None
