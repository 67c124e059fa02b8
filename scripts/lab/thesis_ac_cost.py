"""The third study's cost per chunk, measured before its registration (docs/thesis-actor-critic.md,
"Compute"): each cell of nmrl/experiments/thesis_ac_cells.py (the grid at 20, 5 and 2.5 ms, the
step-size check) run for ``--chunks`` chunks in a scratch directory by the kit, as the study runs it
(one ``nmrl sweep`` process per cell, its points grouped per device), and the wall seconds of each
chunk after the first (the first compiles) read from the points' metrics; then the study's total at
the registered budget.

    python scripts/lab/thesis_ac_cost.py --out /tmp/thesis_ac_cost [--chunks 3]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import statistics

from nmrl.experiments import kit
from nmrl.experiments.thesis_ac_cells import CELLS, CHUNK_S, SECONDS_PER_ENV


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--chunks", type=int, default=3)
    a = ap.parse_args()
    out = pathlib.Path(a.out)
    total = 0.0
    for cell in CELLS:
        short = dataclasses.replace(cell, steps=round(cell.steps * a.chunks * CHUNK_S / SECONDS_PER_ENV))
        kit.run(kit.Study(name="cost", cells=(short,), endpoint=None), out)
        walls = []
        for m in sorted((out / cell.name / "points").glob("*/metrics.jsonl")):
            rows = [json.loads(line) for line in m.read_text().splitlines() if line.strip()]
            walls.append([r["wall_s"] for r in rows])
        per_chunk = statistics.median(w for ws in walls for w in ws[1:])
        chunks = SECONDS_PER_ENV / CHUNK_S
        total += per_chunk * chunks
        print(f"{cell.name}: {len(walls)} points, {per_chunk:.1f} s per chunk after the first "
              f"(first {statistics.median(ws[0] for ws in walls):.1f} s); {chunks:.0f} chunks: "
              f"{per_chunk * chunks / 3600:.2f} h", flush=True)
    print(f"the study at its budget: {total / 3600:.1f} h of wall time on this machine")


if __name__ == "__main__":
    main()
