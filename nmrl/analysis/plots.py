"""Figures drawn from rows: the paper's Fig. 3 (average reward against l), learning curves, the
finer-delta study's figures; and the Agg set-up (matplotlib's backend set on import, before pyplot:
no display is needed) and the figure save (:func:`save`) that the gait pictures, the scripts and
the benchmarks take from here (``plt``, ``save``).

Every figure takes the rows it draws (results or study tables, metrics rows) as arguments and
reads no run directory: the experiments (nmrl/experiments/) gather them. Fig. 3 of the paper plots
the average reward after 10^5 trials against the period length l; the text gives two of its
values, 3.28 at l = 1 and 4.59 at l = 10, which are marked for reference. Intervals are 95%
Student-t intervals of the mean over seeds (nmrl/analysis/stats.py).
"""

from __future__ import annotations

import os
import pathlib

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from nmrl.analysis.stats import mean_ci95, smooth  # noqa: E402
from nmrl.paper.control_step import DELTA_0  # noqa: E402
from nmrl.runs.store import atomic_path  # noqa: E402

#: the trials per point behind the paper's Fig. 3 (Sec. V-D)
PAPER_TRIALS = 100_000
#: The values of Fig. 3 that the paper's text states (Sec. V-D).
PAPER_FIG3 = {1: 3.28, 10: 4.59}


def save(fig, path: str | os.PathLike, **savefig) -> pathlib.Path:
    """Write ``fig`` to ``path`` atomically (a reader sees the old picture or the whole new one,
    never half of one; the format from the suffix) and close it, also when writing fails.
    ``savefig`` are matplotlib's options for this figure (``dpi``, ``bbox_inches``, ...), passed
    unchanged: each figure keeps its own."""
    path = pathlib.Path(path)
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, **savefig)
    finally:
        plt.close(fig)
    return path


def _save(fig, path: pathlib.Path) -> None:
    save(fig, path, dpi=110, bbox_inches="tight")


