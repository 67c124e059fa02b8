"""Publish the PPO baseline against the nm-period actor-critic under results/baseline_ppo/.

    .venv/bin/python scripts/publish/publish_baseline_ppo.py [--src runs/baseline_ppo] [--dest results/baseline_ppo]

Reads every seed's run directory SRC/ppo_s{seed} (``nmrl baseline ppo``), the actor-critic's
learning curves of l = 1 and l = 10 from results/fig3_paper/points/*/metrics.jsonl (per-point
control steps = steps per environment x its environments), the actor-critic's deterministic
evaluations at the budgets (DEST/ac_milestones.json, scripts/lab/ac_milestones.py) and, if present, the
wall times of results/benchmarks/results.json's ``baseline`` section. Writes, atomically:

* ``ppo_s{seed}/{config.json, metrics.jsonl, resumes.jsonl}``: each PPO run's config, rows per
  iteration and resumes, and, only while the seed is unfinished, ``compact.npz``, its newest
  parameters (nmrl.runs.checkpoint.save_tree_compact, ~1 MB): what a fresh clone needs to continue
  the run (scripts/run/baseline_ppo.sh seeds runs/ from it). A finished seed's compact.npz is not
  published (and removed from DEST): its ``--resume`` does nothing and needs no parameters;
* ``comparison.png``: the average reward per control step during learning against control steps
  (PPO's exploring policy, the actor-critic's exploring policy; mean over seeds, each seed thin),
  and the deterministic policies' evaluations (PPO every iteration, the actor-critic at the budgets);
* ``summary.json``: per method and budget (10^6, 10^7, 2.5*10^7 control steps), the deterministic
  policies' average reward per step and forward speed, mean +/- 95% CI over seeds, each seed,
  and the control steps each was actually taken at (PPO: the iteration boundary nearest the
  budget); printed as a markdown table;
* once every seed has ``--gait-steps`` control steps (default 2.5*10^7): ``gaits/ppo_best/`` (the
  best seed by its last deterministic evaluation, evaluated from its run directory SRC/ppo_s{seed}
  like ``nmrl baseline eval``, only when the published eval.json is not of that seed and step:
  eval.json, strobe.png, gait.gif) and ``gaits.png``, its strobe above those of the
  actor-critic's best l = 1 and l = 10 seeds at 10^5 trials (results/fig3_paper/gaits/, written by
  scripts/publish/publish_fig3_paper.py) where they exist.

The numbers (which rows, which seeds, the intervals, the table) are nmrl/analysis/publish_ppo.py's;
this script copies, draws and writes.
"""

from __future__ import annotations

import argparse
import json
import pathlib

import numpy as np

from nmrl.analysis import stats
from nmrl.analysis.publish_ppo import AC_LS, BUDGETS, ac_curves, ppo_runs, summary, table  # noqa: F401
from nmrl.runs import store

ROOT = pathlib.Path(__file__).resolve().parents[2]


