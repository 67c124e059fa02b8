"""A study as data: cells that are ``nmrl sweep`` commands, an endpoint, and one runner.

A :class:`Study` names its cells in run order; a :class:`Cell` (nmrl/experiments/kit_cells.py) is a
directory under the study's (``screen/dt0.0025/white``) and one ``nmrl sweep`` as typed data: its
learner, settings, budget and points, checked against the learner's declarations as it is made
(every point of a cell is one compiled program: the values of one traced field x seeds, or the
points the cell lists, differing in several traced fields and the seed: ``nmrl sweep --points``).
:func:`run` brings every cell to its budget and scores it:

* a cell with a ``sweep.json`` is continued (``nmrl sweep --resume``, its budget given again),
  unless its files show that the resume has nothing to do (:func:`at_budget`);
  one missing but present in ``published`` (a committed copy made by :func:`publish`) is first
  seeded from there (sweep.json, every point's config.json, metrics.jsonl and compact.npz: the
  compact continuation states, every environment starting a new trial); any other starts fresh;
  a measurement's file missing but published is seeded the same way (:func:`seed_measurements`);
* each sweep runs as its own ``nmrl sweep`` process (niced by the caller), its command line made
  from the cell by ``kit_cells.sweep_argv`` alone, so that its devices, memory and signals are its
  own; a signal stops the study after the sweep saves, with its status;
* every point at its budget gets ``endpoint.json``: the deterministic policy's reward per second
  over the study's rollouts from perturbed starts (nmrl/analysis/endpoint.py), once per step (a
  study whose endpoint is None scores its points from their metrics alone, in its measurements);
* ``rows.csv``: one row per point with its cell, seed, the varied field's value, budget, whether it
  diverged, the exploring reward per second of its last chunk and its mean over chunks (the area
  under the learning curve), and the endpoint (a diverged point's: its last good policy's, at
  which the sweep froze it).

nmrl/experiments/kit_progress.py reads where each cell stands and its time left from the files, beside
a running study. :func:`publish` copies what continues and re-scores a study (no full checkpoints)
into a folder small enough to commit, with ``analysis.csv``, the study's own analysis of the rows (its
pre-registered contrasts), its report's figures and tables, and the files of its measurements (steps
that are not sweeps, run after every cell, :class:`Measurement`). A study's own modules (e.g.
nmrl/experiments/exploration2.py and its cells, rules and analysis beside it; the finer-delta study,
nmrl/experiments/study.py, with its cells and tables) hold its cells as data and any rule that makes
later cells from earlier rows.
"""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile
from typing import Any, Callable, Mapping, Sequence

from nmrl.experiments.kit_cells import Cell, sweep_argv
from nmrl.paper.control_step import DELTA_0
from nmrl.runs import signals, store

ROWS = "rows.csv"
ANALYSIS = "analysis.csv"
ENDPOINT = "endpoint.json"
COLUMNS = ("cell", "point", "seed", "field", "value", "control_dt", "steps", "budget", "diverged",
           "avg_reward_per_s", "auc_reward_per_s", "det_reward_per_s", "forward_speed", "det_forward_speed")
#: a cell's files beside its points: nmrl sweep's spec and its results table (nmrl/experiments/sweep.py)
_CELL_FILES = ("sweep.json", "results.csv")
_PUBLISHED_POINT_FILES = ("config.json", "metrics.jsonl", "compact.npz", ENDPOINT)


class StudyError(Exception):
    """A study cannot start or continue: its settings or its directory say why (bad input, exit status 2)."""


class StudyStopped(RuntimeError):
    """A cell's sweep ended without finishing (a signal, an error); ``status`` is its exit status."""

    def __init__(self, cell: str, status: int):
        super().__init__(f"cell {cell} stopped with status {status}")
        self.cell, self.status = cell, status


@dataclasses.dataclass(frozen=True)
class Endpoint:
    seconds: float = 10.0
    rollouts: int = 8
    start_noise: float = 0.05
    seed: int = 0


@dataclasses.dataclass(frozen=True)
class Measurement:
    """A step of a study that is not a sweep, run after every cell: ``run(out, rows)`` writes
    ``file`` (a file or a folder) in the study's directory from the rows and the cells' points,
    continuing what an earlier call left there, and does nothing while a cell it needs is
    unfinished; :func:`publish` copies ``file``."""

    file: str
    run: Callable[[pathlib.Path, list[dict]], None]


