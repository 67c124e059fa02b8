"""Beyond the paper: does learning survive a finer time discretization?

The paper's thesis (Sec. III, eq. (1)): as the control step delta shrinks, a stationary policy
(white exploration noise, l = 1) learns worse, and nm-periods of a fixed *duration* do not. Its
experiment uses delta = 0.02 s only. This study runs delta in {0.02, 0.01, 0.005} s on the same
physics (5 ms MuJoCo steps, 4/2/1 per control step) and the same problem in continuous time
(nmrl/experiments/timescale.py: gamma, alpha, lambda, stop probability, Delta and rewards converted per second).

Arms, per delta: the stationary policy (l = 1) and nm-periods of 0.1, 0.2 and 0.4 s
(l = period / delta, e.g. 10, 20, 40 for 0.2 s).

The rule for step sizes (the same for every arm): a grid beta^theta x beta^v (one seed, a shorter
budget in simulated seconds) is run for every (delta, arm); the chosen pair is the one with the
highest average reward over the second half of its grid run (diverged runs are never chosen), among
the pairs with beta^theta <= ``beta_theta_cap`` if that is set. A study with a cap can reuse another
study's grid/ (copy it: finished points are never rerun); a final cell that holds other points than
the rule chooses is refused (move it away: the final cells run as one program each).
Every arm then runs ``seeds`` seeds at its chosen pair for the same budget in simulated seconds.

The study is written on the study kit (nmrl/experiments/kit.py): its cells, one ``nmrl sweep
--points`` per phase and delta, and the rule that makes the final cells from the grid are data
(nmrl/experiments/timescale_cells.py); its tables, the gradient measurement and the figures are
the kit's measurements (nmrl/experiments/timescale_tables.py), run in that order after the cells.
This module holds the settings check (``study.json``), the phases and the command.

Layout of ``OUT``::

    study.json                   the spec (refuses to continue a different one)
    grid/dt{delta}/              one ``nmrl sweep`` per delta (sweep.json, points/, results.csv): every
                                 arm x step-size pair as one vmapped program (nmrl.runs.driver.run_points)
    grid.csv                     every grid run: delta, arm, betas, score, diverged, chosen
    final/dt{delta}/             the chosen step sizes x seeds, one ``nmrl sweep`` per delta
    final.csv                    delta, arm, seed, betas, reward per second, speed, diverged
    gradvar.csv                  tr Cov of the per-period actor gradient estimate (nmrl/experiments/gradvar.py)
    timescale.png, grid.png      the figures (nmrl/analysis/plots.py)
    rows.csv                     the kit's row per point (nmrl/experiments/kit.py)

Every phase resumes where it stopped: run the same command again. A larger ``--final-seconds``
(everything else the same) extends the final runs from their last checkpoints.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
import sys
from typing import Sequence

from nmrl import options
from nmrl.experiments import kit
from nmrl.experiments.kit import StudyError
from nmrl.experiments.timescale import TimescaleSpec
from nmrl.experiments.timescale_cells import final_cells, grid_cells
from nmrl.experiments.timescale_tables import (FINAL, FINAL_CSV, GRADVAR_CSV, GRID, GRID_CSV, figures,
                                               grid_rows, measure, tables)
from nmrl.runs import command, lock, parser, store
from nmrl.tasks import EnvFields
from nmrl.runs.store import read_csv

SPEC_FILE = "study.json"
PHASES = ("grid", "final", "gradvar", "plot")
_GRADVAR_FIELDS = {"gradvar_envs", "gradvar_batches"}


def kit_study(spec: TimescaleSpec, out: pathlib.Path, phases: Sequence[str] = PHASES,
              progress: bool = True) -> kit.Study:
    """The study as the kit runs it: the grid cells, the rule for the final cells, no endpoint (its
    numbers are its own), and as measurements the tables, then (phases ``gradvar``, ``plot``) the
    gradient measurement and the figures."""
    steps = [kit.Measurement(GRID_CSV, lambda o, rows: tables(o, spec))]
    if "gradvar" in phases:
        steps.append(kit.Measurement(GRADVAR_CSV, lambda o, rows: measure(o, spec, progress)))
    if "plot" in phases:
        steps.append(kit.Measurement("timescale.png", lambda o, rows: figures(o)))
    return kit.Study(name="timescale", cells=grid_cells(spec), endpoint=None,
                     run_options={"checkpoint_every": spec.checkpoint_every, **({} if progress else {"quiet": True})},
                     later=final_cells(spec, out), measurements=tuple(steps))


def run_study(spec: TimescaleSpec, out: str | pathlib.Path, *, phases: Sequence[str] = PHASES,
              progress: bool = True) -> dict:
    """Run (or continue) the study into ``out``; returns {"grid": rows, "final": rows, "gradvar": rows}
    (each table as written, [] before it exists). kit.StudyStopped if a cell's sweep did not end."""
    spec.validate()
    out = command.study_dir(out, phases, PHASES, StudyError)
    held = lock.hold(out)  # one writer of the study for its whole run (nmrl/runs/lock.py)
    try:
        _settle(spec, out)
        if "final" in phases and "grid" not in phases and not grid_rows(out, spec):
            raise StudyError(f"{out}: the step-size grid is not finished; run the grid phase first")
        kit.run(kit_study(spec, out, phases, progress), out,
                only=[f"{p}/" for p in (GRID, FINAL) if p in phases])
        return {k: read_csv(out / f) if (out / f).exists() else []
                for k, f in (("grid", GRID_CSV), ("final", FINAL_CSV), ("gradvar", GRADVAR_CSV))}
    finally:
        held.release(remove_if_empty=True)


