"""Statistics of runs: intervals over seeds, running means, the averages the tables report.

Plain numpy/scipy on numbers and metrics rows (``metrics.jsonl`` objects); no figures, no files.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy import stats


def mean_ci95(x: np.ndarray) -> tuple[float, float]:
    """Mean and half-width of the 95% t-interval (0 half-width for a single value)."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return float("nan"), float("nan")
    if x.size == 1:
        return float(x[0]), 0.0
    return float(x.mean()), float(stats.t.ppf(0.975, x.size - 1) * x.std(ddof=1) / np.sqrt(x.size))


def diff_ci95(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """``mean(b) - mean(a)`` and the half-width of its 95% Welch interval (unequal variances,
    Welch-Satterthwaite degrees of freedom); NaN when either sample has fewer than 2 finite values."""
    a, b = (np.asarray(x, float) for x in (a, b))
    a, b = a[np.isfinite(a)], b[np.isfinite(b)]
    if a.size < 2 or b.size < 2:
        return float("nan"), float("nan")
    va, vb = a.var(ddof=1) / a.size, b.var(ddof=1) / b.size
    se2 = va + vb
    if se2 == 0:
        return float(b.mean() - a.mean()), 0.0
    dof = se2**2 / (va**2 / (a.size - 1) + vb**2 / (b.size - 1))
    return float(b.mean() - a.mean()), float(stats.t.ppf(0.975, dof) * np.sqrt(se2))


def contrast_ci95(samples: Sequence[np.ndarray], weights: Sequence[float]) -> tuple[float, float]:
    """``sum_i w_i mean(samples_i)`` and the half-width of its 95% interval for independent samples of
    unequal variances: standard error ``sqrt(sum_i w_i^2 s_i^2 / n_i)``, degrees of freedom by
    Welch-Satterthwaite, ``(sum_i v_i)^2 / sum_i v_i^2 / (n_i - 1)`` with ``v_i = w_i^2 s_i^2 / n_i``.
    With weights (-1, +1) it is :func:`diff_ci95`; with (+1, -1, -1, +1) over (a at δ1, a at δ2, b at
    δ1, b at δ2) it is the interaction: how much more ``a`` changes from δ2 to δ1 than ``b`` does.
    NaN when a sample has fewer than 2 finite values."""
    xs = [np.asarray(x, float) for x in samples]
    xs = [x[np.isfinite(x)] for x in xs]
    if len(xs) != len(weights) or any(x.size < 2 for x in xs):
        return float("nan"), float("nan")
    est = float(sum(w * x.mean() for w, x in zip(weights, xs)))
    v = np.array([w * w * x.var(ddof=1) / x.size for w, x in zip(weights, xs)])
    se2 = float(v.sum())
    if se2 == 0:
        return est, 0.0
    dof = se2**2 / float(sum(vi**2 / (x.size - 1) for vi, x in zip(v, xs)))
    return est, float(stats.t.ppf(0.975, dof) * np.sqrt(se2))


def smooth(y: np.ndarray, k: int = 5) -> np.ndarray:
    """Trailing running mean over up to ``k`` points (the first points use what exists)."""
    c = np.cumsum(np.insert(np.asarray(y, float), 0, 0.0))
    i = np.arange(1, len(y) + 1)
    lo = np.maximum(i - k, 0)
    return (c[i] - c[lo]) / (i - lo)


def final_avg(rows: list[dict], key: str) -> float:
    """Mean of ``key`` over the last tenth (at least one) of the chunks."""
    if not rows:
        return float("nan")
    k = max(1, len(rows) // 10)
    return float(np.mean([r[key] for r in rows[-k:]]))


def at_milestone(rows: list[dict], m: int) -> float | None:
    """Mean avg_reward of the chunks whose trial count lies in (0.9 m, m] (the last tenth before the
    milestone m); None when the run has not reached m trials."""
    if not rows or rows[-1]["trials"] < m:
        return None
    sel = [r["avg_reward"] for r in rows if 0.9 * m < r["trials"] <= m]
    if not sel:  # a chunk longer than a tenth of m: the last chunk at or before m
        before = [r for r in rows if r["trials"] <= m]
        sel = [before[-1]["avg_reward"]] if before else []
    return float(np.mean(sel)) if sel else None


def largest_fall(rows: list[dict], *, from_trials: int = 10_000, k: int = 5) -> dict | None:
    """The deepest fall of a learning curve below its running peak: on the ``k``-chunk trailing mean
    of ``avg_reward`` (:func:`smooth`), over the chunks with at least ``from_trials`` trials (the
    early curve, before a gait, is left out), the largest ``peak so far - value``. Returns the fall,
    its share of the peak (None for a peak <= 0), the peak and the trough with their trial counts,
    and the curve's end value; None without chunks from ``from_trials`` on. A collapse is a fall that
    does not come back; a dip is one that does (compare ``end`` with ``peak``)."""
    if not rows:
        return None
    y = smooth(np.array([r["avg_reward"] for r in rows], float), k)
    trials = np.array([r["trials"] for r in rows])
    idx = np.flatnonzero(trials >= from_trials)
    if idx.size == 0:
        return None
    y, trials = y[idx], trials[idx]
    peak = np.maximum.accumulate(y)
    i = int(np.argmax(peak - y))
    j = int(np.argmax(y[: i + 1]))  # where that peak was reached (first time)
    fall = float(peak[i] - y[i])
    return {"fall": fall, "share": fall / float(peak[i]) if peak[i] > 0 else None,
            "peak": float(peak[i]), "peak_trials": int(trials[j]),
            "trough": float(y[i]), "trough_trials": int(trials[i]), "end": float(y[-1])}
