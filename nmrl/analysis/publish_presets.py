"""The fast-preset comparison's numbers per point: the end value, the peak, collapse, the running
mean at the milestones, the mean learning curve over points (``results/fast_preset/``).

Per point (``rows`` = its ``metrics.jsonl`` rows, one per chunk, in order):

* ``avg_reward``: the mean of the chunks' average reward per control step over the last tenth of
  the chunks (as the sweep's results.csv);
* ``peak``: the maximum of the SMOOTH-chunk running mean of the average reward;
* ``collapsed``: the point diverged, or ``avg_reward`` ended more than half of |peak| below the
  peak (for peak > 0: below 50% of the peak);
* ``first_below_half``: the trials at which the running mean first fell below half of the running
  peak, once that peak exceeded 0.3 (empty if never).

scripts/publish/publish_fast_preset.py reads the points, writes the tables and draws the figure.
"""

from __future__ import annotations

import numpy as np

#: chunks in the running mean
SMOOTH = 5
#: trials at which the screening table reads each point
MILESTONES = (500, 1000, 1500, 2000, 2500, 3000, 3500)


def running_mean(rows: list[dict]) -> tuple[list, np.ndarray]:
    """(trials, the SMOOTH-chunk running mean of the average reward) of a point's chunks, the mean
    over up to SMOOTH chunks ending at each (only full windows: the first SMOOTH - 1 chunks have none)."""
    r = np.array([x["avg_reward"] for x in rows], float)
    w = min(SMOOTH, len(r))
    return [x["trials"] for x in rows][w - 1:], np.convolve(r, np.ones(w) / w, mode="valid")


def point_summary(rows: list[dict]) -> dict:
    """One point's row of results.csv (see the module docstring)."""
    r = np.array([x["avg_reward"] for x in rows], float)
    t = np.array([x["trials"] for x in rows], float)
    k = max(1, len(r) // 10)
    end = float(np.mean(r[-k:]))
    w = min(SMOOTH, len(r))
    _, sm = running_mean(rows)
    peak = float(np.max(sm))
    diverged = any(bool(x["diverged"]) for x in rows) or not np.all(np.isfinite(r))
    run_peak = np.maximum.accumulate(sm)
    below = np.where((run_peak > 0.3) & (sm < 0.5 * run_peak))[0]
    first = int(t[below[0] + w - 1]) if len(below) else ""
    return {"trials": int(t[-1]), "avg_reward": end, "peak": peak,
            "collapsed": bool(diverged or end < peak - 0.5 * abs(peak)), "diverged": bool(diverged),
            "first_below_half": first, "chunks": len(rows)}


def mean_curve(points: dict, grid: np.ndarray) -> np.ndarray:
    """Mean over the points of each point's average reward interpolated on the trial grid (NaN past
    a point's last chunk)."""
    ys = []
    for rows in points.values():
        t = np.array([x["trials"] for x in rows], float)
        r = np.array([x["avg_reward"] for x in rows], float)
        y = np.interp(grid, t, r, left=np.nan, right=np.nan)
        ys.append(y)
    if not ys:
        return np.full(grid.shape, np.nan)
    ys = np.array(ys)
    n = np.sum(~np.isnan(ys), axis=0)
    return np.where(n > 0, np.nansum(ys, axis=0) / np.maximum(n, 1), np.nan)


def at_trials(rows: list[dict], m: int) -> float | None:
    """The SMOOTH-chunk running mean of the average reward at the last chunk with <= m trials (None if
    the point has not reached m, or has no chunk at or before m)."""
    if not rows or rows[-1]["trials"] < m or rows[0]["trials"] > m:
        return None
    i = max(j for j, x in enumerate(rows) if x["trials"] <= m)
    return float(np.mean([x["avg_reward"] for x in rows[max(0, i - SMOOTH + 1):i + 1]]))
