"""The sweep over the period length l (and seeds) as one program: the paper's Fig. 3 (Sec. V-D).

Every (l, seed) point is one training state; the states are stacked and one jitted program runs
the learner's chunk on all of them. l lives in the traced ``Hyper`` pytree (nmrl/paper/learner.py): the
in-period index is a counter compared with l, so no padding is needed and no point recompiles.

The points run through the one driver (nmrl.runs.driver.run_points) in the layout of
nmrl/runs/points.py, chosen by measurement in benchmarks/bench_sweep.py: the points split over the
local devices, each device stepping its points one after another; a point that is not active
(finished, diverged, or waiting for the ``first`` stage) is skipped. Every point gives the results
of a separate ``nmrl train`` run up to float rounding (the two programs are compiled apart;
tests/test_sweep.py).

Layout of ``OUT``::

    sweep.json                       the sweep's spec (l values, seeds, base config)
    points/l{l}_s{seed}/             a complete run directory per point (config.json,
                                     metrics.jsonl, checkpoints/, compact.npz): ``nmrl eval``
                                     and ``nmrl train --resume`` work on it
    results.csv                      l, seed, trials, steps, avg_reward, forward_speed, diverged, checkpoint
    fig3.png                         Fig. 3 and the learning curves (nmrl/analysis/plots.py)

``avg_reward`` in results.csv is the average reward per control step during learning (the
exploring policy, as the paper measures it), averaged over the last tenth of the chunks. A
diverged point is frozen at its last good parameters and marked; it never stops the sweep.
Resuming (the driver's one resume, as ``nmrl train --resume``) restores every point from its own
newest full checkpoint, else from its compact
continuation state (``compact.npz``: parameters, counters, PRNG key; every environment then starts a
new trial, so the continuation is statistically, not bitwise, equal); a point of a later stage that
never ran starts as a fresh sweep would. A diverged point stays frozen at its last good checkpoint
and keeps its metrics.
"""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
import time
from typing import Sequence

from nmrl.analysis import plots, stats
from nmrl.paper.learner import TrainConfig
from nmrl.runs import distributed as dist, driver, store
from nmrl.runs.driver import Stopped  # noqa: F401  (raised by run_sweep after a signal)
from nmrl.runs.points import slot_order, stack_trees  # noqa: F401  (the sweep's layout, nmrl/runs/points.py)

SPEC_FILE = "sweep.json"
RESULTS_FILE = "results.csv"
#: fig3.png is redrawn after a chunk only when this many seconds passed since the last drawing
PLOT_EVERY_S = 120.0
RESULT_COLUMNS = ("l", "seed", "trials", "steps", "avg_reward", "forward_speed", "diverged", "checkpoint")


class SweepError(Exception):
    """The sweep cannot start or resume (message says why)."""


@dataclasses.dataclass(frozen=True)
class SweepSpec:
    ls: tuple[int, ...]
    seeds: int
    base: TrainConfig = TrainConfig()
    #: l values whose points (every seed) run to the budget before the other points start
    first: tuple[int, ...] = ()

    def validate(self) -> None:
        if len(self.ls) == 0:
            raise ValueError("the list of l values is empty: give at least one, e.g. --l 1 10")
        for l in self.ls:
            if not isinstance(l, int) or isinstance(l, bool) or l < 1:
                raise ValueError(f"l={l!r} is invalid: every l must be an integer >= 1")
        dup = sorted({l for l in self.ls if self.ls.count(l) > 1})
        if dup:
            raise ValueError(f"duplicate l values {dup}: each l may appear once")
        if not isinstance(self.seeds, int) or isinstance(self.seeds, bool) or self.seeds < 1:
            raise ValueError(f"seeds={self.seeds!r} is invalid: must be an integer >= 1")
        bad = [l for l in self.first if l not in self.ls]
        if bad or len(set(self.first)) != len(self.first):
            raise ValueError(f"first={list(self.first)} is invalid: the l values that run first must be "
                             f"distinct values of the sweep's l list {list(self.ls)}")
        for cfg in self.point_configs():
            cfg.validate()

    def stages(self) -> list[list[int]] | None:
        """Point indices by stage: the points of ``first`` (every seed), then the rest."""
        if not self.first:
            return None
        pts = self.points()
        return [[i for i, (l, _) in enumerate(pts) if l in self.first]]

    def points(self) -> list[tuple[int, int]]:
        return [(l, s) for l in self.ls for s in range(self.seeds)]

    def point_configs(self) -> list[TrainConfig]:
        return [dataclasses.replace(self.base, l=l, seed=s) for l, s in self.points()]


def point_dir(out: pathlib.Path, l: int, seed: int) -> pathlib.Path:
    return out / "points" / f"l{l}_s{seed}"


def write_results(out: pathlib.Path, spec: SweepSpec) -> list[dict]:
    """(Re)write results.csv atomically from the points' metrics; returns the rows."""
    rows = []
    for (l, s) in spec.points():
        d = point_dir(out, l, s)
        m = store.read_metrics(d)
        last = m[-1] if m else {}
        rows.append({
            "l": l, "seed": s, "trials": last.get("trials", 0), "steps": last.get("step", 0),
            "avg_reward": stats.final_avg(m, "avg_reward"), "forward_speed": stats.final_avg(m, "forward_speed"),
            "diverged": bool(any(r["diverged"] for r in m)),
            "checkpoint": os.path.relpath(d, out) if driver.existing_step(d) is not None else "",
        })
    store.write_csv(out / RESULTS_FILE, RESULT_COLUMNS, rows)
    return rows


