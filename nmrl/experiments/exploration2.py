"""The second exploration x control-step study (docs/exploration-study-2.md) on the kit: its cells
(nmrl/experiments/exploration2_cells.py), the rules that add the later ones
(nmrl/experiments/exploration2_rules.py), the gradient's SNR at matched policies (:func:`snr`),
the gaits of the best and worst arm at 2.5 ms (nmrl/experiments/exploration2_gaits.py), each
grid policy with its noise scaled (nmrl/experiments/exploration2_noise.py), the analysis and
report (nmrl/experiments/exploration2_analysis.py), and its command.

    python -m nmrl.experiments.exploration2 run --out runs/exploration2 [--published results/exploration2/runs]
    python -m nmrl.experiments.exploration2 publish --out runs/exploration2 --dest results/exploration2/runs
    python -m nmrl.experiments.exploration2 progress --out runs/exploration2   # each cell's chunks and time left
"""

from __future__ import annotations

import json
import pathlib
import sys

from nmrl.experiments import kit, kit_cli
from nmrl.experiments.exploration2_analysis import analysis, report
from nmrl.experiments.exploration2_cells import (ENDPOINT, SIGMA_SCREEN, SNR_CSV, SNR_POLICY_ITERATIONS, SNR_SEEDS,
                                                 grid_name, snr_name)
from nmrl.experiments.exploration2_gaits import GAITS, gaits
from nmrl.experiments.exploration2_noise import NOISE_CSV, noise_scales
from nmrl.experiments.exploration2_rules import complete_cells, later_cells


def snr(out: pathlib.Path, rows: list[dict]) -> None:
    """The gradient's SNR at matched policies (nmrl/experiments/matched_snr.py) into ``snr.csv``:
    white's 20 ms policies of seeds 0-2 after 0, 4, 8 and 16 iterations, at 20, 5 and 2.5 ms, with
    white at their own sigma and NMp with its chosen settings at each control step (20 ms: its 20 ms
    choice; 5 and 2.5 ms: its 2.5 ms one). Waits until those cells are complete."""
    from nmrl.experiments import matched_snr

    cells = complete_cells(rows)
    need = [*(snr_name(it) for it in SNR_POLICY_ITERATIONS), grid_name("white", 0.02), grid_name("nmp", 0.02),
            grid_name("nmp", 0.0025)]
    if any(c not in cells for c in need):
        return

    def points(cell: str) -> dict[int, pathlib.Path]:
        return {int(r["seed"]): out / cell / "points" / r["point"] for r in rows
                if r["cell"] == cell and int(r["seed"]) < SNR_SEEDS}

    def config(cell: str) -> dict:
        return json.loads((next(iter(points(cell).values())) / "config.json").read_text())

    by_it = {0: points(snr_name(1)), 4: points(snr_name(4)), 8: points(snr_name(8)),
             16: points(grid_name("white", 0.02))}
    white = matched_snr.exploration_of(config(grid_name("white", 0.02)))
    nmp20, nmp_fine = (matched_snr.exploration_of(config(grid_name("nmp", dt))) for dt in (0.02, 0.0025))
    arms = {"white": {dt: white for dt in matched_snr.DTS},
            "nmp": {dt: nmp20 if dt == 0.02 else nmp_fine for dt in matched_snr.DTS}}
    matched_snr.measure(by_it, arms, out / SNR_CSV)


STUDY = kit.Study(name="exploration2", cells=SIGMA_SCREEN, endpoint=ENDPOINT, later=later_cells, analysis=analysis,
                  report=report, measurements=(kit.Measurement(SNR_CSV, snr), kit.Measurement(GAITS, gaits),
                                               kit.Measurement(NOISE_CSV, noise_scales)))


def main(argv: list[str] | None = None) -> int:
    return kit_cli.main(STUDY, argv, "python -m nmrl.experiments.exploration2", __doc__.split("\n\n")[0])


if __name__ == "__main__":
    sys.exit(main())
