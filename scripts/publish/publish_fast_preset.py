"""Publish the fast-preset comparison: ``results/fast_preset/``.

Reads per-point metrics (``metrics.jsonl``, one row per chunk) of

* the ``fast`` preset's reduced Fig. 3 sweep, ``results/fig3_fast/points/l<l>_s<seed>/metrics.jsonl``
  (8 l x 3 seeds, 64 environments per point, 250-step chunks, ~5,200 trials per point; sgd with
  beta^theta = 1e-5, beta^v = 5e-4), used as the baseline as it is (not re-run);
* the candidate sweeps given with ``--run NAME=DIR`` (``DIR/points/l<l>_s<seed>/metrics.jsonl``,
  e.g. the confirmation sweep of ``fast_clip``; a sweep still running is read as far as it got);
* the screening sweeps given with ``--screen NAME=DIR`` (a few points each).

Writes ``results.csv`` (baseline and ``--run`` sweeps; columns l, seed, preset, trials, avg_reward,
peak, collapsed, then diverged, first_below_half, chunks), ``screening.csv`` (the same for the
screening sweeps), ``summary.json`` (per preset: points, collapsed, diverged; the mean learning
curve over the points on a common trial grid and its mean up to ``fast``'s first collapse)
and ``learning_curves.png`` (one panel per l: each seed's curve, ``fast`` against the candidates).

The numbers per point (end value, peak, collapse, milestones, mean curves) are
nmrl/analysis/publish_presets.py's, defined there; this script reads, writes and draws.

Usage (the full command that wrote the published files: results/fast_preset/README.md):
    python scripts/publish/publish_fast_preset.py --run fast_clip=runs/fast_preset/fast_clip \
        [--screen NAME=DIR ...] [--rename OLD=NEW ...]
"""

from __future__ import annotations

import argparse
import json
import pathlib
import re

import numpy as np

from nmrl.analysis.publish_presets import (MILESTONES, SMOOTH, at_trials, mean_curve, point_summary,  # noqa: F401
                                           running_mean)
from nmrl.runs import store

ROOT = pathlib.Path(__file__).resolve().parents[2]
BASELINE = ROOT / "results" / "fig3_fast"
OUT = ROOT / "results" / "fast_preset"
COLUMNS = ("l", "seed", "preset", "trials", "avg_reward", "peak", "collapsed", "diverged",
           "first_below_half", "chunks")


def points_of(src: pathlib.Path) -> dict[tuple[int, int], list[dict]]:
    """Every point's metrics rows by (l, seed): ``src/points/l<l>_s<seed>/metrics.jsonl`` (a sweep,
    running or published)."""
    pat = re.compile(r"l(\d+)_s(\d+)")
    out = {}
    for f in sorted((src / "points").glob("*/metrics.jsonl")):
        m = pat.fullmatch(f.parent.name)
        rows = store.read_jsonl(f)
        if m and rows:
            out[(int(m.group(1)), int(m.group(2)))] = rows
    return dict(sorted(out.items()))


def screen_points(name: str, src: pathlib.Path) -> dict[str, dict[tuple[int, int], list[dict]]]:
    """A screening run's points by candidate: ``points/l<l>_s<seed>`` belong to ``name``;
    ``points/<candidate>__l<l>_s<seed>`` (several candidates in one program) to ``<candidate>``."""
    pat = re.compile(r"(?:(.+)__)?l(\d+)_s(\d+)")
    out: dict = {}
    for f in sorted((src / "points").glob("*/metrics.jsonl")):
        m = pat.fullmatch(f.parent.name)
        rows = store.read_jsonl(f)
        if m and rows:
            out.setdefault(m.group(1) or name, {})[(int(m.group(2)), int(m.group(3)))] = rows
    return out


def write_csv(path: pathlib.Path, table: list[dict]) -> None:
    store.write_csv(path, COLUMNS, [{k: (f"{row[k]:.4f}" if isinstance(row[k], float) else row[k]) for k in COLUMNS}
                                    for row in table])


