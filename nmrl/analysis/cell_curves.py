"""A study's cells summarised: per-cell endpoint statistics and learning curves with seed bands.

A cell holds the runs of one setting over seeds (nmrl/experiments/kit.py). :func:`summary` gives
each cell's deterministic endpoint as its mean with the 95% Student-t interval over seeds (what the
Welch contrasts decide on) and, from 4 runs up, the IQM (rliable's 25% trimmed mean) with its
stratified percentile-bootstrap interval (nmrl/analysis/prereg_stats.py; it undercovers with few
runs, hence reported, not deciding). :func:`band` is a learning curve's mean over seeds with the
95% t interval at every point of the seeds' common length; :func:`figure` draws one panel per
group (e.g. per control step) with one line and band per cell (each seed's curve instead of a band
below 3 seeds), against simulated seconds per
environment (steps x control step), so that curves of different control steps share an axis.
"""

from __future__ import annotations

import os
import pathlib
from typing import Mapping, Sequence

import numpy as np

from nmrl.analysis import plots, prereg_stats
from nmrl.analysis.stats import mean_ci95

#: runs a cell needs before its IQM and bootstrap interval are reported
IQM_MIN_RUNS = 4
BOOTSTRAP_REPS = 50_000
SUMMARY_COLUMNS = ("n", "mean", "sd", "ci_lo", "ci_hi", "iqm", "iqm_lo", "iqm_hi")  #: :func:`summary`'s keys
PANELS_PER_ROW = 4
#: seeds from which a cell's curve gets its t band (fewer: each seed's curve is drawn thin)
BAND_MIN_SEEDS = 3


def summary(values: Sequence[float]) -> dict:
    """``n``, ``mean``, ``sd``, the 95% t interval ``ci_lo``/``ci_hi`` and, with at least
    :data:`IQM_MIN_RUNS` runs, ``iqm`` with its bootstrap interval ``iqm_lo``/``iqm_hi`` (50,000
    replicates, seed 0); empty strings where a statistic needs more runs."""
    x = np.asarray([v for v in values if np.isfinite(v)], float)
    out: dict = {"n": int(x.size), "mean": "", "sd": "", "ci_lo": "", "ci_hi": "", "iqm": "", "iqm_lo": "",
                 "iqm_hi": ""}
    if x.size == 0:
        return out
    out["mean"] = float(x.mean())
    if x.size >= 2:
        _, half = mean_ci95(x)
        out.update(sd=float(x.std(ddof=1)), ci_lo=out["mean"] - half, ci_hi=out["mean"] + half)
    if x.size >= IQM_MIN_RUNS:
        point, lo, hi = prereg_stats.stratified_bootstrap_ci([x], reps=BOOTSTRAP_REPS, seed=0)
        out.update(iqm=point, iqm_lo=lo, iqm_hi=hi)
    return out


def band(curves: Sequence[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(t, mean, lo, hi)`` of the seeds' curves ``(t_i, y_i)`` over their common length (the
    shortest run's points; every run's t must agree there): the mean over seeds and its 95% t
    interval (lo = hi = mean with one seed)."""
    if not curves:
        raise ValueError("no curves")
    n = min(len(t) for t, _ in curves)
    t = np.asarray(curves[0][0][:n], float)
    for ti, _ in curves:
        if not np.allclose(np.asarray(ti[:n], float), t):
            raise ValueError("the seeds' curves are not on the same time points")
    y = np.stack([np.asarray(yi[:n], float) for _, yi in curves])
    mean, half = np.array([mean_ci95(col) for col in y.T]).T  # half 0 with one seed
    return t, mean, mean - half, mean + half


def draw(ax, cells: Mapping[str, Sequence[tuple[np.ndarray, np.ndarray]]],
         colors: Mapping[str, str] | None = None) -> None:
    """One line per cell on ``ax``: the mean over the cell's seeds with its 95% t band (:func:`band`),
    each seed's curve instead of the band below :data:`BAND_MIN_SEEDS` seeds, the seeds counted in the
    legend; ``colors``: a cell's colour (default: the colour cycle's next)."""
    for label, curves in cells.items():
        t, mean, lo, hi = band(curves)
        (line,) = ax.plot(t, mean, lw=1.6, marker="o", ms=3, label=f"{label} ({len(curves)})",
                          color=(colors or {}).get(label))
        if len(curves) >= BAND_MIN_SEEDS:
            ax.fill_between(t, lo, hi, color=line.get_color(), alpha=0.2, lw=0)
        else:  # a t interval over 2 seeds is 13 SDs wide: each seed is drawn instead
            for ti, yi in curves:
                ax.plot(ti, yi, lw=0.6, alpha=0.5, color=line.get_color())
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)


def figure(panels: Mapping[str, Mapping[str, Sequence[tuple[np.ndarray, np.ndarray]]]], path: str | os.PathLike,
           ylabel: str, title: str = "", colors: Mapping[str, str] | None = None) -> pathlib.Path:
    """One panel per key of ``panels`` (its title), its cells drawn by :func:`draw` against simulated
    seconds per environment, y shared; ``colors``: a cell's colour in every panel."""
    plt = plots.plt
    path = pathlib.Path(path)
    n = max(1, len(panels))
    cols = min(n, PANELS_PER_ROW)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 3.6 * rows), sharey=True, squeeze=False,
                             layout="constrained")
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    for ax, (name, cells) in zip(axes.ravel(), panels.items()):
        draw(ax, cells, colors)
        ax.set_title(name)
        ax.set_xlabel("simulated seconds per environment")
    for row in axes:
        row[0].set_ylabel(ylabel)
    if title:
        fig.suptitle(title)
    plots.save(fig, path, dpi=110, bbox_inches="tight")
    return path
