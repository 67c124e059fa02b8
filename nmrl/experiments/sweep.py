"""The sweep over the period length l (and seeds) as one program: the paper's Fig. 3 (Sec. V-D).

Every (l, seed) point is one training state; the states are stacked and one jitted program runs
the learner's chunk on all of them. l lives in the actor-critic's traced ``Hyper`` pytree
(nmrl/learners/ac_train.py): the in-period index is a counter compared with l, so no padding is needed
and no point recompiles. Any learner (nmrl/learners/contract.py) sweeps the same way over one of
its traced hyperparameters (``SweepSpec.field``, e.g. ``l``; None: over seeds only), its points
named ``{field}{value}_s{seed}`` (``s{seed}``). A sweep may instead list its points one by one
(``SweepSpec.overrides``, ``nmrl sweep --points FILE``): each a name and the config fields it sets on
the base config, the points differing only in traced hyperparameters and the seed (one program; a
study's grid over several traced fields at once, nmrl/experiments/study.py).

The points run through the one driver (nmrl.runs.driver.run_points) in the layout of
nmrl/runs/points.py, chosen by measurement in benchmarks/bench_sweep.py: the points split over the
local devices, each device stepping its points one after another; a point that is not active
(finished, diverged, or waiting for the ``first`` stage) is skipped. Every point gives the results
of a separate ``nmrl train`` run up to float rounding (the two programs are compiled apart;
tests/test_sweep.py).

Layout of ``OUT``::

    sweep.json                       the sweep's spec (learner, field, its values, seeds, base config;
                                     a sweep of listed points: ``points``, the list as given)
    points/l{l}_s{seed}/             a complete run directory per point (config.json,
                                     metrics.jsonl, checkpoints/, compact.npz): ``nmrl eval``
                                     and ``nmrl train --resume`` work on it
    results.csv                      l, seed, trials, steps, avg_reward, forward_speed, diverged, checkpoint
                                     (listed points: point instead of l)
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

import collections
import dataclasses
import json
import os
import pathlib
import time
from typing import Sequence

from nmrl import learners, options
from nmrl.analysis import plots, stats
from nmrl.options import SEED_RANGE, check_seed
from nmrl.runs import distributed as dist, driver, errors, lock, preflight, store
from nmrl.runs.resume import existing_step, given_changes
from nmrl.runs.signals import setting_up, stop_setup
from nmrl.runs.errors import Stopped  # noqa: F401  (raised by run_sweep after a signal)
from nmrl.runs.points import slot_order, stack_trees  # noqa: F401  (the sweep's layout, nmrl/runs/points.py)

SPEC_FILE = "sweep.json"
RESULTS_FILE = "results.csv"
#: fig3.png is redrawn after a chunk only when this many seconds passed since the last drawing
PLOT_EVERY_S = 120.0
#: the config fields a listed point may not set: the sweep's budget (given again on a resume)
BUDGET_FIELDS = ("steps", "trials")
RESULT_COLUMNS = ("l", "seed", "trials", "steps", "avg_reward", "forward_speed", "diverged", "checkpoint")


class SweepError(Exception):
    """The sweep cannot start or resume (message says why)."""


def _default_base():
    return learners.get(learners.DEFAULT).config()


@dataclasses.dataclass(frozen=True)
class SweepSpec:
    #: the values of ``field`` (for the actor-critic's Fig. 3: the period lengths l)
    ls: tuple
    seeds: int
    base: object = dataclasses.field(default_factory=_default_base)
    #: values whose points (every seed) run to the budget before the other points start
    first: tuple = ()
    #: the traced hyperparameter the sweep varies (one of the learner's ``hyper_fields``); None:
    #: the points differ in the seed only (``ls`` must then be ``(None,)``)
    field: str | None = "l"
    #: the first seed: the points' seeds are seed0 .. seed0 + seeds - 1 (a study keeps its screen's
    #: seeds apart from its grid's)
    seed0: int = 0
    #: the points one by one (``nmrl sweep --points FILE``): dicts of a ``name`` (the point's
    #: directory) and the config fields it sets on ``base``; () : the points are ``ls`` x seeds.
    #: A sweep of listed points has no ``field`` (``ls`` is ``(None,)``), seeds or ``first``.
    overrides: tuple = ()

    def validate(self) -> None:
        """ValueError naming the first bad value: the field, its values, the seed count, ``first``,
        and every point's config held to the bounds of ``nmrl train`` (nmrl.runs.preflight.check_config).
        The points are not enumerated: their count is bounded by the memory pre-flight of
        :func:`run_sweep`."""
        learner = learners.of(self.base)
        if self.overrides:
            return self._validate_overrides()
        f = self.field
        if f is None:
            if tuple(self.ls) != (None,):
                raise ValueError(f"a sweep over seeds only has no values, got {list(self.ls)}")
        elif f not in learner.hyper_fields:
            raise ValueError(f"field={f!r} is invalid: a sweep of the learner {learner.name!r} varies one of its "
                             f"traced hyperparameters: {', '.join(learner.hyper_fields)}")
        if len(self.ls) == 0:
            raise ValueError(f"the list of {f} values is empty: give at least one, e.g. --{f} 1 10")
        if f == "l":
            for l in self.ls:
                if not isinstance(l, int) or isinstance(l, bool) or l < 1:
                    raise ValueError(f"l={l!r} is invalid: every l must be an integer >= 1")
        dup = sorted({l for l in self.ls if self.ls.count(l) > 1})
        if dup:
            raise ValueError(f"duplicate {f} values {dup}: each value may appear once")
        self._validate_seeds()
        bad = [l for l in self.first if l not in self.ls]
        if bad or len(set(self.first)) != len(self.first):
            raise ValueError(f"first={list(self.first)} is invalid: the {f} values that run first must be "
                             f"distinct values of the sweep's {f} list {list(self.ls)}")
        for v in self.ls:  # the points differ in the value and the seed, whose bounds are checked above
            cfg = self.base if f is None else options.replace(self.base, **{f: v})
            preflight.check_config(options.replace(cfg, seed=0))  # the bounds of ``nmrl train``

    def _validate_seeds(self) -> None:
        """``seeds`` an integer >= 1, and every seed ``seed0 .. seed0 + seeds - 1`` one the run field
        ``seed`` allows (nmrl.options.SEED_RANGE, the one seed range); ValueError naming the value."""
        if not isinstance(self.seeds, int) or isinstance(self.seeds, bool) or self.seeds < 1:
            raise ValueError(f"seeds={self.seeds!r} is invalid: must be an integer >= 1")
        check_seed(self.seed0, "seed0")
        last = self.seed0 + self.seeds - 1
        if not SEED_RANGE.contains(last):
            raise ValueError(f"seeds={self.seeds!r} is invalid: the last seed, seed0 + seeds - 1 = {last}, must be "
                             f"{SEED_RANGE.text(int)}")

    def _validate_overrides(self) -> None:
        """The listed points: distinct plain names, fields of the config other than the budget, the
        bounds of ``nmrl train`` for each, and one program for all (nmrl/runs/points.py)."""
        from nmrl.runs import points as pts

        if self.field is not None or tuple(self.ls) != (None,) or self.first or self.seed0:
            raise ValueError("a sweep of listed points has no swept field, values, first values or seed0")
        fields = options.leaves(type(self.base))
        names = []
        for i, o in enumerate(setting_up(self.overrides, len(self.overrides), step="checking the names")):
            n = o.get("name") if isinstance(o, dict) else None
            if not isinstance(n, str) or not n or n.startswith(".") or "/" in n or "\\" in n or len(n) > 200:
                raise ValueError(f"point {i}: name={n!r} is invalid: every point needs a \"name\", a plain "
                                 f"directory name (not empty, no '/', not starting with '.')")
            bad = sorted(k for k in o if k != "name" and (k not in fields or k in BUDGET_FIELDS))
            if bad:
                raise ValueError(f"point {n!r} sets {bad}: a point sets fields of the learner's config other "
                                 f"than the budget ({', '.join(BUDGET_FIELDS)}: the sweep's options)")
            names.append(n)
        dup = sorted(n for n, k in collections.Counter(names).items() if k > 1)
        if dup:
            raise ValueError(f"duplicate point names {dup}: each point needs its own name")
        configs = self.point_configs()
        # points that differ in the seed alone are checked and resolved once: the seed's own range
        # (the run field's declaration) is checked per point
        checked: dict = {}
        for n, c in setting_up(zip(names, configs), len(names), step="checking the configs"):
            try:
                check_seed(c.budget.seed)
                seedless = options.replace(c, seed=0)
                if seedless not in checked:
                    preflight.check_config(seedless)  # the bounds of ``nmrl train``
                    checked[seedless] = seedless.resolved()
            except ValueError as e:
                raise ValueError(f"point {n!r}: {e}") from None
        pts.check_one_program(names, [checked[options.replace(c, seed=0)]
                                      for c in setting_up(configs, len(configs), step="resolving the configs")])

    def stages(self) -> list[list[int]] | None:
        """Point indices by stage: the points of ``first`` (every seed), then the rest."""
        if not self.first:
            return None
        pts = self.points()
        return [[i for i, (l, _) in enumerate(pts) if l in self.first]]

    def points(self) -> list[tuple[int, int]]:
        return [(l, s) for l in self.ls for s in range(self.seed0, self.seed0 + self.seeds)]

    def names(self) -> list[str]:
        """The points' directory names under ``points/``."""
        if self.overrides:
            return [o["name"] for o in self.overrides]
        return [point_name(l, s, self.field) for l, s in self.points()]

    def count(self) -> int:
        """The number of points (known before they are enumerated)."""
        return len(self.overrides) if self.overrides else len(self.ls) * self.seeds

    def point_configs(self) -> list:
        if self.overrides:
            return [options.replace(self.base, **{k: v for k, v in o.items() if k != "name"})
                    for o in setting_up(self.overrides, len(self.overrides), step="making the configs")]
        if self.field is None:
            return [options.replace(self.base, seed=s) for _, s in self.points()]
        return [options.replace(self.base, **{self.field: v}, seed=s) for v, s in self.points()]

    def columns(self) -> tuple[str, ...]:
        """The columns of results.csv: the swept field's (none over seeds only; listed points: ``point``),
        then the rest."""
        if self.overrides:
            return ("point",) + RESULT_COLUMNS[1:]
        return (() if self.field is None else (self.field,)) + RESULT_COLUMNS[1:]


