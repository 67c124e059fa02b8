"""Publish the paper-scale Fig. 3 sweep as it grows: results/fig3_paper/ (committed whenever it is published).

    .venv/bin/python scripts/publish/publish_fig3_paper.py [--src runs/fig3_paper] [--dest results/fig3_paper]

Writes into ``dest`` (each file atomically):

* ``sweep.json``, ``results.csv`` (the columns of ``nmrl sweep``);
* ``fig3.png``: average reward during learning against l, one line per milestone below, each over the
  l whose every seed reached it (never points at different budgets on one curve;
  nmrl.analysis.plots.fig3_milestones), the paper's 3.28 and 4.59 marked;
* ``points/l{l}_s{seed}/{config.json, metrics.jsonl, compact.npz}``: everything a fresh clone needs
  to continue the sweep (``scripts/run/fig3_paper.sh`` seeds ``runs/fig3_paper`` from it when the full
  checkpoints are gone; nmrl.runs.checkpoint.restore_compact);
* ``learning_curves.png``: average reward per step during learning against trials, every l (mean
  over seeds, thin lines per seed), the paper's 3.28 (l = 1) and 4.59 (l = 10) marked;
* ``progress.json`` and ``progress.md``: per l, the average reward per step during learning at
  10^4, 2*10^4, 3*10^4, 5*10^4 and 10^5 trials (mean over the chunks whose trial count lies in
  (0.9 M, M], i.e. the last tenth before the milestone M), mean +- 95% CI over the seeds and each seed; the share of the
  budget every point has; divergences (point, trials); the measured rate (control steps/s of the
  whole machine over the last 10 chunks of the points still running, from metrics ``wall_s``) and
  the control steps left (every running point to the budget at its mean trial length so far) with
  the hours they take at that rate;
  the plain answers at every milestone reached (l = 10 against l = 1: difference of the seed means with its 95% Welch interval and the
  relative difference; the best l; collapsed points, i.e. last tenth below half the running peak);
  per point its largest fall below the running peak from 10^4 trials on (nmrl.analysis.stats.largest_fall:
  how steady learning is, short of a divergence or a collapse), in progress.md one row per l;
* ``gaits/l{1,10}_best/{eval.json, strobe.png, gait.gif}`` once every seed of that l has
  ``--gait-trials`` trials (default the budget): the best seed's gait (see :func:`gaits`).
"""

from __future__ import annotations

import argparse
import json
import pathlib

import numpy as np

from nmrl import options
from nmrl.analysis import plots, publish_fig3, stats
from nmrl.analysis.publish_fig3 import MILESTONES, falls_md, progress_md  # noqa: F401
from nmrl.experiments import sweep
from nmrl.learners.ac_config import TrainConfig
from nmrl.runs import store



