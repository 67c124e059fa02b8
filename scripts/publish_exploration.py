"""Publish the exploration study under results/exploration/.

    .venv/bin/python scripts/publish_exploration.py [--src runs/exploration] [--dest results/exploration]

Copies the tables (study.json, results.csv, screen.csv, snr.csv, summary.json) and every cell's
continuation files (nmrl.analysis.exploration_results.publish: what `scripts/exploration_study.sh`
seeds a fresh clone from) and draws ``learning_curves.png`` (one panel per control step).
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
    print(f"{len(written)} files under {dest}; {len(rows)} runs in results.csv")


if __name__ == "__main__":
    main()