@dataclasses.dataclass(frozen=True)
class Study:
    name: str
    cells: tuple[Cell, ...]
    #: the deterministic endpoint every point is scored by; None: none (the study's numbers are its own)
    endpoint: Endpoint | None = Endpoint()
    #: how a cell runs, not what it computes (nmrl/experiments/kit_cells.py's ``SweepOptions``)
    run_options: Mapping[str, Any] = dataclasses.field(default_factory=lambda: {"checkpoint_every": 1, "quiet": True})
    #: the study's rule for later cells: from the rows so far, the cells that follow (run after
    #: ``cells``, as they appear; a rule reads only finished cells' rows)
    later: Callable[[list[dict]], Sequence[Cell]] | None = None
    #: the study's analysis: from every row, the rows of its result table (written as
    #: ``analysis.csv`` beside ``rows.csv`` by :func:`publish`)
    analysis: Callable[[list[dict]], list[dict]] | None = None
    #: the study's figures and tables beyond ``analysis.csv``: called by :func:`publish` with every
    #: row and the published folder, from which alone it draws (so a fresh clone redraws them)
    report: Callable[[list[dict], pathlib.Path], None] | None = None
    #: run after every cell, in order (:class:`Measurement`)
    measurements: tuple[Measurement, ...] = ()


def all_cells(study: Study, out: pathlib.Path) -> list[Cell]:
    """``study.cells`` and every later cell its rule makes from the rows so far, in the rule's order: a
    cell the rule adds once other cells' rows exist (a screen's extension) goes right after the cell
    the rule lists before it, so it comes before the cells the rule lists after it, whenever those
    became known; a cell the rule stops listing (an extension while its runs go on) keeps its place."""
    cells = list(study.cells)
    while study.later is not None:
        names = {c.name for c in cells}
        later = study.later(rows(study, out, cells))
        if all(c.name in names for c in later):
            break
        for i, c in enumerate(later):
            if c.name in names:
                continue
            before = next((p.name for p in reversed(later[:i]) if p.name in names), None)
            at = len(study.cells) if before is None else [x.name for x in cells].index(before) + 1
            cells.insert(at, c)
            names.add(c.name)
    return cells


def _nmrl() -> list[str]:
    return [sys.executable, "-m", "nmrl.cli"]


def _sweep(argv: list[str]) -> int:
    """Run one ``nmrl sweep`` to its end and return its exit status. A Ctrl-C reaches the sweep too
    (the terminal signals the whole process group): the sweep saves every active point and exits,
    and the study waits for that instead of killing it while it saves (``subprocess.call`` would)."""
    p = subprocess.Popen(argv)
    while True:
        try:
            return p.wait()
        except KeyboardInterrupt:
            continue


def seed_from(published: pathlib.Path, d: pathlib.Path) -> bool:
    """Copy a published cell's continuation state and its ``results.csv`` into ``d`` (which holds no
    sweep); True if done."""
    if (d / "sweep.json").exists() or not (published / "sweep.json").exists():
        return False
    copy_cell(published, d)
    return True


def copy_cell(src: pathlib.Path, dst: pathlib.Path) -> None:
    """A cell's sweep.json and results.csv, and each point's continuation files, from ``src`` to ``dst``."""
    dst.mkdir(parents=True, exist_ok=True)
    for f in _CELL_FILES:
        if (src / f).is_file():
            shutil.copy2(src / f, dst / f)
    for p in point_dirs(src):
        q = dst / "points" / p.name
        q.mkdir(parents=True, exist_ok=True)
        for f in _PUBLISHED_POINT_FILES:
            if (p / f).is_file():
                shutil.copy2(p / f, q / f)


def run_cell(study: Study, cell: Cell, out: pathlib.Path, published: pathlib.Path | None = None) -> None:
    """Bring one cell to its budget (see the module docstring); StudyStopped if its sweep did not end."""
    d = out / cell.name
    if published is not None:
        seed_from(published / cell.name, d)
    how = {**study.run_options, **cell.run_options}  # how the cell runs, on its start and every resume
    if (d / "sweep.json").exists():
        saved = json.loads((d / "sweep.json").read_text()).get("points", [])
        if cell.points and saved != json.loads(json.dumps(list(cell.points))):
            raise StudyError(f"{d} holds a sweep of other points than the cell {cell.name} lists (other "
                             f"settings chose them); move it away to run the cell's points")
        if at_budget(cell, d):
            return
        rc = _sweep([*_nmrl(), "sweep", *sweep_argv(cell, how, resume=True), "--out", str(d)])
    elif cell.points:
        with tempfile.TemporaryDirectory() as tmp:  # the sweep records its points in its sweep.json
            f = pathlib.Path(tmp) / "points.json"
            f.write_text(json.dumps(list(cell.points)))
            rc = _sweep([*_nmrl(), "sweep", *sweep_argv(cell, how, points_file=str(f)), "--out", str(d)])
    else:
        rc = _sweep([*_nmrl(), "sweep", *sweep_argv(cell, how), "--out", str(d)])
    if rc != 0:
        raise StudyStopped(cell.name, rc)
    guard = signals.active()  # a signal to the study's process alone (under a command's guard) stops it here
    if guard is not None and guard.signal is not None:
        raise StudyStopped(cell.name, 128 + guard.signal)


