"""The checks of a run before anything of it is written: its config, its directory, its memory.

Every refusal comes before the first write, so a start that fails leaves no directory that blocks
the next attempt: the learner's checks and the bounds of every field (:func:`check_config`); a
fresh run's ``--out`` new or empty (:func:`fresh_out`: no file of a run, :data:`RUN_FILES`, nor of
anything else); the one-writer lock (:func:`hold`, :mod:`nmrl.runs.lock`: one process writes a run
directory at a time, a second writer is refused naming the holder); the memory estimate of the
run's sizes against the machine's (:func:`preflight`, :func:`preflight_points`,
:mod:`nmrl.runs.memory`); the first allocation, whose failure is :class:`OutOfMemory`
(:func:`allocate`).
"""

from __future__ import annotations

import dataclasses
import functools
import os
import pathlib
import sys
from typing import Callable

import jax

from nmrl import learners, options, tasks
from nmrl.learners.contract import Config
from nmrl.runs import bounds, distributed as dist, io_errors, lock, memory, store
from nmrl.runs.errors import OutOfMemory, RunError
from nmrl.runs.store import RUN_FILES



@functools.lru_cache(maxsize=1)
def physics_timestep() -> float:
    """The MJCF's physics timestep [s]; a control step must be a whole number of them."""
    import mujoco

    from nmrl.paper.env import MODEL_PATH

    return float(mujoco.MjModel.from_xml_path(str(MODEL_PATH)).opt.timestep)


def check_config(cfg: Config) -> None:
    """The learner's checks (``Learner.validate``: its own, then ``cfg.validate()``) and what only
    shows later (in the environment, the PRNG, the budget): a ValueError naming the value and what
    is allowed, before anything is built or written."""
    try:
        learner = learners.of(cfg)
    except TypeError as e:
        raise ValueError(str(e)) from e
    learner.validate(cfg)
    bounds.check(cfg)  # float32-finite floats, int32 integers, the declared ranges (the seed's: 32 bits)
    env = cfg.environment.env
    if env == tasks.PAPER:  # a task checks its own step (nmrl.tasks.check_env)
        ts = cfg.environment.physics_timestep or physics_timestep()
        n = cfg.environment.control_dt / ts
        if abs(n - round(n)) > 1e-6 or round(n) < 1:
            raise ValueError(f"control_dt={cfg.environment.control_dt!r} is invalid: must be a whole multiple of the "
                             f"physics timestep {ts:g} s (e.g. {ts:g}, {2 * ts:g}, {4 * ts:g}; --physics-timestep sets it)")
    if cfg.environment.physics == "c":  # the model the run steps: the paper's or the task's
        from nmrl.physics.mujoco_c import check_supported

        check_supported(tasks.mj_model(env))
    if cfg.budget.trials is not None and cfg.environment.stop_prob == 0:
        raise ValueError(f"trials={cfg.budget.trials} is invalid with stop_prob=0: no trial would ever end; "
                         f"give the budget as --steps")


def fresh_out(out: pathlib.Path) -> None:
    """Refuse an ``--out`` that holds (part of) a run or anything else (a fresh run starts in a new or
    empty directory, so that no file of another kind is mixed with it), is not a directory, or
    cannot be created."""
    if out.exists() and not out.is_dir():
        raise RunError(f"--out={str(out)!r} is invalid: it exists and is not a directory")
    if out.is_dir():
        held = [n for n in RUN_FILES if (out / n).exists()]
        if held:
            raise RunError(f"{out} already holds a run ({', '.join(held)}); continue it with --resume or "
                           f"choose another --out")
        other = store.foreign_entries(out)
        if other:
            raise RunError(f"--out={str(out)!r} is invalid: it holds {len(other)} entries that are no run's "
                           f"({', '.join(other[:3])}{', ...' if len(other) > 3 else ''}); a fresh run starts in a new "
                           f"or empty directory")
        return
    if out.is_symlink():
        raise RunError(f"--out={str(out)!r} is invalid: a broken symbolic link")
    p = out.absolute()
    while not p.exists():
        p = p.parent
    if not p.is_dir():
        raise RunError(f"--out={str(out)!r} is invalid: {p} is not a directory")
    if not os.access(p, os.W_OK | os.X_OK):
        raise RunError(f"--out={str(out)!r} is invalid: {p} is not writable")


def hold(out: pathlib.Path, create: bool = True) -> "lock.Hold | None":
    """The one-writer lock of ``out`` (process 0 only: the others never write); a directory that
    cannot take the lock file is a disk or file system failure naming ``out``."""
    if not dist.is_writer():
        return None
    try:
        return lock.hold(out, create=create)
    except OSError as e:
        f = io_errors.find(e, out)
        if f is None:  # not the disk or file system refusing: a path that cannot be a directory
            raise RunError(f"--out={str(out)!r} is invalid: cannot create the directory ({e.strerror or e})") from None
        raise io_errors.IOFailure(dataclasses.replace(f, path=str(out))) from None


def _sizes(cfg: Config) -> str:
    """The sizes that set a run's memory, as the command line gives them."""
    names = [n for n in options.leaves(type(cfg)) if n == "num_envs" or n.startswith("hidden")]
    return ", ".join(f"{n}={options.value(cfg, n)}" for n in names)


def preflight(cfg: Config, trainer, points: int = 1) -> None:
    """Refuse sizes whose memory estimate exceeds the machine's (RunError naming both)."""
    try:
        est = memory.estimate(trainer.init, jax.random.PRNGKey(0), points=points)
        memory.preflight(est, _sizes(cfg) + (f" for {points} points" if points > 1 else ""),
                         warn=lambda m: print(f"nmrl: warning: {m}", file=sys.stderr, flush=True))
    except memory.TooLarge as e:
        raise RunError(str(e)) from None


def preflight_points(cfg: Config, points: int):
    """Refuse ``points`` runs of ``cfg``'s sizes whose memory estimate exceeds the machine's
    (RunError naming both), before the points' configs exist; returns the environment built for
    the estimate, for :func:`~nmrl.runs.driver.run_points` to share."""
    trainer = learners.of(cfg).make(cfg)
    preflight(cfg, trainer, points=points)
    return trainer.env


def _out_of_memory(e: BaseException) -> bool:
    text = str(e)
    return isinstance(e, MemoryError) or "RESOURCE_EXHAUSTED" in text or "Out of memory" in text


def allocate(fn: Callable, what: str, cfg: Config):
    """``fn()`` with its result computed (an allocation that fails raises :class:`OutOfMemory`)."""
    try:
        return jax.block_until_ready(fn())
    except Exception as e:  # noqa: BLE001 - XlaRuntimeError, MemoryError
        if _out_of_memory(e):
            raise OutOfMemory(f"out of memory {what} ({_sizes(cfg)}): {str(e).strip().splitlines()[0][:200]}; "
                              f"choose smaller sizes") from None
        raise


def create_dir(out: pathlib.Path) -> None:
    """Create ``out`` (and its parents); a path that cannot be a directory is a RunError naming it."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise RunError(f"--out={str(out)!r} is invalid: cannot create the directory ({e.strerror or e})") from e
