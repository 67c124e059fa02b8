"""The nm-period actor-critic's deterministic policies at a sample budget, for the PPO comparison.

    python scripts/lab/ac_milestones.py --src runs/ac_1e6 --label 1e6                 # a sweep directory
    python scripts/lab/ac_milestones.py --git-rev REV --label 1e7                     # published compact states
    python scripts/lab/ac_milestones.py --src results/fig3_paper --label 2.5e7

For every point l{l}_s{seed} of ``--ls`` (default 1 and 10) under SRC/points/ (a sweep directory
with checkpoints, or published compact states: ``nmrl eval`` reads either), or under
results/fig3_paper/points/ as committed at ``--git-rev``, evaluates the deterministic policy for
``--seconds`` (10 s, seed 0; nmrl.analysis.evaluate) and records the control steps it was trained
on (steps per environment x environments), its trials, its average reward per step, forward
speed and gait (stride frequency and length per paw, wrist on the ground:
nmrl.analysis.evaluate.gait). The rows are merged into ``--out``
(results/baseline_ppo/ac_milestones.json) under ``--label``, written atomically.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import subprocess
import tempfile

from nmrl.analysis import evaluate
from nmrl.runs import checkpoint, store

ROOT = pathlib.Path(__file__).resolve().parents[2]
PUBLISHED = "results/fig3_paper/points"


def _from_git(rev: str, ls: list[int], seeds: int, dest: pathlib.Path) -> pathlib.Path:
    for l in ls:
        for s in range(seeds):
            d = dest / "points" / f"l{l}_s{s}"
            d.mkdir(parents=True)
            for name in (store.CONFIG_FILE, store.COMPACT_FILE):
                blob = subprocess.run(["git", "show", f"{rev}:{PUBLISHED}/l{l}_s{s}/{name}"], cwd=ROOT,
                                      check=True, capture_output=True).stdout
                (d / name).write_bytes(blob)
    return dest


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--src", type=pathlib.Path, help="a sweep directory (SRC/points/l{l}_s{seed})")
    src.add_argument("--git-rev", help="take results/fig3_paper/points as committed at this revision")
    ap.add_argument("--label", required=True, help="the budget's name in the output, e.g. 1e6")
    ap.add_argument("--ls", type=int, nargs="+", default=[1, 10])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--out", type=pathlib.Path, default=ROOT / "results" / "baseline_ppo" / "ac_milestones.json")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        base = _from_git(a.git_rev, a.ls, a.seeds, pathlib.Path(tmp)) if a.git_rev else a.src
        rows = []
        for l in a.ls:
            for s in range(a.seeds):
                point = base / "points" / f"l{l}_s{s}"
                cfg = checkpoint.load_run_config(point)
                ev = evaluate.evaluate(point, seconds=a.seconds, seed=0, render=False,
                                       out_dir=pathlib.Path(tmp) / "eval" / point.name)
                det = ev["deterministic"]
                rows.append({"l": l, "seed": s, "steps_per_env": ev["step"], "num_envs": cfg.budget.num_envs,
                             "control_steps": ev["step"] * cfg.budget.num_envs, "trials": ev["trials"],
                             "avg_reward": det["avg_reward"], "forward_speed": det["forward_speed"],
                             "gait": det["gait"], "source": a.git_rev or str(a.src)})
                hind = det["gait"]["hind_paw"]
                print(f"{a.label}: l={l} seed={s} {rows[-1]['control_steps']:,} control steps, {ev['trials']:,} "
                      f"trials: {det['avg_reward']:+.3f} per step, {det['forward_speed']:+.2f} m/s, hind paw "
                      f"{hind['stride_frequency_hz']:.2f} Hz x {hind['stride_length_m'] or float('nan'):.2f} m")
    out = json.loads(a.out.read_text()) if a.out.is_file() else {}
    out[a.label] = {"seconds": a.seconds, "rows": rows}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    store.atomic_write_json(a.out, out)


if __name__ == "__main__":
    main()
