"""The one driver of training runs: 1..P points, chunk by chunk, with signals and progress.

The driver runs any learner of nmrl/learners/ (the contract: nmrl/learners/contract.py; the
paper's actor-critic is ``ac``): a run's config is of one learner, whose ``make`` gives the pure
``init`` and ``chunk``. Its two entry points are sessions of one path (nmrl/runs/session.py),
which differ only in how they read their points, lay them out and in their
:class:`~nmrl.runs.session.Policy`:

* :func:`train` -- one point, one run (``nmrl train``): its N environments split over the local
  devices (layout :class:`~nmrl.runs.layout.OneRun`, ``psum``-ed updates, nmrl/runs/sharding.py);
  3 checkpoints kept, one saved after every chunk. A run whose parameters diverge stops with
  :class:`~nmrl.runs.errors.Diverged` and keeps its last good checkpoint.
* :func:`run_points` -- P points (the runs of a sweep or study) as one compiled program (layout
  :class:`~nmrl.runs.layout.Points`, nmrl/runs/points.py: the points over the devices, one at a
  time per device); 2 checkpoints kept per point, with its compact state. A diverged point is
  frozen at its last good checkpoint and the others go on; ``priority`` stages the points.

Both go the same way (nmrl/runs/session.py): the checks (nmrl/runs/preflight.py) or a resume's
reads (nmrl/runs/resume.py: a run continues with its own config, only the budget may change), the
points laid out on the devices (nmrl/runs/layout.py), the compile, then the runs' files and the
chunk loop (nmrl/runs/loop.py). One process writes a run directory at a time
(:mod:`nmrl.runs.lock`, held from before the run is read until the session ends; a second writer
is refused naming the holder). Nothing is written before every check, the memory estimate and the
first allocation have passed and the chunk has compiled: a start that fails or is stopped before
its first chunk leaves no directory that blocks the next attempt. Several processes
(nmrl/runs/distributed.py) run the same session in lockstep: every process reads the run
directory before process 0 writes (a barrier in between).

The names other modules reach through the driver are imported here: the exceptions
(nmrl/runs/errors.py), the checks, the resume's and the loop's functions, and the run store's.
"""

from __future__ import annotations

import os
import pathlib
import sys
from typing import Callable, Sequence

import jax
import numpy as np

from nmrl import learners, options
from nmrl.learners.contract import Config
from nmrl.runs import checkpoint, distributed as dist, lock, session, sharding, signals
from nmrl.runs import points as pts
from nmrl.runs.errors import RunError
# with the names other modules reach through the driver, used here or not (the module docstring)
from nmrl.runs.layout import OneRun, Point, Points, begin_fresh, begin_resumed, num_shards  # noqa: F401
from nmrl.runs.loop import (Progress, budget_done, budget_text, compile_or_stop, drive, guarded,  # noqa: F401
                            next_save, progress_table)
from nmrl.runs.preflight import allocate, check_config, fresh_out, hold, preflight  # noqa: F401
from nmrl.runs.resume import BUDGET_FIELDS, existing_step, load_resume
from nmrl.runs.store import RUN_FILES, is_diverged, read_metrics


# ----------------------------------------------------------------------------- one run