def learning_curves(out: pathlib.Path, results: list[dict]) -> dict[int, list[list[dict]]]:
    """Every l's points' metrics rows (one list per seed that has any), for the figure."""
    curves: dict[int, list[list[dict]]] = {}
    for r in results:
        m = store.read_metrics(point_dir(out, int(r["l"]), int(r["seed"])))
        if m:
            curves.setdefault(int(r["l"]), []).append(m)
    return curves


def draw(out: pathlib.Path, results: list[dict], path: str | os.PathLike | None = None) -> pathlib.Path:
    """fig3.png (or ``path``) from the results rows and the points' learning curves."""
    return plots.fig3(results, learning_curves(out, results), pathlib.Path(path) if path else out / "fig3.png")


def _write_spec(out: pathlib.Path, spec: SweepSpec) -> None:
    out.mkdir(parents=True, exist_ok=True)
    store.atomic_write_json(out / SPEC_FILE, {"ls": list(spec.ls), "seeds": spec.seeds, "first": list(spec.first),
                                              "base": dataclasses.asdict(spec.base)})


def run_sweep(spec: SweepSpec, out: str | os.PathLike, *, resume: bool = False, progress: bool = True,
              keep: int = 2, max_chunks: int | None = None, plot: bool = True,
              checkpoint_every: int = 1, group: int = 1, devices: int | None = None,
              given: dict | None = None) -> list[dict]:
    """Run (or resume) the sweep into ``out`` (nmrl.runs.driver.run_points); returns the results rows.

    A resume uses the saved spec (``sweep.json``); a budget given in ``spec.base`` replaces the saved
    one, in sweep.json and (as a resume of :func:`nmrl.runs.driver.train` does) in every point's
    config.json, with a line in its resumes.jsonl. Raises :class:`Stopped` after SIGINT/SIGTERM
    (every active point saved; results.csv and fig3.png written).

    ``given`` (the config options given on the command line with a resume) may change only the
    budget: any other that differs from the saved base config (e.g. another ``actor_opt`` chain) is
    refused (SweepError naming them), before anything is written."""
    spec.validate()
    out = pathlib.Path(out)
    if resume:
        if not (out / SPEC_FILE).exists():
            raise SweepError(f"--resume: {out / SPEC_FILE} not found; is {out} a sweep directory?")
        saved = json.loads((out / SPEC_FILE).read_text())
        base = TrainConfig(**saved["base"])
        if given:
            try:
                driver._given_changes(base, given, out)
            except driver.RunError as e:
                raise SweepError(str(e).replace("the run in", "the sweep in")) from e
        if spec.base.steps is not None or spec.base.trials is not None:  # the budget may be extended
            base = dataclasses.replace(base, steps=spec.base.steps, trials=spec.base.trials)
        spec = SweepSpec(ls=tuple(saved["ls"]), seeds=saved["seeds"], base=base,
                         first=tuple(saved.get("first", ())))
        spec.validate()
    elif (out / SPEC_FILE).exists():
        raise SweepError(f"{out} already holds a sweep; continue it with --resume or choose another --out")
    base = spec.base.resolved()
    new_spec = not resume or base != TrainConfig(**saved["base"])
    spec = dataclasses.replace(spec, base=base)
    last_plot = [0.0]
    writer = dist.is_writer()  # several processes (nmrl/runs/distributed.py): only process 0 writes

    def on_chunk():
        if not writer:
            return
        results = write_results(out, spec)
        if plot and time.time() - last_plot[0] >= PLOT_EVERY_S:
            draw(out, results)
            last_plot[0] = time.time()

    names = [point_dir(out, l, s).name for l, s in spec.points()]
    begun: list[bool] = []

    def before_start() -> None:  # every check passed: the sweep's own files
        if new_spec and writer:
            _write_spec(out, spec)
        begun.append(True)

    results: list[dict] = []  # (a process other than 0 writes and returns none)
    try:
        driver.run_points(out, names, spec.point_configs(), resume=resume, progress=progress, keep=keep,
                          max_chunks=max_chunks, checkpoint_every=checkpoint_every, on_chunk=on_chunk,
                          priority=spec.stages(), group=group, devices=devices, before_start=before_start)
    finally:
        if begun and writer:
            results = write_results(out, spec)
            if plot and (out / "points").is_dir():
                draw(out, results)
    return results


def load_results(out: str | os.PathLike) -> list[dict]:
    """The rows of results.csv with their types (nmrl.runs.store.read_csv: ``diverged`` is a bool)."""
    return store.read_csv(pathlib.Path(out) / RESULTS_FILE)


__all__: Sequence[str] = ("SweepSpec", "SweepError", "Stopped", "run_sweep", "load_results", "point_dir",
                          "write_results", "draw")
