"""A pre-registered study's decisions drawn: each cell's endpoint over its runs, and each contrast
with its interval against the equivalence margin.

:func:`endpoints`: one panel per group (a control step), one column per cell (an arm): every run's
value as a dot, the cell's mean with its 95% Student-t interval (nmrl/analysis/stats.py, what the
Welch contrasts decide on) as a bar. :func:`paired`: two measures of every run against each other
(e.g. a policy's forward speed with and without its exploration noise), the line y = x drawn.
:func:`contrasts`: one row per contrast of a family table
(nmrl/analysis/prereg_stats.py ``family``): the estimate with its 95% Welch interval, the
equivalence band ``±margin`` shaded, and the decision written beside it; a contrast without an
estimate is listed as pending. Linear axes in the endpoint's own unit, no transforms.
"""

from __future__ import annotations

import os
import pathlib
from typing import Mapping, Sequence

import numpy as np

from nmrl.analysis import plots
from nmrl.analysis.stats import mean_ci95

#: horizontal spread of a cell's run dots (in column widths), so equal values stay visible
JITTER = 0.12


def endpoints(panels: Mapping[str, Mapping[str, Sequence[float]]], path: str | os.PathLike, ylabel: str,
              title: str = "", colors: Mapping[str, str] | None = None) -> pathlib.Path:
    """One panel per key of ``panels`` (its title), one column per cell in it: each run's value
    (finite ones; a cell's non-finite runs are counted in its label), its mean and 95% t interval,
    drawn in the cell's colour from ``colors`` (default blue)."""
    plt = plots.plt
    n = max(1, len(panels))
    width = max([len(c) for c in panels.values()] or [1])
    fig, axes = plt.subplots(1, n, figsize=(1.2 + 0.9 * width * n, 3.8), sharey=True, squeeze=False,
                             layout="constrained")
    rng = np.random.default_rng(0)
    for ax, (name, cells) in zip(axes[0], panels.items()):
        labels = []
        for i, (cell, values) in enumerate(cells.items()):
            x = np.asarray(values, float)
            ok = x[np.isfinite(x)]
            labels.append(f"{cell}\n(n={ok.size}" + (f", {x.size - ok.size} non-finite)" if ok.size < x.size else ")"))
            if ok.size == 0:
                continue
            ax.plot(i + rng.uniform(-JITTER, JITTER, ok.size), ok, "o", ms=4, alpha=0.55, color="tab:gray")
            mean, half = mean_ci95(ok)
            ax.errorbar([i + 0.3], [mean], yerr=[[half], [half]], fmt="s", ms=6, capsize=4,
                        color=(colors or {}).get(cell, "tab:blue"))
        ax.set_xticks(range(len(labels)), labels, fontsize=8)
        ax.set_xlim(-0.6, max(len(labels), 1) - 0.2)
        ax.set_title(name)
        ax.grid(alpha=0.3, axis="y")
    axes[0][0].set_ylabel(ylabel)
    if title:
        fig.suptitle(title)
    return plots.save(fig, path, dpi=110, bbox_inches="tight")


def paired(panels: Mapping[str, Mapping[str, Sequence[tuple[float, float]]]], path: str | os.PathLike,
           xlabel: str, ylabel: str, title: str = "", colors: Mapping[str, str] | None = None) -> pathlib.Path:
    """One panel per key of ``panels`` (its title), one marker series per cell in it: each run's
    ``(x, y)`` pair (finite pairs only), with the line y = x across the panel: runs below it score
    less on y than on x. ``colors``: a cell's colour in every panel (default: the colour cycle's
    next in each panel)."""
    plt = plots.plt
    n = max(1, len(panels))
    fig, axes = plt.subplots(1, n, figsize=(1.4 + 3.6 * n, 3.9), sharex=True, sharey=True, squeeze=False,
                             layout="constrained")
    pairs = np.asarray([p for cells in panels.values() for v in cells.values() for p in v] or [(0.0, 1.0)], float)
    pairs = pairs[np.all(np.isfinite(pairs), axis=1)]
    lo, hi = (float(pairs.min()), float(pairs.max())) if pairs.size else (0.0, 1.0)
    pad = 0.05 * (hi - lo or 1.0)
    for ax, (name, cells) in zip(axes[0], panels.items()):
        ax.plot([lo - pad, hi + pad], [lo - pad, hi + pad], color="black", lw=0.8, label="y = x")
        for cell, v in cells.items():
            xy = np.asarray(v, float).reshape(-1, 2)
            xy = xy[np.all(np.isfinite(xy), axis=1)]
            ax.plot(xy[:, 0], xy[:, 1], "o", ms=5, alpha=0.7, label=f"{cell} (n={len(xy)})",
                    color=(colors or {}).get(cell))
        ax.set_title(name)
        ax.set_xlabel(xlabel)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    axes[0][0].set_ylabel(ylabel)
    if title:
        fig.suptitle(title, fontsize=10)
    return plots.save(fig, path, dpi=110, bbox_inches="tight")


def contrasts(table: Sequence[Mapping], margin: float, path: str | os.PathLike, xlabel: str,
              title: str = "") -> pathlib.Path:
    """One row per contrast of ``table`` (top to bottom in its order), rows with ``estimate``,
    ``lo``, ``hi`` and ``decision``: the estimate and its interval, the band ``(-margin, margin)``
    shaded, zero marked, the decision and the contrast's family (if given) as the row's label."""
    plt = plots.plt
    fig, ax = plt.subplots(figsize=(7.5, 0.8 + 0.36 * max(1, len(table))), layout="constrained")
    ax.axvspan(-margin, margin, color="tab:green", alpha=0.12, lw=0, label=f"equivalence margin ±{margin:g}")
    ax.axvline(0.0, color="black", lw=0.8)
    names = []
    for i, r in enumerate(table):
        y = len(table) - 1 - i
        fam = f"{r['family']} " if r.get("family") else ""
        names.append(f"{fam}{r['contrast']}: {r.get('decision', '')}")
        est = r.get("estimate", "")
        if est == "" or est is None or not np.isfinite(float(est)):
            continue
        est, lo, hi = float(est), float(r["lo"]), float(r["hi"])
        colour = {"ahead": "tab:blue", "behind": "tab:red", "equivalent": "tab:green"}.get(r.get("decision"), "tab:gray")
        ax.errorbar([est], [y], xerr=[[est - lo], [hi - est]], fmt="o", capsize=3, color=colour)
    ax.set_yticks(range(len(table) - 1, -1, -1), names, fontsize=8)
    ax.set_ylim(-0.7, len(table) - 0.3)
    ax.set_xlabel(xlabel)
    ax.grid(alpha=0.3, axis="x")
    ax.legend(fontsize=7, loc="lower right")
    if title:
        ax.set_title(title)
    return plots.save(fig, path, dpi=110, bbox_inches="tight")