def train(cfg: Config, out: str | os.PathLike, *, resume: bool = False, progress: bool = True,
          keep: int = 3, max_chunks: int | None = None, devices: int | None = None,
          given: dict | None = None, step: int | None = None) -> list[dict]:
    """Run (or resume) training into ``out``; returns the metrics rows written in this call.

    The N environments are split over ``devices`` local devices (default: every one; on a CPU
    nmrl.runs.devices exposes one per core), each stepping its N/D environments; the summed update is
    ``psum``-ed (equal to the 1-device run up to float rounding, tests/test_sharding.py).

    A fresh run refuses an ``out`` holding any of :data:`RUN_FILES` (RunError). A resume continues
    the run's own config from its newest checkpoint (or ``step``); ``given`` are the config fields
    the user set (the command line's options): the budget among them replaces the run's, any other
    that differs from the run's config is refused (RunError naming them); without ``given`` only the
    budget of ``cfg`` (if any) is used. A checkpoint of another run or a corrupted one is refused
    (RunError/CheckpointError naming it; for a corrupted newest one, the newest good step).
    Every refusal comes before anything is written. A budget change is recorded in ``config.json``,
    every resume in ``resumes.jsonl``.

    Raises :class:`~nmrl.runs.errors.Diverged` when the parameters diverge, :class:`~nmrl.runs.errors.Stopped` after SIGINT/SIGTERM.
    ``max_chunks`` stops after that many chunks (used by tests to interrupt a run).
    """
    out = pathlib.Path(out)
    if step is not None and not resume:
        raise RunError(f"--step={step} picks the checkpoint to resume from and needs --resume "
                       f"(the budget is --steps)")

    def read(holds: session.Holds) -> list[Point]:
        if resume:
            if out.is_dir():
                holds.hold(out, create=False)  # before the run is read
            run_cfg, trainer, ts, record = load_resume(cfg, out, given, step)
            num_shards(run_cfg, devices)  # a bad device count is refused before anything is written
            return [Point(out.name, out, run_cfg, trainer, ts, record=record)]
        check_config(cfg)
        new = cfg.resolved()
        fresh_out(out)
        trainer = learners.of(new).make(new)
        num_shards(new, devices)
        preflight(new, trainer)
        # creates the directory (removed again if nothing is written, also by a second signal's immediate exit)
        holds.hold(out, on_exit=True)
        fresh_out(out)  # again under the lock: another writer may have finished meanwhile
        ts = allocate(lambda: jax.jit(trainer.init)(jax.random.PRNGKey(new.budget.seed)), "allocating the state", new)
        return [Point(out.name, out, new, trainer, ts)]

    def nothing_to_do(ps: Sequence[Point]) -> str:
        p = ps[0]
        return (f"{out}: nothing to do: the run is at step {int(p.ts.step)} ({int(p.ts.trials)} trials), its "
                f"budget is {budget_text(p.cfg)}; give a larger --steps or --trials to continue")

    policy = session.Policy(
        kind=session.ONE_RUN, keep=keep, checkpoint_every=1, freeze_diverged=False, compact=False,
        barrier="train-checked", nothing_to_do=nothing_to_do,
        stopped=("nothing of the run was written" if not resume else
                 f"the run in {out} is as it was; continue with: nmrl train --resume --out {out}"),
        stop_message=lambda sig, st: (f"stopped by signal {sig} at step {st} (saved); continue "
                                      f"with: nmrl train --resume --out {out}"))
    return session.run(policy, read, lambda ps: OneRun(ps[0], devices), resume=resume, progress=progress,
                       max_chunks=max_chunks)


