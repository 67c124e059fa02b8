"""The finer-delta study's publisher (docs/timescale.md): a study directory into results/, figures and tables.

:func:`publish` copies a finished study (nmrl/experiments/study.py) into a record: ``study.json``,
``grid.csv``, ``final.csv``, ``gradvar.csv`` and every point's metrics (``metrics/<phase>/dt<δ>/<point>.jsonl``;
no checkpoints), then draws the record's figures from it (:func:`figures`: ``timescale.png`` and
``grid.png`` by nmrl.analysis.plots.timescale, the same function the study's plot phase calls, so a
record makes its own figures again byte for byte). :func:`tables` is the record's numbers as the
Markdown tables of docs/timescale.md: reward per second (mean and 95% t-interval over seeds) per δ
and arm with the change from 0.02 s and the chosen step sizes, and the gradient statistics.

    .venv/bin/python scripts/publish/publish_timescale.py STUDY_DIR RESULTS_DIR   # copy, draw, print the tables
    .venv/bin/python scripts/publish/publish_timescale.py RESULTS_DIR             # draw and print from the record
"""

from __future__ import annotations

import pathlib
import shutil

import numpy as np

from nmrl.analysis import plots
from nmrl.analysis.stats import mean_ci95
from nmrl.runs.store import read_csv, read_jsonl

TABLES = ("study.json", "grid.csv", "final.csv", "gradvar.csv")


def publish(src: pathlib.Path, dest: pathlib.Path) -> None:
    """Copy the study ``src``'s tables and its points' metrics into ``dest``, then draw its figures."""
    src, dest = pathlib.Path(src), pathlib.Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    for f in TABLES:
        if (src / f).exists():
            shutil.copy2(src / f, dest / f)
    for m in src.glob("*/dt*/points/*/metrics.jsonl"):
        rel = m.relative_to(src)
        out = dest / "metrics" / rel.parts[0] / rel.parts[1] / f"{rel.parts[3]}.jsonl"
        out.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(m, out)
    figures(dest)


def figures(record: pathlib.Path) -> None:
    """``timescale.png`` and ``grid.png`` of a record, drawn from its tables and its final runs' metrics."""
    record = pathlib.Path(record)
    final = read_csv(record / "final.csv")
    gradvar = read_csv(record / "gradvar.csv") if (record / "gradvar.csv").exists() else []
    curves: dict = {}
    for r in final:
        f = record / "metrics" / "final" / f"dt{float(r['dt']):g}" / f"{r['arm']}_s{r['seed']}.jsonl"
        curves.setdefault((r["arm"], float(r["dt"])), []).append(read_jsonl(f))
    plots.timescale(record, read_csv(record / "grid.csv"), final, gradvar, curves)


def tables(record: pathlib.Path) -> str:
    """The record's reward and gradient tables as Markdown (docs/timescale.md)."""
    record = pathlib.Path(record)
    final, grid = read_csv(record / "final.csv"), read_csv(record / "grid.csv")
    dts = sorted({float(r["dt"]) for r in final}, reverse=True)
    arms = plots.arm_order(final)
    out = ["| arm | " + " | ".join(f"δ = {d:g} s" for d in dts) + " | change 0.02 → finest |",
           "|---|" + "---|" * (len(dts) + 1)]
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
        out.append(f"| {a} | " + " | ".join(cells) + f" | {means[-1] - means[0]:+.1f} |")
    if (record / "gradvar.csv").exists():
        rows = read_csv(record / "gradvar.csv")
        out += ["", "| policy | arm | " + " | ".join(f"tr Cov, SNR/s at δ = {d:g}" for d in dts) + " |",
                "|---|---|" + "---|" * len(dts)]
        for p in sorted({r["policy"] for r in rows}):
            for a in arms:
                cells = []
                for d in dts:
                    r = [x for x in rows if x["policy"] == p and x["arm"] == a and float(x["dt"]) == d]
                    cells.append(f"{float(r[0]['trcov']):.3g} ± {float(r[0]['trcov_ci']):.2g}, "
                                 f"{float(r[0]['snr_per_s']):.3g}" if r else "")
                out.append(f"| {p} | {a} | " + " | ".join(cells) + " |")
    return "\n".join(out) + "\n"