def at_budget(cell: Cell, d: pathlib.Path) -> bool:
    """Whether the cell's sweep in ``d`` has ended at the cell's budget: every point its
    ``sweep.json`` names has diverged (frozen by the sweep) or holds a continuation state
    (``compact.npz``, saved with every checkpoint) whose counter has reached the budget -- the test a
    resume makes on the restored states (nmrl.runs.loop.budget_done), read from the files, so that a
    finished cell costs no process, no JAX start and no restore. Its ``results.csv`` is not asked
    for: a resume with nothing to do writes nothing, so a cell without one would be resumed at every
    start and never gain it. Anything missing or unreadable answers False: the resume then decides,
    and reports what is wrong."""
    from nmrl.experiments import sweep
    from nmrl.runs import compact
    from nmrl.runs.errors import CheckpointError

    budget = cell.budget_limit()
    if budget is None:
        return False
    counter, limit = budget
    try:
        names = sweep.load_spec(d).names()
    except (OSError, ValueError, KeyError, TypeError):
        return False
    for name in names:
        p = d / "points" / name
        try:
            if any(store.is_diverged(r) for r in store.read_metrics(p)):
                continue
            _, arrays = compact.load_compact(p)
        except (ValueError, CheckpointError):  # a damaged metrics file (jsonl.Corrupt) or state
            return False
        if counter not in arrays or int(arrays[counter]) < limit:
            return False
    return True


def point_dirs(d: pathlib.Path) -> list[pathlib.Path]:
    """The point directories of the cell at ``d`` that have a config.json, in name order."""
    return sorted(p for p in (d / "points").glob("*/") if (p / "config.json").exists())


def score_point(study: Study, p: pathlib.Path) -> dict | None:
    """``endpoint.json`` of a point (computed once per saved step); None if it has no saved policy."""
    from nmrl.analysis import endpoint
    from nmrl.runs import checkpoint

    try:
        meta, config, params = checkpoint.restore_params(p)
    except checkpoint.CheckpointError:
        return None
    f = p / ENDPOINT
    if f.exists():
        old = json.loads(f.read_text())
        if old.get("step") == int(meta["step"]):
            return old
    e = study.endpoint
    res = endpoint.deterministic_endpoint(config, params, seconds=e.seconds, rollouts=e.rollouts,
                                          start_noise=e.start_noise, seed=e.seed)
    res = {"step": int(meta["step"]), **res}
    store.atomic_write_json(f, res)
    return res


def rows(study: Study, out: pathlib.Path, cells: Sequence[Cell] | None = None) -> list[dict]:
    """One row per point of every cell that exists (see the module docstring); ``cells`` default:
    :func:`all_cells`."""
    res = []
    for cell in (all_cells(study, out) if cells is None else cells):
        d = out / cell.name
        if not (d / "sweep.json").exists():
            continue
        spec = json.loads((d / "sweep.json").read_text())
        field = spec.get("field")
        for p in point_dirs(d):
            cfg = json.loads((p / "config.json").read_text())
            m = store.read_metrics(p)
            e = json.loads((p / ENDPOINT).read_text()) if (p / ENDPOINT).exists() else {}
            diverged = bool(any(r.get("diverged") for r in m))
            # the endpoint of the newest metrics row's policy; a diverged point's is its last good one
            if not (m and (e.get("step") == m[-1]["step"] or (diverged and e))):
                e = {}
            res.append({
                "cell": cell.name, "point": p.name, "seed": cfg.get("seed"), "field": field or "",
                "value": cfg.get(field) if field else "", "control_dt": cfg.get("control_dt"),
                "steps": m[-1]["step"] if m else 0, "budget": cfg.get("steps"),
                "diverged": diverged,
                "avg_reward_per_s": m[-1]["avg_reward"] / DELTA_0 if m else "",
                "auc_reward_per_s": sum(r["avg_reward"] for r in m) / len(m) / DELTA_0 if m else "",
                "det_reward_per_s": e.get("reward_per_s", ""),
                "forward_speed": m[-1].get("forward_speed", "") if m else "",
                "det_forward_speed": sum(e["forward_speed"]) / len(e["forward_speed"]) if e.get("forward_speed")
                else "",
            })
    return res


