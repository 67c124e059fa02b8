"""The finer-delta study's cells as data (nmrl/experiments/study.py) and its rule for the final cells.

At every control step delta the study runs two cells of the kit (nmrl/experiments/kit.py), each one
``nmrl sweep --points`` (one compiled program: the arms differ only in the actor-critic's traced
fields l and lambda, the grid's pairs in beta^theta and beta^v):

* ``grid/dt{delta}``: every arm x (beta^theta, beta^v) pair of the grid, one seed (0), the grid's
  budget in simulated seconds (:meth:`TimescaleSpec.grid_points`);
* ``final/dt{delta}``: every arm x seed at the arm's chosen pair, the final budget
  (:meth:`TimescaleSpec.final_points`); made by :func:`final_cells` once every delta's grid is
  finished (the rule: nmrl/experiments/timescale_tables.py ``grid_rows``).

A point lists every config field that differs from the actor-critic's defaults (the conversions of
nmrl/experiments/timescale.py, the study's sizes and physics) and its seed; the budget is the cell's
``--steps``, so a larger ``--final-seconds`` continues the final cells from their saved points.
"""

from __future__ import annotations

import pathlib
from typing import Callable, Sequence

from nmrl import options
from nmrl.experiments import kit
from nmrl.experiments.sweep import BUDGET_FIELDS
from nmrl.experiments.timescale import TimescaleSpec
from nmrl.experiments.timescale_tables import FINAL, GRID, cell_name, chosen_betas, grid_rows
from nmrl.learners.ac_config import TrainConfig


def points_of(names: Sequence[str], configs: Sequence[TrainConfig]) -> tuple[dict, ...]:
    """Each config as a point of ``nmrl sweep --points``: its name, its seed and every other field
    (but the budget) that differs from the actor-critic's defaults."""
    default = TrainConfig()
    keep = [k for k in options.leaves(TrainConfig) if k not in (*BUDGET_FIELDS, "seed")]
    changed = [{k: v for k, v in options.flat(c).items() if k in keep and v != options.value(default, k)} for c in configs]
    return tuple({"name": n, **d, "seed": c.budget.seed} for n, c, d in zip(names, configs, changed))


def points_cell(phase: str, dt: float, names: list[str], configs: list[TrainConfig]) -> kit.Cell:
    """The cell of ``phase`` at ``dt`` that runs ``configs`` (one budget) as points named ``names``."""
    return kit.Cell(cell_name(phase, dt), "ac", steps=configs[0].budget.steps, points=points_of(names, configs))


def grid_cells(spec: TimescaleSpec) -> tuple[kit.Cell, ...]:
    """The step-size grid, one cell per control step."""
    return tuple(points_cell(GRID, dt, *spec.grid_points(dt)) for dt in spec.dts)


def final_cells(spec: TimescaleSpec, out: pathlib.Path) -> Callable[[list[dict]], list[kit.Cell]]:
    """The rule: once the grid of every delta is finished (its points' metrics in ``out``), the final
    cells at each arm's chosen pair; none before."""

    def rule(rows: list[dict]) -> list[kit.Cell]:
        grid = grid_rows(out, spec)
        if not grid:
            return []
        return [points_cell(FINAL, dt, *spec.final_points(dt, chosen_betas(grid, dt))) for dt in spec.dts]

    return rule
