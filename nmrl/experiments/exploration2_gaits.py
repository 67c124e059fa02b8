"""The gaits of the best and the worst arm at 2.5 ms (docs/exploration-study-2.md, "Published").

Once every arm's 2.5 ms grid cell is complete (:data:`GAIT_ARMS`: W, Ws, OU, CN, NMs, NMp), the arms
are ranked by their cell's mean deterministic reward per second (the primary endpoint). For the best
and the worst arm, the run whose endpoint is the cell's median (the lower one of the middle two at
an even count) is the arm's typical policy: its deterministic policy is rolled out for the full
10 s from the robot's start and drawn (nmrl/experiments/kit_gaits.py: ``eval.json``, the GIF, the
10-s strobe, ``gaits.json``). Each folder is made once per saved step of its run; the measurement
waits while a cell it needs is unfinished.
"""

from __future__ import annotations

import pathlib

import numpy as np

from nmrl.experiments import kit_gaits
from nmrl.experiments.exploration2_cells import grid_name
from nmrl.experiments.exploration2_rules import complete_cells
from nmrl.experiments.kit_gaits import GAITS, STROBE_10S

__all__ = ["GAITS", "GAIT_ARMS", "STROBE_10S", "chosen", "gaits"]

GAIT_DT = 0.0025
GAIT_ARMS = ("white", "ws", "ou", "colored", "nms", "nmp")


def chosen(rows: list[dict]) -> list[dict] | None:
    """``[best, worst]``, each {rank, arm, cell, point, seed, det_reward_per_s, cell_mean}; None
    while any 2.5 ms grid cell of :data:`GAIT_ARMS` is incomplete."""
    cells = complete_cells(rows)
    names = {arm: grid_name(arm, GAIT_DT) for arm in GAIT_ARMS}
    if any(n not in cells for n in names.values()):
        return None
    means = {arm: float(np.mean(cells[n])) for arm, n in names.items()}
    order = sorted(GAIT_ARMS, key=lambda a: means[a])
    return [kit_gaits.pick((r for r in rows if r["cell"] == names[arm]), rank=rank, arm=arm, cell=names[arm],
                           cell_mean=means[arm]) for rank, arm in (("best", order[-1]), ("worst", order[0]))]


def gaits(out: pathlib.Path, rows: list[dict]) -> None:
    """The measurement of the module docstring: ``out/gaits/<rank>_<arm>/`` and ``out/gaits/gaits.json``."""
    pick = chosen(rows)
    if pick is not None:
        kit_gaits.draw(out, [{"name": f"{c['rank']}_{c['arm']}", **c} for c in pick],
                       lambda c: f"{c['arm']} at 2.5 ms (the {c['rank']} arm), seed {c['seed']}, deterministic policy")