def screening_table(screens: dict, old: dict) -> str:
    """Markdown: every screened point at the milestones, beside the old preset's same point."""
    reach = max(x[-1]["trials"] for pts in screens.values() for x in pts.values())
    ms = [m for m in MILESTONES if m <= reach]
    lines = ["| candidate | point | " + " | ".join(f"{m:,} trials" for m in ms) + " | end (trials) | collapsed |",
             "|---|---|" + "---|" * len(ms) + "---|---|"]
    f = lambda v: "–" if v is None else f"{v:+.2f}"  # noqa: E731
    pts_all = sorted({k for pts in screens.values() for k in pts})
    for key in pts_all:
        if key in old:
            o = point_summary(old[key])
            lines.append(f"| fast (results/fig3_fast) | l = {key[0]}, seed {key[1]} | "
                         + " | ".join(f(at_trials(old[key], m)) for m in ms)
                         + f" | {o['avg_reward']:+.2f} ({o['trials']:,}) | {'yes' if o['collapsed'] else 'no'} |")
        for name, pts in screens.items():
            if key in pts:
                o = point_summary(pts[key])
                lines.append(f"| {name} | l = {key[0]}, seed {key[1]} | "
                             + " | ".join(f(at_trials(pts[key], m)) for m in ms)
                             + f" | {o['avg_reward']:+.2f} ({o['trials']:,}) | {'yes' if o['collapsed'] else 'no'} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--run", action="append", default=[], help="NAME=SWEEP_DIR of a full candidate sweep")
    ap.add_argument("--screen", action="append", default=[], help="NAME=SWEEP_DIR of a screening sweep")
    ap.add_argument("--rename", action="append", default=[],
                    help="OLD=NEW: call the screened candidate OLD (a point-name prefix) NEW")
    ap.add_argument("--out", default=str(OUT))
    args = ap.parse_args()
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    sets = {"fast": points_of(BASELINE)}
    for spec in args.run:
        name, _, d = spec.partition("=")
        sets[name] = points_of(pathlib.Path(d))
    screens: dict = {}
    for spec in args.screen:
        name, _, d = spec.partition("=")
        for cand, pts in screen_points(name, pathlib.Path(d)).items():
            cand = dict(r.split("=", 1) for r in args.rename).get(cand, cand)
            screens.setdefault(cand, {}).update(pts)

    table = [{"l": l, "seed": s, "preset": name, **point_summary(rows)}
             for name, pts in sets.items() for (l, s), rows in pts.items()]
    write_csv(out / "results.csv", table)
    if screens:
        stable = [{"l": l, "seed": s, "preset": name, **point_summary(rows)}
                  for name, pts in screens.items() for (l, s), rows in pts.items()]
        write_csv(out / "screening.csv", stable)

    # the old preset's first collapse: the earliest first_below_half (or divergence) over its points
    base = [r for r in table if r["preset"] == "fast"]
    firsts = [r["first_below_half"] for r in base if r["first_below_half"] != ""]
    t_c = min(firsts) if firsts else None
    grid = np.arange(100, 5001, 50, dtype=float)
    summary = {"definitions": {k: v for k, v in (
        ("avg_reward", "mean over the last tenth of the chunks"),
        ("peak", f"max of the {SMOOTH}-chunk running mean"),
        ("collapsed", "diverged, or avg_reward < peak - |peak|/2"),
        ("speed", "mean over the points of each point's chunk average reward interpolated on a trial "
                  "grid (every 50 trials from 100), averaged over the grid up to the old preset's first "
                  "collapse"))},
               "old_first_collapse_trials": t_c, "presets": {}}
    for name, pts in {**sets, **{f"screen:{k}": v for k, v in screens.items()}}.items():
        rows = [r for r in (table if name in sets else
                            [{"l": l, "s": s, **point_summary(x)} for (l, s), x in pts.items()])
                if name not in sets or r["preset"] == name]
        curve = mean_curve(pts, grid)
        upto = grid <= (t_c or grid[-1])
        same = {}
        if name not in sets or name != "fast":
            # the old preset on the same (l, seed) points, over the trials both reached (<= t_c)
            reach = min(max(x["trials"] for x in rows_) for rows_ in pts.values()) if pts else 0
            both = upto & (grid <= reach)
            old = mean_curve({k: v for k, v in sets["fast"].items() if k in pts}, grid)
            same = {"compared_up_to_trials": int(grid[both][-1]) if both.any() else None,
                    "mean_reward": float(np.nanmean(curve[both])) if both.any() else None,
                    "old_fast_same_points_mean_reward": float(np.nanmean(old[both])) if both.any() else None}
        summary["presets"][name] = {
            "vs_old_fast_same_points": same,
            "points": len(rows), "collapsed": sum(r["collapsed"] for r in rows),
            "diverged": sum(r["diverged"] for r in rows),
            "min_trials": min((r["trials"] for r in rows), default=None),
            "mean_reward_up_to_old_first_collapse": (float(np.nanmean(curve[upto]))
                                                      if np.any(np.isfinite(curve[upto])) else None),
            "mean_curve": {int(g): (None if not np.isfinite(c) else round(float(c), 4))
                           for g, c in zip(grid[::10], curve[::10])},
        }
    store.atomic_write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    if screens:
        store.atomic_write_text(out / "screening.md", screening_table(screens, sets["fast"]))

    from nmrl.analysis.plots import plt, save

    ls = sorted({l for pts in sets.values() for l, _ in pts})
    cols = 4
    fig, axes = plt.subplots((len(ls) + cols - 1) // cols, cols, figsize=(4 * cols, 3.2 * ((len(ls) + cols - 1) // cols)),
                             sharex=True, sharey=True, squeeze=False)
    colors = dict(zip(sets, ["tab:red", "tab:blue", "tab:green", "tab:purple"]))
    for ax, l in zip(axes.flat, ls):
        for name, pts in sets.items():
            for (pl, s), rows in pts.items():
                if pl != l:
                    continue
                t, sm = running_mean(rows)
                ax.plot(t, sm, color=colors[name], lw=1.2, alpha=0.85, marker="." if len(sm) < 3 else None,
                        label=f"{name} (24-point sweep)" if s == 0 else None)
        for (name, pts), c in zip(screens.items(), ["tab:cyan", "tab:olive", "tab:gray"]):
            for (pl, s), rows in pts.items():
                if pl != l:
                    continue
                t, sm = running_mean(rows)
                ax.plot(t, sm, color=c, lw=1.4, ls="--", label=f"{name}, screening (seed {s})")
        ax.legend(loc="lower right", fontsize=7)
        ax.axhline(0, color="k", lw=0.5)
        ax.set_title(f"l = {l}")
        ax.set_ylim(-4, 3.5)
        ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("trials")
    for ax in axes[:, 0]:
        ax.set_ylabel("avg reward per step (5-chunk mean)")
    fig.suptitle("fast presets on the reduced Fig. 3 layout: each seed, 5-chunk running mean (64 environments "
                 "per point); dashed: screening runs")
    fig.tight_layout()
    save(fig, out / "learning_curves.png", dpi=110)
    print(json.dumps({k: {kk: v[kk] for kk in ("points", "collapsed", "diverged", "min_trials",
                                               "mean_reward_up_to_old_first_collapse", "vs_old_fast_same_points")}
                      for k, v in summary["presets"].items()} | {"old_first_collapse": t_c}, indent=1))


if __name__ == "__main__":
    main()