def fig3(results: list[dict], curves: dict[int, list[list[dict]]], path: str | os.PathLike) -> pathlib.Path:
    """Write ``path``: reward vs l (mean, 95% CI over seeds, paper's points) from the ``results`` rows
    (l, seed, trials, avg_reward, diverged: a bool), and the learning curves from ``curves``
    (l -> the metrics rows of each of its seeds)."""
    path = pathlib.Path(path)
    ls = sorted({int(r["l"]) for r in results})
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(13, 4.8))
    fig.subplots_adjust(wspace=0.32)
    means, halves, divs = [], [], []
    for l in ls:
        rs = [r for r in results if int(r["l"]) == l]
        ok = [float(r["avg_reward"]) for r in rs if not r["diverged"]]
        m, h = mean_ci95(np.array(ok)) if ok else (float("nan"), float("nan"))
        means.append(m)
        halves.append(h)
        divs.append(len(rs) - len(ok))
        ax.scatter([l] * len(ok), ok, color="tab:blue", alpha=0.35, s=14)
    ax.errorbar(ls, means, yerr=halves, fmt="o-", color="tab:blue", capsize=4, label="nmrl (mean, 95% CI)")
    for l, d, m in zip(ls, divs, means):
        if d:
            ax.annotate(f"{d} diverged", (l, m if np.isfinite(m) else 0), textcoords="offset points",
                        xytext=(0, 10), ha="center", color="tab:red", fontsize=8)
    trials = [int(r["trials"]) for r in results]
    reduced = bool(trials) and max(trials) < 0.9 * PAPER_TRIALS
    ax.scatter(list(PAPER_FIG3), list(PAPER_FIG3.values()), marker="*", s=160, color="tab:orange",
               label=(f"paper, after {PAPER_TRIALS:,} trials (this run: {max(trials):,}, not comparable)"
                      if reduced else "paper (values given in the text)"), zorder=5)
    ax.set_xlabel("period length l")
    ax.set_ylabel("average reward per step")
    if trials and min(trials) < 0.95 * max(trials):  # a sweep still running (or --first stages)
        ax.set_title(f"Fig. 3: average reward vs l, points at {min(trials):,}–{max(trials):,} trials")
        for l, m in zip(ls, means):
            t = np.median([int(r["trials"]) for r in results if int(r["l"]) == l])
            ax.annotate(f"{t / 1000:.0f}k", (l, m if np.isfinite(m) else 0), textcoords="offset points",
                        xytext=(6, -12), fontsize=7, color="0.35")
    else:
        ax.set_title(f"Fig. 3: average reward vs l (after ~{np.median(trials):,.0f} trials)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)

    cmap = plt.get_cmap("viridis")
    for j, l in enumerate(ls):
        cs = [(np.array([x["trials"] for x in m]), np.array([x["avg_reward"] for x in m]))
              for m in curves.get(l, []) if m]
        if not cs:
            continue
        n = min(len(c[0]) for c in cs)
        tr = np.mean([c[0][:n] for c in cs], axis=0)
        rw = np.mean([c[1][:n] for c in cs], axis=0)
        ax2.plot(tr, smooth(rw), color=cmap(j / max(1, len(ls) - 1)), label=f"l={l}")
    ax2.set_xlabel("trials")
    ax2.set_ylabel("average reward per step (mean over seeds,\nrunning mean of 5 chunks)")
    ax2.set_title("learning curves")
    ax2.grid(alpha=0.3)
    if ax2.lines:  # no curve yet (every point still at step 0): no empty legend
        ax2.legend(fontsize=8, ncol=2)
    _save(fig, path)
    return path


def milestone_series(by_l: dict, milestones) -> list[dict]:
    """The lines of :func:`fig3_milestones`: per milestone (trials), the l whose every seed reached it,
    with the mean and 95% half-width over the seeds. ``by_l`` maps l (int or str) -> milestone (int
    or str) -> ``{"mean", "ci95", "seeds"}``, the mean None while a seed is short of it (as
    scripts/publish/publish_fig3_paper.py's progress.json). A milestone no l reached is left out."""
    out = []
    for m in milestones:
        got = [(int(k), by_l[k][str(m)]) for k in sorted(by_l, key=int)
               if by_l[k].get(str(m), {}).get("mean") is not None]
        if got:
            out.append({"trials": int(m), "l": [l for l, _ in got], "mean": [float(e["mean"]) for _, e in got],
                        "ci95": [float(e["ci95"]) for _, e in got]})
    return out


def fig3_milestones(by_l: dict, milestones, path: str | os.PathLike, title: str = "") -> pathlib.Path:
    """Write ``path``: Fig. 3 (average reward during learning against l) as it grows, one line per
    milestone of trials, each only over the l whose every seed reached it (:func:`milestone_series`),
    so that points at different budgets are never drawn as one curve. Mean and 95% CI over the seeds;
    the paper's two stated values (after 10^5 trials) marked."""
    path = pathlib.Path(path)
    series = milestone_series(by_l, milestones)
    fig, ax = plt.subplots(figsize=(8, 5))
    cmap = plt.get_cmap("plasma")
    for j, s in enumerate(series):
        dx = (j - (len(series) - 1) / 2) * 0.18  # side by side, so the intervals stay readable
        ax.errorbar(np.array(s["l"]) + dx, s["mean"], yerr=s["ci95"], fmt="o-", capsize=3, ms=4, lw=1.3,
                    color=cmap(0.85 * j / max(1, len(series) - 1)),
                    label=f"{s['trials']:,} trials ({len(s['l'])} l)")
    ax.scatter(list(PAPER_FIG3), list(PAPER_FIG3.values()), marker="*", s=160, color="tab:orange",
               label="paper, 10⁵ trials (values given in the text)", zorder=5)
    ax.set_xlabel("period length l")
    ax.set_ylabel("average reward per step during learning\n(mean over seeds, 95% CI)")
    ax.set_title(title or "Fig. 3: average reward vs l at each milestone every seed of l reached")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    _save(fig, path)
    return path


def arm_order(rows: list[dict]) -> list[str]:
    """The study's arms in the rows: the stationary one first, then by period duration."""
    return sorted({r["arm"] for r in rows}, key=lambda a: (a != "stationary", float(a[1:-1]) if a != "stationary" else 0))


def _arm_label(arm: str) -> str:
    return "stationary (l = 1)" if arm == "stationary" else f"nm-period {arm[1:-1]} s"


def timescale(out: str | os.PathLike, grid: list[dict], final: list[dict], gradvar: list[dict],
              curves: dict[tuple[str, float], list[list[dict]]], path: str | os.PathLike | None = None
              ) -> pathlib.Path:
    """The finer-delta study (nmrl/experiments/study.py): ``timescale.png`` (reward per second against delta,
    one line per period duration, 95% t-intervals over seeds; the per-period gradient variance and
    the signal-to-noise per second; learning curves per delta, ``curves[(arm, dt)]`` = the metrics
    rows of each final run) and ``grid.png`` (the step-size grid), in ``out``."""
    out = pathlib.Path(out)
    path = pathlib.Path(path) if path else out / "timescale.png"
    arms = arm_order(grid)
    dts = sorted({float(r["dt"]) for r in grid}, reverse=True)
    colors = {a: f"C{i}" for i, a in enumerate(arms)}
    fig, axes = plt.subplots(2, 3, figsize=(15, 8.5))
    ax = axes[0, 0]
    for a in arms:
        xs, ms, cs = [], [], []
        for dt in dts:
            v = [float(r["reward_per_s"]) for r in final if r["arm"] == a and float(r["dt"]) == dt]
            if v:
                m, c = mean_ci95(np.array(v))
                xs.append(dt), ms.append(m), cs.append(c)
        if xs:
            ax.errorbar(xs, ms, yerr=cs, marker="o", capsize=4, color=colors[a], label=_arm_label(a))
        for k, dt in enumerate(dts):  # every seed, slightly spread sideways per arm
            v = [float(r["reward_per_s"]) for r in final if r["arm"] == a and float(r["dt"]) == dt]
            shift = 1 + 0.04 * (arms.index(a) - (len(arms) - 1) / 2)
            ax.scatter([dt * shift] * len(v), v, s=12, color=colors[a], alpha=0.5, marker="x")
    ax.set_xscale("log")
    ax.set_xticks(dts, [f"{d:g}" for d in dts])
    ax.minorticks_off()
    ax.invert_xaxis()
    ax.set_xlabel("control step δ [s]")
    ax.set_ylabel("average reward per second (last tenth; x = seeds)")
    ax.set_title("learning at finer δ (equal simulated time)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    pols = sorted({r["policy"] for r in gradvar})
    styles = {p: s for p, s in zip(pols, ["-", "--", ":", "-."])}
    for ax, key, title in ((axes[0, 1], "trcov", "tr Cov of the actor's gradient estimate per period"),
                           (axes[0, 2], "snr_per_s", "signal-to-noise of the estimates summed over 1 s")):
        for p in pols:
            for a in arms:
                rr = sorted([r for r in gradvar if r["policy"] == p and r["arm"] == a], key=lambda r: -float(r["dt"]))
                if not rr:
                    continue
                x = [float(r["dt"]) for r in rr]
                y = [float(r[key]) for r in rr]
                e = [float(r[key + "_ci"]) for r in rr] if key + "_ci" in rr[0] else None
                ax.errorbar(x, y, yerr=e, marker="o", ls=styles[p], color=colors[a], capsize=3,
                            label=f"{_arm_label(a)}, {p}" if a == arms[0] or p == pols[0] else None)
        ax.set_xscale("log")
        ax.set_yscale("log" if key == "trcov" else "symlog", **({} if key == "trcov" else {"linthresh": 1e-3}))
        ax.set_xticks(dts, [f"{d:g}" for d in dts])
        ax.minorticks_off()
        ax.invert_xaxis()
        ax.set_xlabel("control step δ [s]")
        ax.set_title(title, fontsize=10)
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=6)
        else:
            ax.text(0.5, 0.5, "not measured in this study\n(see its gradvar phase)", ha="center",
                    va="center", transform=ax.transAxes, fontsize=9, color="0.4")
    for j, dt in enumerate(dts[:3]):
        ax = axes[1, j]
        for a in arms:
            cs = [([x["step"] * dt for x in m], [x["avg_reward"] / DELTA_0 for x in m])
                  for m in curves.get((a, dt), [])]
            if not cs:
                continue
            n = min(len(c[0]) for c in cs)
            t = np.array(cs[0][0][:n])
            y = np.mean([c[1][:n] for c in cs], axis=0)
            ax.plot(t, smooth(y, 3), color=colors[a], label=_arm_label(a))
        ax.set_title(f"δ = {dt:g} s: mean over seeds", fontsize=10)
        ax.set_xlabel("simulated seconds per environment")
        ax.set_ylabel("reward per second")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    _save(fig, path)
    _grid_figure(grid, arms, dts, out / "grid.png")
    return path


def _grid_figure(grid: list[dict], arms: list[str], dts: list[float], path: pathlib.Path) -> None:
    bts = sorted({float(r["beta_theta"]) for r in grid})
    bvs = sorted({float(r["beta_v"]) for r in grid})
    fig, axes = plt.subplots(len(dts), len(arms), figsize=(3.2 * len(arms), 2.8 * len(dts)), squeeze=False)
    for i, dt in enumerate(dts):
        for j, a in enumerate(arms):
            ax = axes[i, j]
            z = np.full((len(bts), len(bvs)), np.nan)
            for r in grid:
                if r["arm"] == a and float(r["dt"]) == dt:
                    s = float(r["score"])
                    z[bts.index(float(r["beta_theta"])), bvs.index(float(r["beta_v"]))] = s / DELTA_0 if np.isfinite(s) else np.nan
                    if r["chosen"]:
                        ax.add_patch(plt.Rectangle((bvs.index(float(r["beta_v"])) - 0.5, bts.index(float(r["beta_theta"])) - 0.5),
                                                   1, 1, fill=False, ec="red", lw=2))
            im = ax.imshow(z, origin="lower", cmap="viridis")
            mid = np.nanmean([np.nanmin(z), np.nanmax(z)]) if np.isfinite(z).any() else 0.0
            for (bi, vi), val in np.ndenumerate(z):
                ax.text(vi, bi, "div." if np.isnan(val) else f"{val:.0f}", ha="center", va="center", fontsize=7,
                        color="k" if np.isfinite(val) and val > mid else "w")
            ax.set_xticks(range(len(bvs)), [f"{b:.0e}" for b in bvs], fontsize=7)
            ax.set_yticks(range(len(bts)), [f"{b:.0e}" for b in bts], fontsize=7)
            ax.set_title(f"δ={dt:g} s, {_arm_label(a)}", fontsize=8)
            if j == 0:
                ax.set_ylabel("β^θ")
            if i == len(dts) - 1:
                ax.set_xlabel("β^v")
            fig.colorbar(im, ax=ax, fraction=0.046)
    fig.suptitle("step-size grid: reward per second over the second half of the grid run (red: chosen)", fontsize=10)
    fig.tight_layout()
    _save(fig, path)
