"""Publish the exploration study under results/exploration/.

    .venv/bin/python scripts/publish_exploration.py [--src runs/exploration] [--dest results/exploration]

Copies the tables (study.json, results.csv, control.csv, screen.csv, snr.csv, summary.json) and every cell's
continuation files (nmrl.analysis.exploration_results.publish: what `scripts/exploration_study.sh`
seeds a fresh clone from), writes ``answers.md`` (the numbers as tables: progress, rewards per
cell, the answers, the samples-per-update control, the SNR, the screen), draws ``learning_curves.png``
(one panel per control step), ``summary.png`` (final rewards and the gradient's SNR against the
control step) and ``control.png`` (the control's learning curves) and, once
every run at the finest control step is over, the gaits of its best and worst process
(``gaits/<process>/``: `nmrl eval`'s strobe picture, GIF, trajectory and JSON of the median seed,
10 s from seed 0; evaluated once), and the two strobes one above the other at one scale in
``gaits/best_and_worst.png``.
"""

from __future__ import annotations

import argparse
import json
import pathlib

from nmrl.analysis import exploration_results as xr
from nmrl.experiments import exploration_study as es
from nmrl.runs import store

ROOT = pathlib.Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--src", default=str(ROOT / "runs" / "exploration"))
    ap.add_argument("--dest", default=str(ROOT / "results" / "exploration"))
    a = ap.parse_args()
    src, dest = pathlib.Path(a.src), pathlib.Path(a.dest)
    written = xr.publish(src, dest)
    spec = es.StudySpec.from_json(json.loads((src / es.SPEC_FILE).read_text()))
    rows = store.read_csv(src / "results.csv") if (src / "results.csv").exists() else []
    if rows:
        xr.draw(src, rows, spec.dts, es.PROCESSES, dest / "learning_curves.png")
        tables = {n: store.read_csv(src / f"{n}.csv") if (src / f"{n}.csv").exists() else [] for n in ("screen", "snr")}
        summary = json.loads((src / "summary.json").read_text())
        store.atomic_write_text(dest / "answers.md", xr.report(summary, rows, tables["screen"], tables["snr"],
                                                               spec.dts, es.PROCESSES, spec.iterations))
        xr.draw_summary(rows, tables["snr"], spec.dts, es.PROCESSES, spec.iterations, dest / "summary.png")
        if summary.get("control"):
            xr.draw_control(summary["control"], dest / "control.png")
        fine = min(spec.dts)
        done = [r for r in xr.finished(rows, spec.iterations) if float(r["control_dt"]) == fine]
        picks = xr.best_and_worst(done, fine, es.PROCESSES) if len(done) == spec.seeds * len(es.PROCESSES) else None
        titles = []
        for (proc, seed), rank in zip(picks or [], ("best", "worst")):
            out = dest / "gaits" / proc
            if not (out / "trajectory.npz").exists():
                from nmrl.analysis import evaluate

                run = src / "grid" / f"dt{fine:g}" / proc / "points" / f"s{seed}"
                evaluate.evaluate(run, seconds=10.0, seed=0, render=True, out_dir=out)
                print(f"gait of {proc} at {fine:g} s (seed {seed}) in {out}")
            titles.append((f"{rank} at δ = {fine * 1000:g} ms: {proc} (its median seed, {seed}; deterministic "
                           f"policy)", out / "trajectory.npz"))
        if titles:
            xr.draw_gaits(titles, dest / "gaits" / "best_and_worst.png")
    print(f"{len(written)} files under {dest}; {len(rows)} runs in results.csv")


if __name__ == "__main__":
    main()
