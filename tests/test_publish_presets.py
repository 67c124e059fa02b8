"""nmrl.analysis.publish_presets, the fast-preset comparison's numbers, against plain Python loops
over made-up learning curves: running means, the end value, the peak, the first fall below half of
the running peak, collapse, the milestones and the mean curve over points."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nmrl.analysis import publish_presets as pp


def _rows(rewards, diverged_at=None, trials_per_chunk=50):
    return [{"trials": trials_per_chunk * (i + 1), "avg_reward": float(r), "diverged": i == diverged_at}
            for i, r in enumerate(rewards)]


def _loop_running_mean(r, w):
    return [sum(r[i - w + 1:i + 1]) / w for i in range(w - 1, len(r))]


def _loop_summary(rows):
    r = [x["avg_reward"] for x in rows]
    w = min(pp.SMOOTH, len(r))
    k = max(1, len(r) // 10)
    end = sum(r[-k:]) / k
    sm = _loop_running_mean(r, w)
    peak = max(sm)
    first, run_peak = "", -math.inf
    for j, v in enumerate(sm):
        run_peak = max(run_peak, v)
        if run_peak > 0.3 and v < 0.5 * run_peak:
            first = rows[j + w - 1]["trials"]
            break
    diverged = any(x["diverged"] for x in rows) or not all(math.isfinite(v) for v in r)
    return {"trials": rows[-1]["trials"], "avg_reward": end, "peak": peak,
            "collapsed": diverged or end < peak - 0.5 * abs(peak), "diverged": diverged,
            "first_below_half": first, "chunks": len(rows)}


CURVES = {
    "rising": np.linspace(-0.8, 2.5, 40),
    "collapse": np.r_[np.linspace(-0.5, 2.0, 25), np.linspace(2.0, -6.0, 15)],
    "dip and recovery": np.r_[np.linspace(0, 2.0, 15), [0.5] * 6, np.linspace(1.0, 2.6, 19)],
    "never above 0.3": np.linspace(-1.0, 0.2, 30),
    "short": np.array([0.1, 0.4, 0.2]),
    "noisy": np.random.default_rng(3).normal(1.0, 1.0, 60),
}


@pytest.mark.parametrize("name", sorted(CURVES))
def test_point_summary_equals_the_definitions_computed_by_loops(name):
    rows = _rows(CURVES[name])
    got, want = pp.point_summary(rows), _loop_summary(rows)
    assert got.keys() == want.keys()
    for k in want:
        assert got[k] == (pytest.approx(want[k]) if isinstance(want[k], float) else want[k]), k
    t, sm = pp.running_mean(rows)
    w = min(pp.SMOOTH, len(rows))
    assert t == [x["trials"] for x in rows][w - 1:]
    assert sm == pytest.approx(_loop_running_mean(list(CURVES[name]), w))


def test_a_divergence_or_a_non_finite_reward_is_a_collapse():
    assert pp.point_summary(_rows(CURVES["rising"], diverged_at=39))["collapsed"]
    r = CURVES["rising"].copy()
    r[-1] = np.nan
    s = pp.point_summary(_rows(r))
    assert s["diverged"] and s["collapsed"]


def test_collapse_is_the_end_more_than_half_the_peak_below_it():
    assert pp.point_summary(_rows(CURVES["collapse"]))["collapsed"]
    assert not pp.point_summary(_rows(CURVES["dip and recovery"]))["collapsed"]
    assert pp.point_summary(_rows(CURVES["dip and recovery"]))["first_below_half"] != ""


@pytest.mark.parametrize("m", [25, 50, 120, 500, 1000, 2000, 2001])
def test_at_trials_is_the_running_mean_at_the_last_chunk_not_past_m(m):
    rows = _rows(CURVES["noisy"][:40])  # trials 50 .. 2000
    got = pp.at_trials(rows, m)
    if m > 2000 or m < 50:  # not reached, or no chunk at or before m: nothing to read
        assert got is None
        return
    i = max(j for j, x in enumerate(rows) if x["trials"] <= m)
    window = [x["avg_reward"] for x in rows[max(0, i - 4):i + 1]]
    assert got == pytest.approx(sum(window) / len(window))


def test_mean_curve_averages_the_points_where_they_have_data():
    a = _rows([0.0, 1.0, 2.0], trials_per_chunk=100)  # trials 100, 200, 300
    b = _rows([4.0, 4.0], trials_per_chunk=100)  # trials 100, 200
    grid = np.array([100.0, 150.0, 250.0, 300.0, 400.0])
    got = pp.mean_curve({"a": a, "b": b}, grid)
    want = [(0.0 + 4.0) / 2, (0.5 + 4.0) / 2, 1.5, 2.0, np.nan]  # b ends at 200; nobody at 400
    assert np.allclose(got, want, equal_nan=True)
