"""Publish PPO on HalfCheetah-v5 (native against Brax, the same settings) under results/standard_tasks/.

    .venv/bin/python scripts/publish/publish_standard_tasks.py [--src runs/standard_tasks] [--dest results/standard_tasks]

Reads, when ``--src`` exists, the runs of scripts/run/task_validation.sh (SRC/native: the native sweep;
SRC/brax/ppo_s{seed}: the Brax runs) and copies into DEST what a fresh clone needs to continue them
and what the figures are drawn from: ``native/{sweep.json, points/s{seed}/{config.json,
metrics.jsonl, compact.npz, eval.json}}`` (eval.json: ``nmrl eval SRC/native/points/s{seed}``, when
present) and ``brax/ppo_s{seed}/{config.json, metrics.jsonl, resumes.jsonl, compact.npz}``. Then,
from DEST alone (so that it regenerates the same bytes from the committed data), writes:

* ``learning_curves.csv``: learner, seed, control steps, return per episode during learning
  (nmrl/analysis/standard_tasks.py: 1,000 x the iteration's average reward per control step);
* ``learning_curves.png``: both learners' curves, each seed thin, the mean bold, the seed band
  (min..max over seeds) shaded;
* ``summary.json``: per iteration both reached, the native mean and the Brax band; the steps each
  seed reached; the deterministic returns at a common evaluated step and native - Brax (Welch 95%);
* ``deterministic.csv``: the same deterministic returns per learner and seed (when there are any).
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import pathlib

import numpy as np

from nmrl.analysis import ppo_validation as pv, standard_tasks as st
from nmrl.runs import store

ROOT = pathlib.Path(__file__).resolve().parents[2]


def copy_runs(src: pathlib.Path, dest: pathlib.Path) -> None:
    if (src / "native" / "sweep.json").is_file():
        store.atomic_copy(src / "native" / "sweep.json", dest / "native" / "sweep.json")
        for p in sorted((src / "native" / "points").glob("s*")):
            for name in ("config.json", "metrics.jsonl", "compact.npz"):
                if (p / name).is_file():
                    store.atomic_copy(p / name, dest / "native" / "points" / p.name / name)
            if (p / "eval" / "eval.json").is_file():
                store.atomic_copy(p / "eval" / "eval.json", dest / "native" / "points" / p.name / "eval.json")
    for d in sorted((src / "brax").glob("ppo_s*")):
        for name in ("config.json", "metrics.jsonl", "resumes.jsonl", "compact.npz"):
            if (d / name).is_file():
                store.atomic_copy(d / name, dest / "brax" / d.name / name)


def draw(native: st.Curves, brax: st.Curves, path: pathlib.Path) -> None:
    from nmrl.analysis.plots import plt, save

    fig, ax = plt.subplots(figsize=(8, 4.8), dpi=110)
    for name, curves, color in (("Brax PPO", brax, "C3"), ("native PPO", native, "C0")):
        if not curves:
            continue
        for i, (s, (x, y)) in enumerate(sorted(curves.items())):
            ax.plot(x, y, color=color, lw=0.7, alpha=0.45)
        steps, lo, hi = pv.band(curves)
        ax.fill_between(steps, lo, hi, color=color, alpha=0.2)
        mean = [np.mean([y[list(x).index(c)] for x, y in curves.values()]) for c in steps]
        ax.plot(steps, mean, color=color, lw=2, label=f"{name}: mean of {len(curves)} seeds, band min..max")
    ax.set_xlabel("control steps (all environments)")
    ax.set_ylabel("return per episode during learning")
    ax.set_title("HalfCheetah-v5: native PPO (white) vs Brax PPO, the same settings")
    ax.legend(loc="lower right")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    save(fig, path, metadata={"Software": None})


def _csv(rows: list[dict], fields: list[str]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: (f"{r[k]:.6g}" if isinstance(r[k], float) else r[k]) for k in fields})
    return buf.getvalue()


def publish(dest: pathlib.Path) -> dict:
    native = st.native_returns(dest / "native" / "points")
    runs = st.brax_runs(dest / "brax")
    brax = st.brax_returns(runs)
    evals = st.read_evals(dest / "native" / "points")
    sweep = dest / "native" / "sweep.json"
    num_envs = 64
    for p in sorted((dest / "native" / "points").glob("s*")):
        num_envs = int(json.loads((p / store.CONFIG_FILE).read_text())["num_envs"])
    store.atomic_write_text(dest / "learning_curves.csv",
                            _csv(st.curve_rows(native, brax), ["learner", "seed", "control_steps", "return_per_episode"]))
    draw(native, brax, dest / "learning_curves.png")
    out = st.summary(native, brax, evals, runs, num_envs) if sweep.is_file() or runs else {}
    store.atomic_write_json(dest / "summary.json", out)
    det = out.get("deterministic")
    if det:
        rows = [{"learner": name, "seed": int(s), "control_steps": det["control_steps"], "return_mean_10_episodes": v}
                for name in ("native", "brax") for s, v in det[name]["per_seed"].items()]
        store.atomic_write_text(dest / "deterministic.csv",
                                _csv(rows, ["learner", "seed", "control_steps", "return_mean_10_episodes"]))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--src", default="runs/standard_tasks")
    ap.add_argument("--dest", default="results/standard_tasks")
    a = ap.parse_args()
    src, dest = ROOT / a.src, ROOT / a.dest
    if src.is_dir():
        copy_runs(src, dest)
    out = publish(dest)
    print(json.dumps({k: out.get(k) for k in ("within_band", "of", "native_last_steps", "brax_last_steps")}))
    for r in out.get("iterations", []):
        print(f"{r['control_steps']:>9d}  native {r['native_mean']:+9.1f}  brax [{r['peer_lo']:+9.1f}, {r['peer_hi']:+9.1f}]"
              f"  {'within' if r['within'] else 'OUTSIDE'}")
    if out.get("deterministic"):
        print(json.dumps(out["deterministic"], indent=1))


if __name__ == "__main__":
    main()