def _settle(spec: TimescaleSpec, out: pathlib.Path) -> None:
    """Write ``study.json``, or check that it holds ``spec``: a longer ``final_seconds`` (the final runs
    are extended; an old gradvar.csv is kept as ``gradvar_final{seconds}s.csv``) and other gradvar
    settings before gradvar.csv exists may differ; any other difference is refused."""
    spec_path = out / SPEC_FILE
    if not spec_path.exists():
        out.mkdir(parents=True, exist_ok=True)
        store.atomic_write_json(spec_path, spec.to_json())
        return
    saved = TimescaleSpec.from_json(json.loads(spec_path.read_text()))
    diff = [f.name for f in dataclasses.fields(spec) if getattr(saved, f.name) != getattr(spec, f.name)]
    longer = "final_seconds" in diff and spec.final_seconds > saved.final_seconds
    if diff and set(diff) <= _GRADVAR_FIELDS | ({"final_seconds"} if longer else set()):
        old = out / GRADVAR_CSV
        if set(diff) & _GRADVAR_FIELDS and old.exists() and not longer:
            raise StudyError(f"{old} is already measured with gradvar_envs={saved.gradvar_envs}, "
                             f"gradvar_batches={saved.gradvar_batches}; move it away to measure again")
        if old.exists():
            # a longer final budget continues the final runs; the gradient variance of the (now
            # different) trained policies is measured again, the old table is kept beside it
            old.rename(out / f"gradvar_final{saved.final_seconds:g}s.csv")
        store.atomic_write_json(spec_path, spec.to_json())
    elif diff:
        raise StudyError(f"{out} holds a study with other settings ({', '.join(diff)}); continue it "
                         f"with the same options (a longer --final-seconds, or other --gradvar-* before "
                         f"gradvar.csv exists, may be given) or choose another --out")


def main(argv: Sequence[str] | None = None) -> int:
    ap = parser.OneLineParser(prog="nmrl study", description=__doc__.split("\n\n")[0])
    d = TimescaleSpec()
    ap.add_argument("--out", required=True, help="study directory (continued if it exists)")
    parser.add_fields(ap, TimescaleSpec)  # every field of the spec declared an option (nmrl/options.py)
    parser.add_declared(ap, EnvFields, "env", default=d.base.environment.env)
    ap.add_argument("--phases", nargs="+", default=list(PHASES), help=f"any of {list(PHASES)}")
    ap.add_argument("--quiet", action="store_true")
    a = ap.parse_args(argv)
    spec = TimescaleSpec(**parser.given_fields(a, TimescaleSpec), base=options.replace(d.base, env=a.env))
    try:
        return command.run("nmrl study", lambda: run_study(spec, a.out, phases=a.phases, progress=not a.quiet),
                           (StudyError,))
    except kit.StudyStopped as e:
        print(f"nmrl study: {e}; every active point was saved; run the same command again to continue",
              file=sys.stderr)
        return e.status


if __name__ == "__main__":
    sys.exit(main())
