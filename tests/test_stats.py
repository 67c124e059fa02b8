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


def test_largest_fall_is_the_deepest_drop_below_the_running_peak_by_brute_force():
    """Every pair (i <= j) of the smoothed curve from 10^4 trials on, by hand: the largest y[i] - y[j]
    is the fall; its peak and trough positions; the early curve (a deeper drop before 10^4 trials)
    does not count."""
    rng = np.random.default_rng(3)
    y = np.concatenate([[5.0, -3.0], np.cumsum(rng.normal(0.0, 0.5, 60)) + 2.0])
    trials = np.concatenate([[2_000, 6_000], np.linspace(10_000, 100_000, 60).astype(int)])
    rows = [{"avg_reward": float(a), "trials": int(t)} for a, t in zip(y, trials)]
    got = stats.largest_fall(rows, k=3)
    # the 3-chunk trailing mean by hand, then every pair among the chunks from 10^4 trials on
    s = np.array([np.mean(y[max(0, i - 2): i + 1]) for i in range(len(y))])[2:]
    tr = trials[2:]
    best = max(((s[i] - s[j], i, j) for i in range(len(s)) for j in range(i, len(s))), key=lambda t: t[0])
    assert np.isclose(got["fall"], best[0])
    assert got["peak_trials"] == tr[best[1]] and got["trough_trials"] == tr[best[2]]
    assert np.isclose(got["peak"], s[best[1]]) and np.isclose(got["trough"], s[best[2]])
    assert np.isclose(got["end"], s[-1]) and np.isclose(got["share"], best[0] / s[best[1]])
    # a rising curve never falls; nothing from 10^4 trials on: None
    up = [{"avg_reward": float(v), "trials": 10_000 * (v + 1)} for v in range(5)]
    assert stats.largest_fall(up)["fall"] == 0.0
    assert stats.largest_fall(rows[:2]) is None and stats.largest_fall([]) is None


def test_contrast_ci95_with_two_samples_is_scipys_welch_interval():
    rng = np.random.default_rng(1)
    a, b = rng.normal(0.0, 1.0, 4), rng.normal(1.0, 3.0, 6)
    d, h = stats.contrast_ci95([a, b], [-1.0, 1.0])
    lo, hi = sps.ttest_ind(b, a, equal_var=False).confidence_interval(0.95)
    assert np.isclose(d - h, lo) and np.isclose(d + h, hi)
    assert np.isnan(stats.contrast_ci95([a, b[:1]], [-1.0, 1.0])[0])


def test_the_interaction_interval_covers_the_true_interaction_95_percent_of_the_time():
    """Monte Carlo: four normal cells of unequal spread and 4 seeds each, the interaction
    (a1 - a2) - (b1 - b2) = 3; the Welch-Satterthwaite interval's coverage over 4,000 draws is
    0.95 within its Monte Carlo error (the approximation is slightly conservative or liberal by
    well under 2 points here)."""
    rng = np.random.default_rng(7)
    mu, sd = np.array([5.0, 1.0, 2.0, 1.0]), np.array([1.0, 3.0, 0.5, 2.0])
    w = np.array([1.0, -1.0, -1.0, 1.0])
    hits = 0
    for _ in range(4000):
        xs = [rng.normal(m, s, 4) for m, s in zip(mu, sd)]
        est, h = stats.contrast_ci95(xs, w)
        hits += abs(est - float(w @ mu)) <= h
    assert abs(hits / 4000 - 0.95) < 0.02
    # by hand: the estimate is the weighted sum of the means
    xs = [np.array([1.0, 2.0]), np.array([3.0, 5.0]), np.array([0.0, 0.0]), np.array([1.0, 1.0])]
    assert stats.contrast_ci95(xs, w)[0] == (1.5 - 4.0) - (0.0 - 1.0)