def point_name(value, seed: int, field: str | None = "l") -> str:
    return f"s{seed}" if field is None else f"{field}{value:g}_s{seed}" if isinstance(value, float) \
        else f"{field}{value}_s{seed}"


def point_dir(out: pathlib.Path, l, seed: int, field: str | None = "l") -> pathlib.Path:
    return out / "points" / point_name(l, seed, field)


def write_results(out: pathlib.Path, spec: SweepSpec) -> list[dict]:
    """(Re)write results.csv atomically from the points' metrics; returns the rows."""
    rows = []
    keys = ([{"point": o["name"]} for o in spec.overrides] if spec.overrides else
            [{} if spec.field is None else {spec.field: l} for l, _ in spec.points()])
    for key, name, cfg in zip(keys, spec.names(), spec.point_configs()):
        d = out / "points" / name
        m = store.read_metrics(d)
        last = m[-1] if m else {}
        rows.append({
            **key, "seed": cfg.budget.seed, "trials": last.get("trials", 0), "steps": last.get("step", 0),
            "avg_reward": stats.final_avg(m, "avg_reward"), "forward_speed": stats.final_avg(m, "forward_speed"),
            "diverged": bool(any(r["diverged"] for r in m)),
            "checkpoint": os.path.relpath(d, out) if existing_step(d) is not None else "",
        })
    store.write_csv(out / RESULTS_FILE, spec.columns(), rows)
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
    """fig3.png (or ``path``) from the results rows (of a sweep over l) and the points' learning curves."""
    return plots.fig3(results, learning_curves(out, results), pathlib.Path(path) if path else out / "fig3.png")


