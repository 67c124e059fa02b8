"""Publish a sweep's results under results/: CSV, Fig. 3, learning curves, best policies, gaits.

    python scripts/publish/publish_fig3.py runs/fig3_fast results/fig3_fast [--ls 1 10] [--seconds 10]

Copies results.csv, sweep.json, fig3.png and every point's metrics.jsonl; for each l in --ls takes
the seed with the highest avg_reward, publishes its newest checkpoint's *policy* (actor and critic
parameters and counters as ``compact.npz``, ~40 kB: ``nmrl eval`` restores it; the full training
state stays in the sweep directory) and evaluates it with ``nmrl.analysis.evaluate`` (JSON, strobe PNG, GIF). Every
file is written atomically (a policy directory is built beside its place and renamed into it).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import shutil

from nmrl import options
from nmrl.analysis import evaluate
from nmrl.experiments import sweep
from nmrl.runs import checkpoint, store


def copy_policy(point: pathlib.Path, dest: pathlib.Path) -> pathlib.Path:
    """The point's newest checkpoint's policy (actor and critic parameters, step and trials) as
    ``dest/compact.npz`` (:func:`nmrl.runs.checkpoint.save_compact_policy`, ~40 kB; ``nmrl eval``
    reads it), with the point's config and metrics: built in a temporary directory beside ``dest``
    and renamed into place, so ``dest`` is either the old or the new copy. The full training state
    stays in the sweep directory."""
    meta = checkpoint.load_metadata(point)
    config, theta, v = checkpoint.restore_policy(point)
    tmp = dest.with_name(f".{dest.name}.{os.getpid()}.tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    checkpoint.save_compact_policy(tmp, config, theta, v, step=int(meta["step"]), trials=int(meta["trials"]))
    shutil.copy2(point / "config.json", tmp / "config.json")
    shutil.copy2(point / "metrics.jsonl", tmp / "metrics.jsonl")
    old = dest.with_name(f".{dest.name}.{os.getpid()}.old")
    if dest.exists():
        os.replace(dest, old)
    os.replace(tmp, dest)
    shutil.rmtree(old, ignore_errors=True)
    return dest


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sweep_dir")
    ap.add_argument("dest")
    ap.add_argument("--ls", type=int, nargs="+", default=[1, 10])
    ap.add_argument("--seconds", type=float, default=10.0)
    args = ap.parse_args()
    src, dest = pathlib.Path(args.sweep_dir), pathlib.Path(args.dest)
    dest.mkdir(parents=True, exist_ok=True)
    results = sweep.write_results(src, sweep.SweepSpec(**_spec(src)))
    for name in (sweep.RESULTS_FILE, sweep.SPEC_FILE):
        store.atomic_copy(src / name, dest / name)
    sweep.draw(src, results, dest / "fig3.png")
    for r in results:
        store.atomic_copy(sweep.point_dir(src, r["l"], r["seed"]) / "metrics.jsonl",
                          dest / "points" / f"l{r['l']}_s{r['seed']}" / "metrics.jsonl")
    summary = {}
    for l in args.ls:
        rows = [r for r in results if r["l"] == l and not r["diverged"] and r["checkpoint"]]
        if not rows:
            continue
        best = max(rows, key=lambda r: r["avg_reward"])
        pol = copy_policy(sweep.point_dir(src, l, best["seed"]), dest / "policies" / f"l{l}_best")
        ev = evaluate.evaluate(pol, seconds=args.seconds, seed=0, render=True)
        summary[f"l{l}"] = {"seed": best["seed"], "sweep_avg_reward": best["avg_reward"], "eval": ev}
        print(f"l={l} seed={best['seed']}: deterministic {ev['deterministic']['avg_reward']:+.3f} "
              f"({ev['deterministic']['forward_speed']:+.2f} m/s), exploring {ev['exploring']['avg_reward']:+.3f}")
    store.atomic_write_text(dest / "best_policies.json", json.dumps(summary, indent=2, default=str) + "\n")


def _spec(src: pathlib.Path) -> dict:
    from nmrl.learners.ac_config import TrainConfig

    s = json.loads((src / sweep.SPEC_FILE).read_text())
    return {"ls": tuple(s["ls"]), "seeds": s["seeds"], "base": options.build(TrainConfig, **s["base"])}


if __name__ == "__main__":
    main()