def draw(ppo: dict, curves: dict, ac: dict, path: pathlib.Path) -> None:
    from nmrl.analysis.plots import plt, save

    fig, (a, b) = plt.subplots(1, 2, figsize=(13, 4.8), dpi=110)
    colors = {"ppo": "C3", 1: "C0", 10: "C2"}
    for s, rows in ppo.items():
        r = [x for x in rows if x.get("train_reward_per_step") is not None]
        a.plot([x["step"] for x in r], [x["train_reward_per_step"] for x in r], color=colors["ppo"], lw=0.7, alpha=0.4)
        b.plot([x["step"] for x in rows], [x["eval_avg_reward"] for x in rows], color=colors["ppo"], lw=0.7, alpha=0.4)
    for l, by_seed in curves.items():
        for s, (x, y) in by_seed.items():
            a.plot(x, stats.smooth(y, 5), color=colors[l], lw=0.7, alpha=0.4)
    _mean_line(a, [[(x["step"], x["train_reward_per_step"]) for x in rows if x.get("train_reward_per_step") is not None]
                   for rows in ppo.values()], colors["ppo"], "Brax PPO (exploring)")
    for l, by_seed in curves.items():
        _mean_line(a, [list(zip(x, stats.smooth(y, 5))) for x, y in by_seed.values()], colors[l],
                   f"nm-period actor-critic, l = {l} (exploring)")
    _mean_line(b, [[(x["step"], x["eval_avg_reward"]) for x in rows] for rows in ppo.values()], colors["ppo"],
               "Brax PPO (every iteration)")
    for l in AC_LS:
        pts = [(r["control_steps"], r["avg_reward"]) for v in ac.values() for r in v["rows"] if r["l"] == l]
        if pts:
            xs, ys = zip(*pts)
            b.scatter(xs, ys, color=colors[l], s=18, zorder=3, label=f"actor-critic, l = {l} (each seed)")
    for ax, title in ((a, "average reward per control step during learning"),
                      (b, "deterministic policy, 10 s trial: average reward per step")):
        ax.set_xscale("log")
        ax.set_xlabel("control steps (all environments)")
        ax.set_title(title, fontsize=10)
        ax.axhline(0, color="0.7", lw=0.6)
    a.legend(fontsize=8, loc="lower right")  # the curves end high on the right; the low right is empty
    b.legend(fontsize=8, loc="upper left")
    for v, l in ((3.28, 1), (4.59, 10)):  # the paper's Fig. 3 after 10^5 trials, labelled where no curve is
        a.axhline(v, color=colors[l], ls=":", lw=0.8)
        a.annotate(f"paper, l = {l}: {v}", (0.01, v), xycoords=("axes fraction", "data"), ha="left", va="bottom",
                   fontsize=7, color=colors[l])
    fig.tight_layout()
    save(fig, path, format="png")


def _mean_line(ax, series: list[list[tuple[float, float]]], color: str, label: str) -> None:
    """The mean over seeds at the x values every seed has (the seeds share their x grid)."""
    series = [s for s in series if s]
    if not series:
        return
    n = min(len(s) for s in series)
    x = np.array([p[0] for p in series[0][:n]])
    y = np.mean([[p[1] for p in s[:n]] for s in series], axis=0)
    ax.plot(x, y, color=color, lw=1.8, label=f"{label}, mean of {len(series)}")


def publish_seed(src: pathlib.Path, dest: pathlib.Path) -> None:
    """Copy one seed's config, metrics and resumes to ``dest``, and its parameters (compact.npz)
    only while it is unfinished (its metrics short of its config's budget: baseline_ppo.finished_step);
    a finished seed's published compact.npz is removed."""
    from nmrl.experiments import baseline_config as bc, baseline_ppo as bp

    same = dest.exists() and src.resolve() == dest.resolve()
    for name in (store.CONFIG_FILE, store.METRICS_FILE, store.RESUMES_FILE):
        if (src / name).is_file() and not same:
            store.atomic_copy(src / name, dest / name)
    if (dest / store.CONFIG_FILE).is_file() and bp.finished_step(dest, bc.load_config(dest)) is not None:
        (dest / store.COMPACT_FILE).unlink(missing_ok=True)
    elif (src / store.COMPACT_FILE).is_file() and not same:
        store.atomic_copy(src / store.COMPACT_FILE, dest / store.COMPACT_FILE)