def _write_spec(out: pathlib.Path, spec: SweepSpec) -> None:
    out.mkdir(parents=True, exist_ok=True)
    store.atomic_write_json(out / SPEC_FILE, {"ls": list(spec.ls), "seeds": spec.seeds,
                                              **({"seed0": spec.seed0} if spec.seed0 else {}), "first": list(spec.first),
                                              "base": options.flat(spec.base),
                                              learners.KEY: learners.of(spec.base).name, "field": spec.field,
                                              **({"points": list(spec.overrides)} if spec.overrides else {})})


def load_spec(out: str | os.PathLike) -> SweepSpec:
    """The spec a sweep directory's sweep.json holds (no learner named: the actor-critic's, over l)."""
    saved = json.loads((pathlib.Path(out) / SPEC_FILE).read_text())
    base = learners.config_from_dict(saved["base"], saved.get(learners.KEY))
    return SweepSpec(ls=tuple(saved["ls"]), seeds=saved["seeds"], base=base, first=tuple(saved.get("first", ())),
                     field=saved.get("field", "l"), seed0=saved.get("seed0", 0),
                     overrides=tuple(saved.get("points", ())))


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
    refused (SweepError naming them), before anything is written. A fresh sweep refuses a directory
    whose ``points/`` holds any run (no ``sweep.json`` accounts for it); a resume refuses a point
    that is not one of the saved spec's (nmrl.runs.driver.run_points). The sweep's directory is
    locked for the call (nmrl/runs/lock.py): a second writer is refused naming the first."""
    spec.validate()
    out = pathlib.Path(out)
    held = lock.hold(out, create=False) if out.is_dir() and dist.is_writer() else None
    try:
        return _run_sweep(spec, out, resume, progress, keep, max_chunks, plot, checkpoint_every, group, devices,
                          given)
    finally:
        if held is not None:
            held.release()


def _run_sweep(spec, out, resume, progress, keep, max_chunks, plot, checkpoint_every, group, devices, given):
    if resume:
        if not (out / SPEC_FILE).exists():
            raise SweepError(f"--resume: {out / SPEC_FILE} not found; is {out} a sweep directory?")
        saved = load_spec(out)
        base = saved.base
        if type(spec.base) is not type(base):
            raise SweepError(f"--resume continues the sweep in {out} with its own learner {learners.of(base).name!r}; "
                             f"--learner {learners.of(spec.base).name} would change it")
        if given:
            try:
                given_changes(base, given, out)
            except errors.RunError as e:
                raise SweepError(str(e).replace("the run in", "the sweep in")) from e
        if spec.base.budget.steps is not None or spec.base.budget.trials is not None:  # the budget may be extended
            base = options.replace(base, steps=spec.base.budget.steps, trials=spec.base.budget.trials)
        spec = dataclasses.replace(saved, base=base)
        spec.validate()
    elif (out / SPEC_FILE).exists():
        raise SweepError(f"{out} already holds a sweep; continue it with --resume or choose another --out")
    elif store.foreign_entries(out, ("points",)):
        other = store.foreign_entries(out, ("points",))
        raise SweepError(f"--out={str(out)!r} is invalid: it holds {len(other)} entries that are no sweep's "
                         f"({', '.join(other[:3])}{', ...' if len(other) > 3 else ''}); a fresh sweep starts in a "
                         f"new or empty directory")
    elif (out / "points").is_dir():
        for d in sorted((out / "points").iterdir()):
            held = [n for n in store.RUN_FILES if (d / n).exists()] if d.is_dir() else []
            if held:
                raise SweepError(f"{d} holds a run ({', '.join(held)}) but {out} has no {SPEC_FILE}, so no sweep "
                                 f"accounts for it; move it away or choose another --out (nothing was written)")
    base = spec.base.resolved()
    new_spec = not resume or base != saved.base
    spec = dataclasses.replace(spec, base=base)
    last_plot = [0.0]
    writer = dist.is_writer()  # several processes (nmrl/runs/distributed.py): only process 0 writes

    def on_chunk():
        if not writer:
            return
        results = write_results(out, spec)
        if plot and spec.field == "l" and time.time() - last_plot[0] >= PLOT_EVERY_S:
            draw(out, results)
            last_plot[0] = time.time()

    # the memory of every point before the points are enumerated (a count of billions is refused here);
    # listed points may set the environment's own fields (control step, physics, stop rate): every
    # point shares the first one's program (nmrl/runs/points.py), so its environment is theirs
    first = (options.replace(base, **{k: v for k, v in spec.overrides[0].items() if k != "name"})
             if spec.overrides else base)
    stop_setup()
    env = preflight.preflight_points(first, spec.count())
    stop_setup()
    names = spec.names()
    begun: list[bool] = []

    def before_start() -> None:  # every check passed: the sweep's own files
        if new_spec and writer:
            _write_spec(out, spec)
        begun.append(True)

    results: list[dict] = []  # (a process other than 0 writes and returns none)
    try:
        driver.run_points(out, names, spec.point_configs(), resume=resume, progress=progress, keep=keep,
                          max_chunks=max_chunks, checkpoint_every=checkpoint_every, on_chunk=on_chunk,
                          priority=spec.stages(), group=group, devices=devices, before_start=before_start, env=env)
    finally:
        if begun and writer:
            results = write_results(out, spec)
            if plot and spec.field == "l" and (out / "points").is_dir():
                draw(out, results)
    return results


def load_results(out: str | os.PathLike) -> list[dict]:
    """The rows of results.csv with their types (nmrl.runs.store.read_csv: ``diverged`` is a bool)."""
    return store.read_csv(pathlib.Path(out) / RESULTS_FILE)


__all__: Sequence[str] = ("SweepSpec", "SweepError", "Stopped", "run_sweep", "load_results", "point_dir",
                          "point_name", "load_spec", "write_results", "draw")
