"""The one driver of training runs: 1..P points, chunk by chunk, with signals and progress.

The driver runs any learner of nmrl/learners/ (the contract: nmrl/learners/contract.py; the
paper's actor-critic is ``ac``): a run's config is of one learner, whose ``make`` gives the pure
``init`` and ``chunk``. Its two entry points set a session up and hand it to the one chunk loop
(nmrl/runs/loop.py):

* :func:`train` -- one run (``nmrl train``): its N environments split over the local devices
  (``psum``-ed updates, nmrl/runs/sharding.py). A run whose parameters diverge stops with
  :class:`~nmrl.runs.errors.Diverged` and keeps its last good checkpoint.
* :func:`run_points` -- P runs (the points of a sweep or study) as one compiled program
  (nmrl/runs/points.py: the points over the devices, one at a time per device). A diverged point
  is frozen at its last good checkpoint and the others go on; ``priority`` stages the points.

Both go the same way: the checks (nmrl/runs/preflight.py) or a resume's reads
(nmrl/runs/resume.py: a run continues with its own config, only the budget may change), the
points laid out on the devices (nmrl/runs/layout.py), the compile, then the run's files and the
chunk loop. One process writes a run directory at a time (:mod:`nmrl.runs.lock`, held from before
the run is read until the command ends; a second writer is refused naming the holder). Nothing is
written before every check, the memory estimate and the first allocation have passed and the chunk
has compiled: a start that fails or is stopped before its first chunk leaves no directory that
blocks the next attempt. Several processes (nmrl/runs/distributed.py) run the same session in
lockstep: every process reads the run directory before process 0 writes (a barrier in between).

The names other modules reach through the driver are imported here: the exceptions
(nmrl/runs/errors.py), the checks, the resume's and the loop's functions, and the run store's.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import pathlib
import sys
import time
from typing import Callable, Sequence

import jax
import numpy as np

from nmrl import learners
from nmrl.learners import heartbeat
from nmrl.learners.contract import Config
from nmrl.runs import checkpoint, distributed as dist, lock, sharding, signals, store
from nmrl.runs import points as pts
from nmrl.runs.errors import RunError
from nmrl.runs.layout import OneRun, Point, Points, begin_fresh, begin_resumed, num_shards
from nmrl.runs.loop import (Progress, budget_done, budget_text, compile_or_stop, drive, guarded, next_save,
                            progress_table)
from nmrl.runs.preflight import allocate, check_config, fresh_out, hold, preflight
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
    with guarded() as guard, contextlib.ExitStack() as cleanup:
        held = None
        started = False  # whether anything of the run was written in this call
        try:
            guard.at("starting")
            if resume:
                held = hold(out, create=False) if out.is_dir() else None  # before the run is read
                cfg, trainer, ts, record = load_resume(cfg, out, given, step)
                num_shards(cfg, devices)  # a bad device count is refused before anything is written
                if budget_done(cfg, int(ts.step), int(ts.trials)):
                    print(f"{out}: nothing to do: the run is at step {int(ts.step)} ({int(ts.trials)} trials), its "
                          f"budget is {budget_text(cfg)}; give a larger "
                          f"--steps or --trials to continue", file=sys.stderr, flush=True)
                    return []
                p = Point(out.name, out, cfg, trainer, ts, record=record)
            else:
                check_config(cfg)
                cfg = cfg.resolved()
                fresh_out(out)
                trainer = learners.of(cfg).make(cfg)
                num_shards(cfg, devices)
                preflight(cfg, trainer)
                held = hold(out)  # creates the directory (removed again if nothing is written)
                if held is not None:  # a second signal's immediate exit before the first write leaves nothing
                    guard.on_exit.append(lambda: None if started else held.release(remove_if_empty=True))
                fresh_out(out)  # again under the lock: another writer may have finished meanwhile
                ts = allocate(lambda: jax.jit(trainer.init)(jax.random.PRNGKey(cfg.seed)), "allocating the state", cfg)
                p = Point(out.name, out, cfg, trainer, ts)
            dist.barrier("train-checked")  # several processes: all have read the run before process 0 writes
            guard.stop_setup()
            if cfg.steps is not None and cfg.steps % cfg.chunk_steps:
                end = math.ceil(cfg.steps / cfg.chunk_steps) * cfg.chunk_steps
                print(f"note: the budget of {cfg.steps} steps is not a whole number of chunks of {cfg.chunk_steps}: "
                      f"the run stops after whole chunks, at step {end}", file=sys.stderr, flush=True)
            layout = OneRun(p, devices)
            n_dev = layout.n_dev
            progress = progress and dist.is_writer()
            if progress:
                procs = f", {jax.process_count()} processes" if dist.active() else ""
                print(f"train: {cfg.num_envs} environments on {n_dev} device(s), {cfg.num_envs // n_dev} per device "
                      f"({len(jax.local_devices())} local {jax.local_devices()[0].platform} device(s){procs})",
                      file=sys.stderr, flush=True)
            # a chunk's heartbeats where its program calls the host anyway (nmrl/learners/heartbeat.py)
            beat_to: list = []  # the progress line, once it exists
            if progress and getattr(cfg, "physics", None) == "c":  # where the program calls the host anyway
                cleanup.enter_context(heartbeat.listening(lambda *b: beat_to and beat_to[-1](*b)))
            compile_or_stop(guard, layout, cfg, step=int(p.ts.step),
                            chunk=(f"the training chunk ({cfg.num_envs} environments on {n_dev} device(s))"
                                   if progress else None),
                            stopped=("nothing of the run was written" if not resume else
                                     f"the run in {out} is as it was; continue with: nmrl train --resume --out {out}"))
            if dist.is_writer():  # every check passed and the chunk compiled: now the run's files
                started = True
                if resume:
                    begin_resumed(p)
                else:
                    store.write_config(out, cfg)
            bar = Progress(cfg, progress, int(p.ts.step) if cfg.steps is not None else int(p.ts.trials))
            try:
                beat_to.append(bar.beat)
                return drive([p], layout, guard=guard, stages=[[0]], checkpoint_every=1, keep=keep,
                             freeze_diverged=False, compact=False, on_chunk=lambda new: bar.update(new[0]),
                             max_chunks=max_chunks,
                             stop_message=lambda sig, st: (f"stopped by signal {sig} at step {st} (saved); continue "
                                                           f"with: nmrl train --resume --out {out}"))
            finally:
                bar.close()
        finally:
            if held is not None:
                held.release(remove_if_empty=not started)


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
    writer = dist.is_writer()
    with guarded() as guard:
        holds: list = []
        started = False  # whether anything was written in this call
        try:
            guard.at("starting")
            if out.is_dir():
                holds.append(hold(out, create=False))  # the sweep's directory, before any of it is read
            _foreign_points(out, names, dirs, configs, resume, known)
            holds += [hold(d, create=False) for d in dirs if d.is_dir()]  # each existing point, too
            ps: list[Point] = []
            if resume:
                for n, d, c in signals.setting_up(zip(names, dirs, configs), P_, step="reading the points"):
                    if not any((d / f).exists() for f in RUN_FILES):  # deleted, or never begun: a fresh point
                        if writer:
                            print(f"nmrl: note: point {n} has no run in {d}: it starts fresh", file=sys.stderr,
                                  flush=True)
                        tr = learners.of(c).make(c, env=env)
                        env = env or tr.env
                        ts = jax.jit(tr.init)(jax.random.PRNGKey(c.seed))
                        ps.append(Point(n, d, c, tr, ts))
                        continue
                    # a diverged point stopped saving at its last good step and stays frozen there
                    frozen = any(is_diverged(r) for r in read_metrics(d))
                    cfg, tr, ts, record = load_resume(c, d, dataclasses.asdict(c), None, env=env)
                    env = env or tr.env
                    ps.append(Point(n, d, cfg, tr, ts, frozen=frozen, record=record))
                pts.check_one_program(names, [p.cfg for p in ps])
                if all(p.frozen or budget_done(p.cfg, int(p.ts.step), int(p.ts.trials)) for p in ps):
                    # nothing to continue: no compile, nothing written (no resume records), as train() does
                    if progress and writer:
                        print(f"{out}: nothing to do: every point has reached its budget ({budget_text(ps[0].cfg)}) "
                              f"or diverged; give a larger --steps or --trials to continue", file=sys.stderr,
                              flush=True)
                    return []
                preflight(ps[0].cfg, ps[0].trainer, points=P_)
            else:
                learner = learners.of(configs[0])
                # every point compiles to the first one's program (check_one_program above): they share
                # its trainer, whose traced values each point's state carries (a trainer per point cost
                # ~60 ms each, 10 minutes for 10,000 points)
                trainers = [learner.make(configs[0], env=env)] * len(configs)
                preflight(configs[0], trainers[0], points=P_)
                init = jax.jit(jax.vmap(trainers[0].init))
                # one vmapped call: a PRNGKey per point is ~10 dispatched ops each (minutes for 10,000 points)
                keys = jax.vmap(jax.random.PRNGKey)(np.array([c.seed for c in configs], np.uint32))
                signals.stop_setup()
                ts = allocate(lambda: init(keys, pts.stack_trees([learner.hyper(c) for c in configs])),
                              "allocating the states", configs[0])
                host = jax.device_get(ts)  # each point's entry a view of one host copy, not a device slice each
                ps = [Point(n, d, c, tr, pts.unstack(host, i))
                      for i, (n, d, c, tr) in enumerate(signals.setting_up(zip(names, dirs, configs, trainers), P_,
                                                                           step="making the states"))]
                del host
                del ts
            dist.barrier("points-checked")  # several processes: all have read the points before process 0 writes
            signals.stop_setup()
            layout = Points(ps, n_dev, group, [i for st in stages for i in st], devices=mesh_devices)
            for p in ps:
                p.ts = None  # the layout holds the states now
            progress = progress and writer
            if progress:
                print(f"sweep: {P_} points x {configs[0].num_envs} environments on {n_dev} "
                      f"{jax.local_devices()[0].platform} device(s), {layout.per_dev} point(s) per device stepped "
                      f"{'one at a time' if group == 1 else f'in vmapped groups of {group}'} "
                      f"({configs[0].num_envs * min(group, layout.per_dev)} environments per device at a time)",
                      file=sys.stderr, flush=True)
            compile_or_stop(guard, layout, configs[0], step=0, chunk="the sweep chunk" if progress else None,
                            stopped=("nothing was written" if not resume else
                                     f"{out} is as it was; continue with --resume"))
            if writer:  # every check passed and the chunk compiled: lock what is new, check again, then write
                for d in [out, *dirs]:
                    if not lock.held(d):
                        holds.append(hold(d))
                _foreign_points(out, names, dirs, configs, resume, known)  # another writer may have been faster
            started = True
            if before_start is not None:
                before_start()
            if writer:
                for p in ps:
                    if p.record is not None:
                        begin_resumed(p)
                    else:
                        begin_fresh(p)
            last_rows: dict = {}
            t_start = time.time()

            def chunk_done(new: dict[int, dict]) -> None:
                last_rows.update({names[i]: r for i, r in new.items()})
                if on_chunk is not None:
                    on_chunk()
                if progress and table:
                    r = min(new.values(), key=lambda r: r["step"], default=None)  # the point furthest behind
                    due = next_save(r["step"], configs[0].chunk_steps, checkpoint_every, r["wall_s"]) if r else ""
                    print(progress_table(names, last_rows, time.time() - t_start, due), file=sys.stderr, flush=True)

            return drive(ps, layout, guard=guard, stages=stages, checkpoint_every=checkpoint_every, keep=keep,
                         freeze_diverged=True, compact=True, on_chunk=chunk_done, max_chunks=max_chunks,
                         stop_message=lambda sig, st: (f"stopped by signal {sig} after saving every active point; "
                                                       f"continue with --resume"))
        finally:
            for h in reversed(holds):
                if h is not None:
                    h.release(remove_if_empty=not started)


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
        same = own is not None and {k: v for k, v in dataclasses.asdict(own).items() if k not in BUDGET_FIELDS} \
            == {k: v for k, v in dataclasses.asdict(cfg).items() if k not in BUDGET_FIELDS}
        if saved or not same:
            raise RunError(f"{d} already holds a run ({', '.join(held)}) that a fresh start would overwrite; "
                           f"continue it with --resume, or move it away or choose another --out")