def gaits(dest: pathlib.Path, ppo: dict[int, list[dict]], ac_gaits: pathlib.Path, at_steps: float,
          src_root: pathlib.Path) -> dict:
    """The best PPO seed's gait and the side-by-side picture (see the module docstring); {} until
    every seed has ``at_steps`` control steps."""
    if not ppo or any(rows[-1]["step"] < at_steps for rows in ppo.values()):
        return {}
    from nmrl.experiments import baseline_brax as bb

    best = max(ppo, key=lambda s: ppo[s][-1]["eval_avg_reward"])
    src, d = src_root / f"ppo_s{best}", dest / "gaits" / "ppo_best"
    old = json.loads((d / "eval.json").read_text()) if (d / "eval.json").is_file() else None
    if old is None or pathlib.Path(old["run_dir"]).name != src.name or old["step"] != ppo[best][-1]["step"]:
        old = bb.evaluate_checkpoint(src, seconds=10.0, render=True, out_dir=d)  # from the run's parameters
    panels = [(f"Brax PPO, seed {best}, {old['step']:,} control steps", d / "strobe.png")]
    for l in AC_LS:
        e = ac_gaits / f"l{l}_best" / "eval.json"
        if e.is_file():
            ev = json.loads(e.read_text())
            panels.append((f"nm-period actor-critic, l = {l}, {pathlib.Path(ev['run_dir']).name}, "
                           f"{ev['trials']:,} trials", e.parent / "strobe.png"))
    side_by_side(panels, dest / "gaits.png")
    return {"ppo_best_seed": best, "step": old["step"], "deterministic": old["deterministic"]["avg_reward"],
            "forward_speed": old["deterministic"]["forward_speed"], "panels": [t for t, _ in panels]}


def side_by_side(panels: list[tuple[str, pathlib.Path]], path: pathlib.Path) -> None:
    """The strobe pictures ``panels`` (title, png) one above the other in one figure."""
    from nmrl.analysis.plots import plt, save

    imgs = [plt.imread(p) for _, p in panels]
    width = max(i.shape[1] for i in imgs) / 100
    fig, axes = plt.subplots(len(imgs), 1, figsize=(width, sum(i.shape[0] / 100 + 0.3 for i in imgs)), dpi=100,
                             squeeze=False)
    for ax, (title, _), img in zip(axes[:, 0], panels, imgs):
        ax.imshow(img)
        ax.set_axis_off()
        ax.set_title(title, fontsize=11)
    fig.tight_layout()
    save(fig, path, format="png")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--src", type=pathlib.Path, default=ROOT / "runs" / "baseline_ppo")
    ap.add_argument("--dest", type=pathlib.Path, default=ROOT / "results" / "baseline_ppo")
    ap.add_argument("--ac-points", type=pathlib.Path, default=ROOT / "results" / "fig3_paper" / "points")
    ap.add_argument("--ac-gaits", type=pathlib.Path, default=ROOT / "results" / "fig3_paper" / "gaits")
    ap.add_argument("--gait-steps", type=float, default=2.5e7,
                    help="render the gaits once every PPO seed has this many control steps (default 2.5e7)")
    a = ap.parse_args()
    ppo = ppo_runs(a.src)
    if not ppo:
        raise SystemExit(f"publish_baseline_ppo: error: no PPO run with metrics under {a.src}")
    a.dest.mkdir(parents=True, exist_ok=True)
    for s in ppo:
        publish_seed(a.src / f"ppo_s{s}", a.dest / f"ppo_s{s}")
    ac_file = a.dest / "ac_milestones.json"
    ac = json.loads(ac_file.read_text()) if ac_file.is_file() else {}
    summ = summary(ppo, ac)
    bench = ROOT / "results" / "benchmarks" / "results.json"
    if bench.is_file():
        ba = json.loads(bench.read_text()).get("baseline") or {}
        summ["hours_per_1e7_steps"] = ba.get("hours_per_1e7_steps")
    summ["ppo_steps_reached"] = {s: rows[-1]["step"] for s, rows in ppo.items()}
    summ["gaits"] = gaits(a.dest, ppo, a.ac_gaits, a.gait_steps, a.src)
    store.atomic_write_json(a.dest / "summary.json", summ)
    draw(ppo, ac_curves(a.ac_points), ac, a.dest / "comparison.png")
    print(table(summ))


if __name__ == "__main__":
    main()