def learning_curve(point: pathlib.Path) -> tuple[Any, Any]:
    """A point's learning curve from its metrics: simulated seconds per environment, and the
    exploring reward per second of each chunk."""
    import numpy as np

    dt = json.loads((point / "config.json").read_text())["control_dt"]
    m = store.read_metrics(point)
    return np.array([r["step"] * dt for r in m]), np.array([r["avg_reward"] / DELTA_0 for r in m])


def ended(r: dict) -> bool:
    """Whether a point's row (as :func:`rows` builds it, or read back from ``rows.csv``) is final: its
    step counter has reached its budget (the last chunk may pass it, where the budget is not a
    multiple of the chunk), or it diverged and is frozen at its last good policy."""
    if str(r["diverged"]) == "True":
        return True
    return r.get("budget") not in (None, "") and int(r["steps"]) >= int(r["budget"])


def write_rows(study: Study, out: pathlib.Path) -> list[dict]:
    r = rows(study, out)
    out.mkdir(parents=True, exist_ok=True)
    store.write_csv(out / ROWS, COLUMNS, r)
    return r


def run(study: Study, out: str | os.PathLike, *, published: str | os.PathLike | None = None,
        only: Sequence[str] | None = None) -> list[dict]:
    """Every cell (or, ``only`` given, those whose name starts with one of ``only``: none for ``()``)
    to its budget and scored, one at a time in :func:`all_cells`'s order as it stands after the cell
    before (so a cell the rule adds runs where the rule puts it), the measurements in order after
    each (each does nothing while a cell it needs is unfinished and continues what it left, so a
    finished cell's measurement is in the next publish; with no cell to run, they run once on the
    rows as they are); the rows."""
    out = pathlib.Path(out)
    pub = pathlib.Path(published) if published is not None else None
    if pub is not None:
        seed_measurements(study, out, pub)
    done: set[str] = set()
    while True:
        todo = [c for c in all_cells(study, out) if c.name not in done
                and (only is None or any(c.name.startswith(o) for o in only))]
        if not todo:
            r = write_rows(study, out)
            if not done:
                _measure(study, out, r)
            return r
        cell = todo[0]
        run_cell(study, cell, out, pub)
        for p in point_dirs(out / cell.name) if study.endpoint is not None else ():
            score_point(study, p)
        _measure(study, out, write_rows(study, out))
        done.add(cell.name)


def seed_measurements(study: Study, out: pathlib.Path, published: pathlib.Path) -> None:
    """Copy each measurement's file (or folder) missing in ``out`` from ``published``, as a cell is
    seeded: a measurement continues what it left there, so a study resumed on another machine does
    not measure again what was published (a measurement stopped half-way goes on where it was)."""
    for m in study.measurements:
        src, dst = published / m.file, out / m.file
        if not dst.exists() and src.exists():
            out.mkdir(parents=True, exist_ok=True)
            _copy(src, dst)


def _copy(src: pathlib.Path, dst: pathlib.Path) -> None:
    """A measurement's file, or its folder merged into ``dst``; nothing if ``src`` is neither."""
    if src.is_file():
        shutil.copy2(src, dst)
    elif src.is_dir():
        shutil.copytree(src, dst, dirs_exist_ok=True)


def _measure(study: Study, out: pathlib.Path, r: list[dict]) -> None:
    for m in study.measurements:
        m.run(out, r)


def publish(study: Study, out: str | os.PathLike, dest: str | os.PathLike) -> None:
    """Copy every cell's sweep.json, results.csv and points' continuation files, and rows.csv, to ``dest``."""
    out, dest = pathlib.Path(out), pathlib.Path(dest)
    for cell in all_cells(study, out):
        d = out / cell.name
        if not (d / "sweep.json").exists():
            continue
        copy_cell(d, dest / cell.name)
    r = write_rows(study, out)
    shutil.copy2(out / ROWS, dest / ROWS)
    for m in study.measurements:
        _copy(out / m.file, dest / m.file)
    if study.analysis is not None:
        table = study.analysis(r)
        store.write_csv(dest / ANALYSIS, list(dict.fromkeys(k for row in table for k in row)), table)
    if study.report is not None:
        study.report(r, dest)
