"""The paper-scale Fig. 3's plain answers and its progress page, from the progress record.

The record (``results/fig3_paper/progress.json``, built by scripts/publish/publish_fig3_paper.py from the
sweep's points) holds per l and milestone the seeds' average reward per step during learning and
their mean +/- 95% CI, every point's trials, collapse and largest fall. From it:

* :func:`answers`: l = 10 against l = 1 at every milestone both reached (difference of the seed
  means with its 95% Welch interval, :func:`nmrl.analysis.stats.diff_ci95`, and the relative
  difference; the paper: 4.59 vs 3.28, +40%), the best l, and l = 30's divergences and collapses;
* :func:`progress_md`: the page ``progress.md``.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from nmrl.analysis import stats

#: the milestones compared, in trials per point: 2*10^4 an intermediate comparison, 5*10^4 half the
#: budget, where every l can be compared long before all reach 10^5
MILESTONES = (10_000, 20_000, 30_000, 50_000, 100_000)


def answers(p: dict, ls: Sequence[int]) -> dict:
    """The plain answers at every milestone all the compared points have reached:
    l = 10 against l = 1 (difference of the seed means with its 95% Welch interval, and the relative
    difference; paper: 4.59 vs 3.28, +40%), the best l (highest seed mean, among the l whose seeds
    all reached the milestone) and, for l = 30, divergences and collapses (a seed whose last
    tenth lies below half its running peak). ``p`` is the progress record (``by_l``: per l and
    milestone the seeds' values and their mean, ``points``, ``diverged``); ``ls`` the sweep's l."""
    out: dict = {"l10_vs_l1": {}, "best_l": {}}
    by = p["by_l"]
    for m in map(str, MILESTONES):
        if "1" in by and "10" in by and by["1"][m]["mean"] is not None and by["10"][m]["mean"] is not None:
            a, b = np.array(by["1"][m]["seeds"], float), np.array(by["10"][m]["seeds"], float)
            d, h = stats.diff_ci95(a, b)
            out["l10_vs_l1"][m] = {"l1": float(a.mean()), "l10": float(b.mean()), "diff": d, "diff_ci95": h,
                                   "relative": float(b.mean() / a.mean() - 1) if a.mean() > 0 else None}
        done = {l: e[m]["mean"] for l, e in by.items() if e[m]["mean"] is not None}
        if done:
            best = max(done, key=done.get)
            out["best_l"][m] = {"l": int(best), "mean": done[best], "among": sorted(map(int, done))}
    if 30 in ls:
        out["l30"] = {"diverged": [d for d in p["diverged"] if d["point"].startswith("l30_")],
                      "collapsed": [n for n, q in p["points"].items() if n.startswith("l30_") and q.get("collapsed")]}
    return out


def progress_md(p: dict) -> str:
    """progress.md: the milestone table per l, the rate and what is left, divergences, collapses,
    the largest falls, the gaits and the plain answers of ``p["answers"]``."""
    def f(x, nd=2):
        return "–" if x is None else f"{x:+.{nd}f}"

    lines = ["| l | " + " | ".join(f"{m:,} trials: mean ± 95% CI (seeds)" for m in p["milestones"]) +
             " | trials per seed (share of 10⁵) |", "|---|" + "---|" * (len(p["milestones"]) + 1)]
    for l, by in p["by_l"].items():
        cells = []
        for m in p["milestones"]:
            e = by[str(m)]
            seeds = ", ".join(f(v) for v in e["seeds"])
            cells.append(f"{f(e['mean'])} ± {e['ci95']:.2f} ({seeds})" if e["mean"] is not None
                         else f"– ({seeds})")
        pts = [v for k, v in p["points"].items() if k.startswith(f"l{l}_")]
        share = ", ".join(f"{v['trials']:,} ({100 * v['budget_share']:.1f}%)" for v in pts)
        lines.append(f"| {l} | " + " | ".join(cells) + f" | {share} |")
    lines.append("")
    which = "the points still running" if p.get("remaining_ctrl_steps") else "the last points to run (all finished)"
    lines.append(f"Rate (median of the last 10 chunks of {which}, whole machine): "
                 f"{p['rate_ctrl_steps_per_s']:,.0f} control steps/s."
                 if p["rate_ctrl_steps_per_s"] else "Rate: no chunks yet.")
    if p.get("remaining_ctrl_steps"):
        h = p["remaining_hours_at_rate"]
        lines.append(f"Left: ~{p['remaining_ctrl_steps']:,.0f} control steps (every running point to 10⁵ trials at "
                     f"its trials' mean length so far)" + (f", ~{h:.1f} h at that rate." if h is not None else "."))
    lines.append("Diverged: " + (", ".join(f"{d['point']} at {d['trials']:,} trials" for d in p["diverged"])
                                 or "none") + ".")
    collapsed = [n for n, q in p["points"].items() if q.get("collapsed")]
    lines.append("Collapsed (last tenth below half the running peak): " + (", ".join(collapsed) or "none") + ".")
    lines += falls_md(p)
    for l, g in (p.get("gaits") or {}).items():
        lines.append(f"Gait of l = {l}: {g['point']} at {g['trials']:,} trials, deterministic "
                     f"{f(g['deterministic']['avg_reward'])} per step ({g['deterministic']['forward_speed']:.2f} m/s), "
                     f"exploring {f(g['exploring']['avg_reward'])}: {g['dir']}/strobe.png, gait.gif")
    a = p.get("answers") or {}
    if a.get("l10_vs_l1"):
        lines += ["", "l = 10 against l = 1 (paper after 10⁵ trials: 4.59 vs 3.28, +40%):", ""]
        for m, e in a["l10_vs_l1"].items():
            rel = "–" if e["relative"] is None else f"{100 * e['relative']:+.0f}%"
            lines.append(f"- {int(m):,} trials: {f(e['l10'])} vs {f(e['l1'])}, difference {f(e['diff'])} "
                         f"± {e['diff_ci95']:.2f} (95% Welch interval over the seeds), {rel}")
    if a.get("best_l"):
        lines += ["", "Best l (highest mean over the seeds, among the l that reached the milestone):", ""]
        lines += [f"- {int(m):,} trials: l = {e['l']} ({f(e['mean'])}; among l = {', '.join(map(str, e['among']))})"
                  for m, e in a["best_l"].items()]
    return "\n".join(lines) + "\n"


def falls_md(p: dict) -> list[str]:
    """Per l, each seed's largest fall below its running peak (stats.largest_fall: 5-chunk running
    mean, from 10^4 trials on): how steady learning is, short of a divergence or a collapse."""
    lines = ["", "Largest fall below the running peak (5-chunk running mean of the average reward per step, "
             "from 10⁴ trials on; stats.largest_fall): per l the largest over the seeds, then each seed as "
             "fall (share of the peak): peak at trials → trough at trials, end of the run:", "",
             "| l | largest fall | each seed |", "|---|---|---|"]
    for l in p["by_l"]:
        falls = [(n, q["largest_fall"]) for n, q in p["points"].items()
                 if n.startswith(f"l{l}_") and q.get("largest_fall")]
        if not falls:
            continue
        worst = max(e["fall"] for _, e in falls)
        cells = []
        for n, e in falls:
            share = "–" if e["share"] is None else f"{100 * e['share']:.0f}%"
            cells.append(f"{n}: {e['fall']:.2f} ({share}): {e['peak']:+.2f} at {e['peak_trials']:,} → "
                         f"{e['trough']:+.2f} at {e['trough_trials']:,}, end {e['end']:+.2f}")
        lines.append(f"| {l} | {worst:.2f} | " + "; ".join(cells) + " |")
    return lines