def progress(src: pathlib.Path, spec: sweep.SweepSpec) -> dict:
    budget = spec.base.budget.trials
    out = {"budget_trials": budget, "milestones": list(MILESTONES), "by_l": {}, "points": {}, "diverged": []}
    # step -> steps_per_s of the points' chunks ending there: of the points still running (the rate
    # now), else of all points (a finished stage's rows lie at higher steps than the running one's)
    newest: dict[int, list[float]] = {}
    newest_all: dict[int, list[float]] = {}
    remaining = 0.0  # control steps (all environments) the running points still need, at their trial length
    for l in spec.ls:
        per = {str(m): [] for m in MILESTONES}
        for s in range(spec.seeds):
            rows = store.read_metrics(sweep.point_dir(src, l, s))
            name = f"l{l}_s{s}"
            last = rows[-1] if rows else {"trials": 0, "step": 0}
            div = next((r for r in rows if store.is_diverged(r)), None)
            if div is not None:
                out["diverged"].append({"point": name, "trials": div["trials"], "step": div["step"]})
            peak = float(np.max(stats.smooth(np.array([r["avg_reward"] for r in rows])))) if rows else None
            final = stats.final_avg(rows, "avg_reward")
            out["points"][name] = {"trials": last["trials"], "steps": last["step"],
                                   "budget_share": last["trials"] / budget if budget else None,
                                   "final_avg_reward": final, "peak_avg_reward": peak,
                                   "collapsed": bool(peak is not None and peak > 0 and final < 0.5 * peak),
                                   "diverged": div is not None, "largest_fall": stats.largest_fall(rows)}
            for m in MILESTONES:
                per[str(m)].append(stats.at_milestone(rows, m))
            running = bool(rows) and not (budget and last["trials"] >= budget) and div is None
            if budget and div is None and last["trials"] < budget:
                # control steps per trial so far (all environments); a point without trials yet: the
                # stop rule's mean trial length, 1/stop_prob
                per_trial = (last["step"] * spec.base.budget.num_envs / last["trials"] if last["trials"]
                             else 1 / spec.base.environment.stop_prob)
                remaining += (budget - last["trials"]) * per_trial
            for r in rows[-20:]:
                newest_all.setdefault(r["step"], []).append(r["steps_per_s"])
                if running:
                    newest.setdefault(r["step"], []).append(r["steps_per_s"])
        out["by_l"][str(l)] = {}
        for m, vals in per.items():
            got = [v for v in vals if v is not None]
            mean, half = stats.mean_ci95(np.array(got)) if len(got) == spec.seeds else (None, None)
            out["by_l"][str(l)][m] = {"mean": mean, "ci95": half, "seeds": vals}
    # rate: the points active in a chunk share its wall time, and steps_per_s already counts every
    # one of them (nmrl.runs.loop.metrics_row(points=...))
    recent = sorted((newest or newest_all).items())[-10:]
    out["rate_ctrl_steps_per_s"] = float(np.median([v[0] for _, v in recent])) if recent else None
    rate = out["rate_ctrl_steps_per_s"]
    out["remaining_ctrl_steps"] = remaining
    if not remaining:
        out["remaining_hours_at_rate"] = 0.0
    elif rate:
        out["remaining_hours_at_rate"] = remaining / rate / 3600
    else:  # steps left, but no chunk measured yet
        out["remaining_hours_at_rate"] = None
    out["answers"] = answers(out, spec)
    return out


def answers(p: dict, spec: sweep.SweepSpec) -> dict:
    """The plain answers of the sweep ``spec`` (nmrl/analysis/publish_fig3.py)."""
    return publish_fig3.answers(p, spec.ls)


