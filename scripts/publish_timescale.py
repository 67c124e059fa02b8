"""Copy a finished finer-delta study (nmrl/experiments/study.py) into results/ and print its tables as Markdown.

    python scripts/publish_timescale.py runs/timescale results/timescale

Copies study.json, grid.csv, final.csv, gradvar.csv, timescale.png, grid.png and every point's
metrics.jsonl (grid/ and final/, no checkpoints), then prints the tables of docs/timescale.md: reward per second
(mean and 95% t-interval over seeds) per delta and arm, the change from 0.02 s, the chosen step
sizes, and the gradient statistics.
"""

from __future__ import annotations

import pathlib
import shutil
import sys

import numpy as np

from nmrl.analysis.plots import arm_order
from nmrl.analysis.stats import mean_ci95
from nmrl.runs.store import read_csv


def main(src: str, dst: str) -> None:
    src_p, dst_p = pathlib.Path(src), pathlib.Path(dst)
    dst_p.mkdir(parents=True, exist_ok=True)
    for f in ("study.json", "grid.csv", "final.csv", "gradvar.csv", "timescale.png", "grid.png"):
        if (src_p / f).exists():
            shutil.copy2(src_p / f, dst_p / f)
    for m in src_p.glob("*/dt*/points/*/metrics.jsonl"):
        rel = m.relative_to(src_p)
        out = dst_p / "metrics" / rel.parts[0] / rel.parts[1] / f"{rel.parts[3]}.jsonl"
        out.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(m, out)
    final = read_csv(src_p / "final.csv")
    grid = read_csv(src_p / "grid.csv")
    dts = sorted({float(r["dt"]) for r in final}, reverse=True)
    arms = arm_order(final)
    print("| arm | " + " | ".join(f"δ = {d:g} s" for d in dts) + " | change 0.02 → finest |")
    print("|---|" + "---|" * (len(dts) + 1))
    for a in arms:
        cells, means = [], []
        for d in dts:
            rows = [r for r in final if r["arm"] == a and float(r["dt"]) == d]
            v = np.array([float(r["reward_per_s"]) for r in rows])
            m, c = mean_ci95(v)
            div = sum(bool(r["diverged"]) for r in rows)
            col = sum(bool(r.get("collapsed")) for r in rows)
            g = [r for r in grid if r["arm"] == a and float(r["dt"]) == d and r["chosen"]][0]
            cells.append(f"{m:+.1f} ± {c:.1f} ({', '.join(f'{x:+.0f}' for x in v)})"
                         + (f" {div} div." if div else "") + (f", {col} collapsed" if col else "")
                         + f"<br>β = {float(g['beta_theta']):.2g}, {float(g['beta_v']):.2g}")
            means.append(m)
        print(f"| {a} | " + " | ".join(cells) + f" | {means[-1] - means[0]:+.1f} |")
    gv = src_p / "gradvar.csv"
    if gv.exists():
        rows = read_csv(gv)
        print()
        print("| policy | arm | " + " | ".join(f"tr Cov, SNR/s at δ = {d:g}" for d in dts) + " |")
        print("|---|---|" + "---|" * len(dts))
        for p in sorted({r["policy"] for r in rows}):
            for a in arms:
                cells = []
                for d in dts:
                    r = [x for x in rows if x["policy"] == p and x["arm"] == a and float(x["dt"]) == d]
                    if r:
                        r = r[0]
                        cells.append(f"{float(r['trcov']):.3g} ± {float(r['trcov_ci']):.2g}, {float(r['snr_per_s']):.3g}")
                    else:
                        cells.append("")
                print(f"| {p} | {a} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit("usage: python scripts/publish_timescale.py STUDY_DIR RESULTS_DIR")
    main(sys.argv[1], sys.argv[2])