def run_points(out: str | os.PathLike, names: Sequence[str], configs: Sequence[Config], *,
               resume: bool = False, progress: bool = True, keep: int = 2, max_chunks: int | None = None,
               checkpoint_every: int = 1, on_chunk: Callable[[], None] | None = None,
               table: bool = True, priority: Sequence[Sequence[int]] | None = None, group: int = 1,
               devices: int | None = None, before_start: Callable[[], None] | None = None,
               known: Sequence[str] = (), env=None) -> list[dict]:
    """Train every config as one compiled program; point ``names[i]`` lives in ``out/points/<name>/``.

    The configs are of one learner and may differ only in its traced ``hyper_fields`` and the seed
    (one program).
    Layout (nmrl/runs/points.py): the points are split over ``devices`` local devices (default:
    all), stepped one after another on each (``group`` points vmapped together). ``priority`` is a
    list of stages, each a list of point indices: a stage's points run only when every earlier
    stage's points have finished their budget or diverged (points named in no stage form a last
    stage); the points are dealt over the devices in that order (``points.slot_order``).
    Every point is checkpointed every ``checkpoint_every`` chunks (its checkpointer's save policy:
    steps that are multiples of ``checkpoint_every * chunk_steps``), when it finishes and when a
    signal stops the sweep, and writes its compact continuation state beside
    (nmrl.runs.checkpoint.save_compact). ``resume`` continues every point as :func:`train` resumes a
    run (:func:`load_resume`, with the budget of ``configs``; other fields must be the point's own):
    from its newest checkpoint (its later metrics rows are dropped), else from its compact state
    (statistically, not bitwise, equal: every environment starts a new trial), else (a point of a
    later stage that never ran) from the start. A diverged point stays frozen at its last good
    checkpoint. ``on_chunk()`` runs after every chunk; ``progress`` prints the layout, the compile
    time and (with ``table``) every point's latest metrics. SIGINT/SIGTERM stop the sweep after the
    chunk in flight, every active point saved, with :class:`~nmrl.runs.errors.Stopped`. Returns the rows written.
    ``before_start()`` runs once every check has passed and the chunk has compiled, before the
    points' files are written. ``out/points/`` may hold only these points and those named in
    ``known`` (points of the same experiment not run in this call, e.g. finished ones): any other
    run there is refused, as is (a fresh start) a point holding a saved run or another config.
    ``out`` and every point are locked (nmrl/runs/lock.py) for the call. ``env``: the learner's
    environment when the caller has built it (:func:`preflight_points`), else built here.
    """
    if not (isinstance(checkpoint_every, int) and checkpoint_every >= 1):
        raise ValueError(f"checkpoint_every={checkpoint_every!r} is invalid: must be an integer >= 1")
    if len(names) != len(configs) or len(set(names)) != len(names) or not names:
        raise ValueError(f"need one distinct name per config, got {len(names)} names for {len(configs)} configs")
    out = pathlib.Path(out)
    configs = [c.resolved() for c in signals.setting_up(configs, len(configs), step="resolving the configs")]
    pts.check_one_program(names, configs)
    signals.stop_setup()
    P_ = len(names)
    stages = pts.stages(priority, P_)
    n_avail = len(jax.local_devices())
    n_dev = n_avail if devices is None else devices
    if not (isinstance(n_dev, int) and 1 <= n_dev <= n_avail):
        raise ValueError(f"devices={devices!r} is invalid: this process has {n_avail} local device(s)")
    mesh_devices = None
    if dist.active():  # every process's devices; a process may hold only idle slots
        mesh_devices = sharding.process_devices(n_dev)
        n_dev = len(mesh_devices)
    else:
        n_dev = min(n_dev, P_)
    dirs = [out / "points" / n for n in names]

    def read(holds: session.Holds) -> list[Point]:
        nonlocal env
        if out.is_dir():
            holds.hold(out, create=False)  # the sweep's directory, before any of it is read
        _foreign_points(out, names, dirs, configs, resume, known)
        for d in dirs:
            if d.is_dir():
                holds.hold(d, create=False)  # each existing point, too
        if resume:
            ps: list[Point] = []
            for n, d, c in signals.setting_up(zip(names, dirs, configs), P_, step="reading the points"):
                if not any((d / f).exists() for f in RUN_FILES):  # deleted, or never begun: a fresh point
                    if dist.is_writer():
                        print(f"nmrl: note: point {n} has no run in {d}: it starts fresh", file=sys.stderr,
                              flush=True)
                    tr = learners.of(c).make(c, env=env)
                    env = env or tr.env
                    ts = jax.jit(tr.init)(jax.random.PRNGKey(c.budget.seed))
                    ps.append(Point(n, d, c, tr, ts))
                    continue
                # a diverged point stopped saving at its last good step and stays frozen there
                frozen = any(is_diverged(r) for r in read_metrics(d))
                cfg, tr, ts, record = load_resume(c, d, options.flat(c), None, env=env)
                env = env or tr.env
                ps.append(Point(n, d, cfg, tr, ts, frozen=frozen, record=record))
            pts.check_one_program(names, [p.cfg for p in ps])
            return ps
        learner = learners.of(configs[0])
        # every point compiles to the first one's program (check_one_program above): they share
        # its trainer, whose traced values each point's state carries (a trainer per point cost
        # ~60 ms each, 10 minutes for 10,000 points)
        trainers = [learner.make(configs[0], env=env)] * len(configs)
        preflight(configs[0], trainers[0], points=P_)
        init = jax.jit(jax.vmap(trainers[0].init))
        # one vmapped call: a PRNGKey per point is ~10 dispatched ops each (minutes for 10,000 points)
        keys = jax.vmap(jax.random.PRNGKey)(np.array([c.budget.seed for c in configs], np.uint32))
        signals.stop_setup()
        ts = allocate(lambda: init(keys, pts.stack_trees([learner.hyper(c) for c in configs])),
                      "allocating the states", configs[0])
        host = jax.device_get(ts)  # each point's entry a view of one host copy, not a device slice each
        del ts
        return [Point(n, d, c, tr, pts.unstack(host, i))
                for i, (n, d, c, tr) in enumerate(signals.setting_up(zip(names, dirs, configs, trainers), P_,
                                                                     step="making the states"))]

    def admit(ps: list[Point]) -> None:  # a resume with something to do: the memory of every point
        preflight(ps[0].cfg, ps[0].trainer, points=P_)

    def claim(holds: session.Holds) -> None:  # lock what is new, check again
        for d in [out, *dirs]:
            if not lock.held(d):
                holds.hold(d)
        _foreign_points(out, names, dirs, configs, resume, known)  # another writer may have been faster

    def nothing_to_do(ps: Sequence[Point]) -> str | None:
        if not (progress and dist.is_writer()):
            return None
        return (f"{out}: nothing to do: every point has reached its budget ({budget_text(ps[0].cfg)}) "
                f"or diverged; give a larger --steps or --trials to continue")

    policy = session.Policy(
        kind=session.POINTS, keep=keep, checkpoint_every=checkpoint_every, freeze_diverged=True, compact=True,
        barrier="points-checked", nothing_to_do=nothing_to_do, table=table,
        stopped="nothing was written" if not resume else f"{out} is as it was; continue with --resume",
        stop_message=lambda sig, st: (f"stopped by signal {sig} after saving every active point; "
                                      f"continue with --resume"))
    return session.run(policy, read, lambda ps: Points(ps, n_dev, group, [i for st in stages for i in st],
                                                       devices=mesh_devices),
                       resume=resume, progress=progress, max_chunks=max_chunks, stages=stages,
                       admit=admit if resume else None, claim=claim, before_start=before_start,
                       on_chunk=on_chunk)