def learning_curves(src: pathlib.Path, spec: sweep.SweepSpec, path: pathlib.Path) -> None:
    from nmrl.analysis.plots import plt, save

    cmap = plt.get_cmap("viridis")
    fig, ax = plt.subplots(figsize=(9, 5))
    for j, l in enumerate(spec.ls):
        color = cmap(j / max(1, len(spec.ls) - 1))
        curves = []
        for s in range(spec.seeds):
            rows = store.read_metrics(sweep.point_dir(src, l, s))
            if not rows:
                continue
            t = np.array([r["trials"] for r in rows])
            y = stats.smooth(np.array([r["avg_reward"] for r in rows]))
            ax.plot(t, y, color=color, lw=0.5, alpha=0.35)
            curves.append((t, y))
            div = next((r for r in rows if store.is_diverged(r)), None)
            if div is not None:
                ax.plot([div["trials"]], [y[-1]], "x", color="tab:red")
        if curves:
            n = min(len(c[0]) for c in curves)
            ax.plot(np.mean([c[0][:n] for c in curves], 0), np.mean([c[1][:n] for c in curves], 0),
                    color=color, lw=1.8, label=f"l={l}")
    for l, v in plots.PAPER_FIG3.items():
        ax.axhline(v, color="tab:orange", ls="--", lw=1)
        ax.annotate(f"paper, l={l}: {v}", (0.01, v), xycoords=("axes fraction", "data"), va="bottom",
                    color="tab:orange", fontsize=8)
    ax.set_xlabel("trials (per point)")
    ax.set_ylabel("average reward per step during learning\n(running mean of 5 chunks)")
    ax.set_title("Fig. 3 at the paper's budget and step sizes: learning curves (x: diverged)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=4)
    save(fig, path, dpi=110, bbox_inches="tight")


GAIT_LS = (1, 10)


def gaits(dest: pathlib.Path, spec: sweep.SweepSpec, p: dict, at_trials: int) -> dict:
    """The best seed's gait for l = 1 and l = 10 once every seed of that l has ``at_trials`` trials:
    the seed with the highest average reward per step during learning over its last tenth of chunks
    (``final_avg_reward``), its published compact state evaluated as ``nmrl eval
    DEST/points/l{l}_s{seed} --out DEST/gaits/l{l}_best`` (10 s, seed 0: eval.json, strobe.png,
    gait.gif). An existing evaluation of the same point and step is kept (evaluation is
    deterministic for a given state)."""
    from nmrl.analysis import evaluate
    from nmrl.runs import checkpoint

    out = {}
    for l in GAIT_LS:
        names = [f"l{l}_s{s}" for s in range(spec.seeds)]
        if l not in spec.ls or any(p["points"][n]["trials"] < at_trials for n in names):
            continue
        best = max(names, key=lambda n: p["points"][n]["final_avg_reward"])
        src, d = dest / "points" / best, dest / "gaits" / f"l{l}_best"
        old = json.loads((d / "eval.json").read_text()) if (d / "eval.json").is_file() else None
        step = int(checkpoint.load_compact(src)[1]["step"])  # the state nmrl eval reads
        if old is None or pathlib.Path(old["run_dir"]).name != best or old["step"] != step:
            old = evaluate.evaluate(src, seconds=10.0, seed=0, render=True, out_dir=d)
        out[str(l)] = {"point": best, "step": old["step"], "trials": old["trials"],
                       "final_avg_reward_learning": p["points"][best]["final_avg_reward"],
                       "deterministic": {k: old["deterministic"][k] for k in ("avg_reward", "forward_speed")},
                       "exploring": {k: old["exploring"][k] for k in ("avg_reward", "forward_speed")},
                       "dir": str(d.relative_to(dest))}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--src", default="runs/fig3_paper")
    ap.add_argument("--dest", default="results/fig3_paper")
    ap.add_argument("--gait-trials", type=int, default=None,
                    help="render the best l = 1 and l = 10 gaits once every seed has this many trials "
                         "(default: the budget, 10^5)")
    args = ap.parse_args()
    if args.gait_trials is not None and args.gait_trials < 1:
        raise SystemExit(f"publish_fig3_paper: error: --gait-trials={args.gait_trials} is invalid: must be >= 1")
    src, dest = pathlib.Path(args.src), pathlib.Path(args.dest)
    if not (src / sweep.SPEC_FILE).is_file():
        raise SystemExit(f"publish_fig3_paper: error: {src / sweep.SPEC_FILE} not found; is {src} a sweep directory?")
    s = json.loads((src / sweep.SPEC_FILE).read_text())
    spec = sweep.SweepSpec(ls=tuple(s["ls"]), seeds=s["seeds"], base=options.build(TrainConfig, **s["base"]),
                           first=tuple(s.get("first", ())))
    dest.mkdir(parents=True, exist_ok=True)
    results = sweep.write_results(src, spec)
    store.atomic_copy(src / sweep.SPEC_FILE, dest / sweep.SPEC_FILE)
    store.atomic_copy(src / sweep.RESULTS_FILE, dest / sweep.RESULTS_FILE)
    for l, seed in spec.points():
        p = sweep.point_dir(src, l, seed)
        for name in ("config.json", "metrics.jsonl", "compact.npz"):
            if (p / name).is_file():
                store.atomic_copy(p / name, sweep.point_dir(dest, l, seed) / name)
    learning_curves(src, spec, dest / "learning_curves.png")
    p = progress(src, spec)
    plots.fig3_milestones(p["by_l"], MILESTONES, dest / "fig3.png",
                          title="Fig. 3 at the paper's budget and step sizes: reward vs l at each milestone")
    p["gaits"] = gaits(dest, spec, p, args.gait_trials if args.gait_trials is not None else spec.base.budget.trials)
    store.atomic_write_text(dest / "progress.json", json.dumps(p, indent=1) + "\n")
    store.atomic_write_text(dest / "progress.md", progress_md(p))
    print(progress_md(p))


if __name__ == "__main__":
    main()