def _foreign_points(out: pathlib.Path, names: Sequence[str], dirs: Sequence[pathlib.Path],
                    configs: Sequence[Config], resume: bool, known: Sequence[str] = ()) -> None:
    """Refuse a points directory holding a run this session does not account for: a point not among
    ``names``, or (a fresh start) a point that holds checkpoints, a compact state or another config
    (only an unsaved start of the same point may be started again). Nothing is written."""
    pdir = out / "points"
    if not pdir.is_dir():
        return
    index = {n: i for i, n in enumerate(names)}
    for d in sorted(pdir.iterdir()):
        held = [n for n in RUN_FILES if (d / n).exists()] if d.is_dir() else []
        if not held:
            continue
        if d.name in known and d.name not in index:
            continue
        if d.name not in index:
            raise RunError(f"{d} holds a run ({', '.join(held)}) that is none of this session's {len(names)} "
                           f"points ({', '.join(names[:4])}{', ...' if len(names) > 4 else ''}); move it away "
                           f"or choose another --out")
        if resume:
            continue
        cfg = configs[index[d.name]]
        saved = existing_step(d) is not None or checkpoint.has_compact(d)
        try:
            own = checkpoint.load_run_config(d)
        except checkpoint.CheckpointError:
            own = None
        same = own is not None and {k: v for k, v in options.flat(own).items() if k not in BUDGET_FIELDS} \
            == {k: v for k, v in options.flat(cfg).items() if k not in BUDGET_FIELDS}
        if saved or not same:
            raise RunError(f"{d} already holds a run ({', '.join(held)}) that a fresh start would overwrite; "
                           f"continue it with --resume, or move it away or choose another --out")
