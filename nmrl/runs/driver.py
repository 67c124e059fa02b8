"""The one driver of training runs: 1..P points, chunk by chunk, with signals and progress.

The driver runs any learner of nmrl/learners/ (the contract: nmrl/learners/contract.py; the
paper's actor-critic is ``ac``): a run's config is of one learner, whose ``make`` gives the pure
``init`` and ``chunk``. Between two chunks of ``chunk_steps`` control steps (one ``jit``-compiled
``lax.scan``) the driver only appends one metrics row per point to its
``metrics.jsonl``, checkpoints the points (one :class:`~nmrl.runs.checkpoint.Checkpointer` per
point, saving every ``checkpoint_every`` chunks, when a point finishes and when a signal stops
the loop) and shows progress. Two layouts of the same loop:

* :func:`train` -- one run (``nmrl train``): its N environments split over the local devices
  (``psum``-ed updates, nmrl/runs/sharding.py). A run whose parameters diverge stops with
  :class:`Diverged` and keeps its last good checkpoint.
* :func:`run_points` -- P runs (the points of a sweep or study) as one compiled program
  (nmrl/runs/points.py: the points over the devices, one at a time per device). A diverged point
  is frozen at its last good checkpoint and the others go on; ``priority`` stages the points.

Several processes (nmrl/runs/distributed.py) run the same loop in lockstep: each chunk starts at
a barrier, after it they agree on the signal and on process 0's checkpoint decisions, and only
process 0 writes; every process reads the run directory before that (a barrier in between).

SIGINT/SIGTERM at any moment go through one :class:`nmrl.runs.signals.Guard` (the command's, else
the driver's own): during the compile the run stops when the compile returns, before anything of
it is written; during the chunk loop after the chunk in flight, every active point saved
(:class:`Stopped`); a second signal stops at once (the last checkpoints are intact because
checkpoints are written atomically).

One process writes a run directory at a time (:mod:`nmrl.runs.lock`, held from before the run is
read until the command ends; a second writer is refused naming the holder). Nothing is written
before every check, the memory estimate (:mod:`nmrl.runs.memory`) and the first allocation have
passed and the chunk has compiled: a start that fails or is stopped before its first chunk leaves
no directory that blocks the next attempt.

A run directory has one identity, the config it was created with (``config.json``; see
nmrl/runs/checkpoint.py and nmrl/runs/store.py). A fresh run never starts in a directory that
holds any part of a run (:data:`RUN_FILES`). A resume -- of a run or of every point -- goes through
one function (:func:`_resume`): it continues the run with its own config, only the budget may
change (recorded in ``config.json`` and ``resumes.jsonl``), from its newest checkpoint or the one
asked for (else from its compact continuation state, else from the start if it never ran a chunk),
and refuses a checkpoint of another run or a corrupted one (naming the newest good one). Every
refusal happens before anything is written.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import pathlib
import signal
import sys
import time
from typing import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from nmrl import learners
from nmrl.runs import bounds, checkpoint, distributed as dist, io_errors, lock, memory, sharding, signals, store
from nmrl.runs import points as pts
from nmrl.runs.store import (CONFIG_FILE, METRICS_FILE, RESUMES_FILE, RUN_FILES, append_metrics,  # noqa: F401
                             is_diverged, read_metrics, to_python, truncate_metrics)

#: Config fields a resume may change (the budget); the others are the run's identity.
BUDGET_FIELDS = checkpoint.RESUMABLE_FIELDS
#: JAX PRNG seeds are 32-bit: larger (or negative) seeds wrap around to another seed's key.
SEED_MAX = 2**32 - 1
#: A learner's config and Trainer (nmrl/learners/contract.py).
Config = object
Trainer = object


class RunError(Exception):
    """A run cannot start or continue (message says why); nothing was written."""


class Diverged(Exception):
    """Training diverged; the last good checkpoint is kept."""


class OutOfMemory(Exception):
    """The machine ran out of memory allocating the run (its sizes passed the estimate); nothing of
    the run is left."""


class Stopped(Exception):
    """SIGINT/SIGTERM stopped the run after the chunk in flight was saved; ``rows`` were written."""

    def __init__(self, signum: int, step: int, rows: list[dict]):
        super().__init__(f"stopped by signal {signum} at step {step}")
        self.signum, self.step, self.rows = signum, step, rows

    @property
    def exit_status(self) -> int:
        """The shell's convention for a process ended by a signal: 128 + the signal (130, 143)."""
        return 128 + self.signum


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
    bounds.check(cfg)  # float32-finite floats, int32 integers, the ranges of shared fields
    if not (isinstance(cfg.seed, int) and not isinstance(cfg.seed, bool) and 0 <= cfg.seed <= SEED_MAX):
        raise ValueError(f"seed={cfg.seed!r} is invalid: must be an integer in [0, {SEED_MAX}] "
                         f"(JAX's PRNG seeds are 32-bit; others wrap around to another seed)")
    ts = getattr(cfg, "physics_timestep", None) or physics_timestep()
    n = cfg.control_dt / ts
    paper = getattr(cfg, "env", "paper-cheetah") == "paper-cheetah"  # a task checks its own (nmrl.tasks)
    if paper and (abs(n - round(n)) > 1e-6 or round(n) < 1):
        raise ValueError(f"control_dt={cfg.control_dt!r} is invalid: must be a whole multiple of the physics "
                         f"timestep {ts:g} s (e.g. {ts:g}, {2 * ts:g}, {4 * ts:g}; --physics-timestep sets it)")
    if getattr(cfg, "physics", "mjx") == "c":
        import mujoco

        from nmrl.paper.env import MODEL_PATH
        from nmrl.physics.mujoco_c import check_supported

        check_supported(mujoco.MjModel.from_xml_path(str(MODEL_PATH)))
    if cfg.trials is not None and cfg.stop_prob == 0:
        raise ValueError(f"trials={cfg.trials} is invalid with stop_prob=0: no trial would ever end; "
                         f"give the budget as --steps")


def _fresh_out(out: pathlib.Path) -> None:
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


def _hold(out: pathlib.Path, create: bool = True) -> "lock.Hold | None":
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
    names = [f.name for f in dataclasses.fields(cfg) if f.name == "num_envs" or f.name.startswith("hidden")]
    return ", ".join(f"{n}={getattr(cfg, n)}" for n in names)


def _preflight(cfg: Config, trainer, points: int = 1) -> None:
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
    the estimate, for :func:`run_points` to share."""
    trainer = learners.of(cfg).make(cfg)
    _preflight(cfg, trainer, points=points)
    return trainer.env


def _out_of_memory(e: BaseException) -> bool:
    text = str(e)
    return isinstance(e, MemoryError) or "RESOURCE_EXHAUSTED" in text or "Out of memory" in text


def _allocate(fn: Callable, what: str, cfg: Config):
    """``fn()`` with its result computed (an allocation that fails raises :class:`OutOfMemory`)."""
    try:
        return jax.block_until_ready(fn())
    except Exception as e:  # noqa: BLE001 - XlaRuntimeError, MemoryError
        if _out_of_memory(e):
            raise OutOfMemory(f"out of memory {what} ({_sizes(cfg)}): {str(e).strip().splitlines()[0][:200]}; "
                              f"choose smaller sizes") from None
        raise


def _create_dir(out: pathlib.Path) -> None:
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise RunError(f"--out={str(out)!r} is invalid: cannot create the directory ({e.strerror or e})") from e


def existing_step(run_dir: pathlib.Path) -> int | None:
    """The newest checkpoint step in ``run_dir``, or None when there is none (or no directory)."""
    try:
        return checkpoint.latest_step(run_dir)
    except checkpoint.CheckpointError:
        return None


def _train_devices(cfg: Config, devices: int | None = None) -> list:
    """The devices the environment batch is split over: ``devices`` per process (default: all local
    devices). One process lowers the count to the largest that divides N; several processes
    (nmrl/runs/distributed.py) use the same count on each and need N to be a multiple of the total."""
    avail = len(jax.local_devices())
    if devices is not None and not (isinstance(devices, int) and 1 <= devices <= avail):
        raise RunError(f"devices={devices!r} is invalid: this process has {avail} local device(s)")
    n = avail if devices is None else devices
    if not dist.active():
        while cfg.num_envs % n:
            n -= 1
        return jax.local_devices()[:n]
    devs = sharding.process_devices(n)
    if cfg.num_envs % len(devs):
        raise RunError(f"num_envs={cfg.num_envs} is invalid for {jax.process_count()} processes with {n} device(s) "
                       f"each: the environments are split over all {len(devs)} devices, so N must be a multiple "
                       f"of {len(devs)}")
    return devs


def _num_shards(cfg: Config, devices: int | None = None) -> int:
    """How many devices (of every process) the environment batch is split over (:func:`_train_devices`)."""
    return len(_train_devices(cfg, devices))


def _sharded_trainer(cfg: Config, trainer, devices: int | None = None):
    n = _num_shards(cfg, devices)
    if n == 1:
        return trainer
    return learners.of(cfg).make(cfg, env=trainer.env, axis_name=sharding.AXIS, num_shards=n)


def stop_on_signals() -> tuple[dict, Callable[[], None]]:
    """Install SIGINT/SIGTERM handlers for a chunk loop: a first signal sets ``stop["signal"]`` (the
    loop stops after the chunk in flight is saved), a second stops at once (KeyboardInterrupt).
    Returns ``(stop, restore)``; call ``restore()`` when the loop ends."""
    stop: dict = {"signal": None}

    def on_signal(signum, _frame):
        if stop["signal"] is not None:
            raise KeyboardInterrupt
        stop["signal"] = signum
        print(f"\nsignal {signum}: stopping after the chunk in flight is saved (again to stop now)",
              file=sys.stderr, flush=True)

    old = {sg: signal.signal(sg, on_signal) for sg in (signal.SIGINT, signal.SIGTERM)}

    def restore() -> None:
        for sg, h in old.items():
            signal.signal(sg, h)

    return stop, restore


def _compile_needed(guard: signals.Guard) -> bool:
    """Whether to compile the chunk: not when one process was already stopped by a signal (it stops
    at once, before anything of the run is written, instead of after a compile of tens of seconds);
    several processes compile and then agree on the signal (nmrl/runs/distributed.py)."""
    return guard.signal is None or dist.active()


def compile_chunk(fn, ts, donate: bool = True):
    """AOT-compile ``fn`` (donating its argument if ``donate``) for ``ts``; returns (compiled, seconds)."""
    t0 = time.time()
    compiled = jax.jit(fn, donate_argnums=0 if donate else ()).lower(ts).compile()
    return compiled, time.time() - t0


def metrics_row(cfg: Config, m: dict, wall: float, points: int = 1) -> dict:
    """One metrics.jsonl object from a chunk's metrics (``points`` programs shared the wall time)."""
    return {"chunk": m["step"] // cfg.chunk_steps, **m, "total_steps": m["step"] * cfg.num_envs,
            "wall_s": wall, "steps_per_s": points * cfg.chunk_steps * cfg.num_envs / wall}


def budget_done(cfg: Config, ts_step: int, ts_trials: int) -> bool:
    if cfg.steps is not None:
        return ts_step >= cfg.steps
    return ts_trials >= cfg.trials


def budget_text(cfg: Config) -> str:
    """The budget :func:`budget_done` checks, as the command line gives it: ``steps=N`` or ``trials=N``."""
    return f"steps={cfg.steps}" if cfg.steps is not None else f"trials={cfg.trials}"


class _Progress:
    """A rich progress bar on a terminal, one plain line per chunk otherwise.

    ``done0`` is where this session started (a resumed run): the ETA extrapolates this session's
    own speed, not the run's whole progress over this session's time.
    """

    def __init__(self, cfg: Config, enabled: bool, done0: int = 0):
        self.cfg = cfg
        self.enabled = enabled
        self.rich = enabled and sys.stderr.isatty()
        self.t0 = time.time()
        self.total = cfg.steps if cfg.steps is not None else cfg.trials
        self.frac0 = min(done0 / self.total, 1.0)
        if self.rich:
            from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

            self.bar = Progress(TextColumn("[bold]train[/]"), BarColumn(), TextColumn("{task.percentage:>5.1f}%"),
                                TimeRemainingColumn(), TextColumn("{task.description}"), transient=False)
            self.task = self.bar.add_task("compiling…", total=self.total, completed=min(done0, self.total))
            self.bar.start()

    def eta(self, frac: float) -> float:
        """Seconds left at ``frac`` of the budget, from this session's speed (nan before any progress)."""
        gained = frac - self.frac0
        return (time.time() - self.t0) * (1 - frac) / gained if gained > 0 else float("nan")

    def update(self, row: dict) -> None:
        if not self.enabled:
            return
        cfg = self.cfg
        done = row["step"] if cfg.steps is not None else row["trials"]
        text = (f"trials {row['trials']:,}  steps {row['total_steps']:,}  {row['steps_per_s']:,.0f} steps/s  "
                f"avg reward {row['avg_reward']:+.3f}  speed {row['forward_speed']:+.2f} m/s")
        if self.rich:
            self.bar.update(self.task, completed=min(done, self.total), description=text)
        else:
            frac = min(done / self.total, 1.0)
            print(f"[{100 * frac:5.1f}%] {text}  ETA {self.eta(frac):,.0f}s", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.rich:
            self.bar.stop()


def _given_changes(ident: Config, given: dict, out: pathlib.Path) -> None:
    """Refuse options given with ``--resume`` that would change the run's identity, naming them all."""
    base = ident.resolved()
    bad = []
    fields = {f.name for f in dataclasses.fields(ident)}
    for k, v in given.items():
        if k in BUDGET_FIELDS:
            continue
        if k not in fields:
            bad.append(f"--{k.replace('_', '-')} {v!r} (the run's learner {learners.of(ident).name!r} has no such "
                       f"option)")
            continue
        try:
            new = getattr(dataclasses.replace(ident, **{k: v}).resolved(), k)
        except (TypeError, ValueError):
            new = v
        if new != getattr(base, k):
            bad.append(f"--{k.replace('_', '-')} {v!r} (the run has {getattr(base, k)!r})")
    if bad:
        raise RunError(f"--resume continues the run in {out} with its own config; these options would change "
                       f"it: {', '.join(bad)}; only the budget (--steps or --trials) may change")


def _budget(cfg: Config) -> dict:
    return {k: getattr(cfg, k) for k in BUDGET_FIELDS}


def _resume(cfg: Config, out: pathlib.Path, given: dict | None, step: int | None, env=None):
    """Everything a resume of the run in ``out`` checks and reads, nothing written:
    ``(config, trainer, state, record)``, the config with the session's budget (``given``'s, else
    ``cfg``'s, else the run's own), the state from the checkpoint ``step`` or the newest one, else from
    the compact continuation state, else (a run that never finished a chunk) the initial state.
    ``record`` is the line for ``resumes.jsonl`` (:func:`_begin_resumed` writes it)."""
    if not out.is_dir():
        why = "it does not exist" if not out.exists() else "it is not a directory"
        raise RunError(f"--resume: no checkpoint found in {out} ({why})")
    run_cfg = checkpoint.load_run_config(out)
    source = str(out / CONFIG_FILE)
    try:
        steps = checkpoint.all_steps(out)
    except checkpoint.CheckpointError:
        if (out / checkpoint.CHECKPOINTS).is_dir():
            raise
        steps = []
    compact = not steps and checkpoint.has_compact(out)
    if not steps:
        rows = read_metrics(out)
        if run_cfg is None or step is not None:
            why = (f"; its {METRICS_FILE} has {len(rows)} row(s) that cannot be continued: choose another --out"
                   if rows else "")
            raise RunError(f"--resume: no checkpoint found in {out}" + why)
        if rows and not compact and dist.is_writer():  # stopped before its first save: it starts again
            print(f"nmrl: note: the run in {out} has no checkpoint yet (it was stopped before its first save): it "
                  f"starts again from step 0 with its own config, and its {len(rows)} metrics row(s) are replaced",
                  file=sys.stderr, flush=True)
    if run_cfg is None:  # a run directory without config.json (written by checkpoint.save alone)
        source = f"the newest checkpoint ({out / checkpoint.CHECKPOINTS / str(steps[-1])})"
        for s in reversed(steps):
            try:
                run_cfg = checkpoint.load_config(out, s)
                break
            except checkpoint.CorruptCheckpoint:
                if s == steps[0]:
                    raise
    has_config = (out / CONFIG_FILE).is_file()
    if type(cfg) is not type(run_cfg):  # before the options, which are the other learner's
        raise RunError(f"--resume continues the run in {out} with its own learner {learners.of(run_cfg).name!r}; "
                       f"--learner {learners.of(cfg).name} would change it")
    if given is not None:
        _given_changes(run_cfg, given, out)
        new_budget = {k: given.get(k) for k in BUDGET_FIELDS}
    else:  # library callers: the budget of ``cfg``, if it has one
        new_budget = _budget(cfg)
    if all(v is None for v in new_budget.values()):
        new_budget = None
    trainer = learners.of(run_cfg).make(run_cfg, env=env)
    _preflight(run_cfg, trainer)  # before the state is restored or made: sizes beyond the machine

    def load(s: int):
        meta = checkpoint.load_metadata(out, s)
        checkpoint.check_identity(meta, run_cfg, source)
        return meta, checkpoint.restore(out, trainer, step=s)

    if compact:  # no full checkpoint (e.g. a fresh clone of published results): statistically equal
        meta = {"path": str(checkpoint.compact_path(out))}
        ts = checkpoint.restore_compact(out, trainer)
        old_budget = _budget(run_cfg)
    elif not steps:  # created, stopped before its first checkpoint: start it again, as it would have run
        meta, ts = None, jax.jit(trainer.init)(jax.random.PRNGKey(run_cfg.seed))
        old_budget = _budget(run_cfg)
    else:
        start = steps[-1]
        rows = read_metrics(out) if step is None else []
        if rows and rows[-1]["step"] < steps[-1] and any(s <= rows[-1]["step"] for s in steps):
            # the newest chunk's row was lost (a partial line dropped): run that chunk again from the newest
            # checkpoint its rows reach, so metrics.jsonl stays whole
            start = max(s for s in steps if s <= rows[-1]["step"])
        try:  # the newest checkpoint or the one asked for (newest_good with a step: no fallback)
            s, (meta, ts), _ = checkpoint.newest_good(out, load, step if step is not None else start)
        except checkpoint.CorruptCheckpoint as e:
            if step is not None:
                raise
            good = None
            for s in reversed(steps[:-1]):
                try:
                    load(s)
                except checkpoint.CheckpointError:
                    continue
                good = s
                break
            hint = (f"resume from the newest good checkpoint with --resume --step {good}" if good is not None
                    else "no older checkpoint is readable either")
            raise RunError(f"{e}; {hint} (nothing was changed)") from e
        except checkpoint.ForeignCheckpoint as e:
            asked = step if step is not None else start
            fits = []  # only checkpoints without the mismatch are worth naming
            for s in steps:
                if s == asked:
                    continue
                try:
                    checkpoint.check_identity(checkpoint.load_metadata(out, s), run_cfg, source)
                except checkpoint.CheckpointError:
                    continue
                fits.append(s)
            if fits:
                hint = f" (checkpoints of this run: --step {fits})"
            elif has_config and len(steps) > 1:
                hint = (f"; every checkpoint in {out} differs from its {CONFIG_FILE} the same way: if it was "
                        f"edited, restore it (nothing was changed)")
            elif has_config:
                hint = f"; if {CONFIG_FILE} was edited, restore it (nothing was changed)"
            else:
                hint = ""
            raise RunError(f"{e}{hint}") from e
        old_budget = {k: meta["config"].get(k) for k in BUDGET_FIELDS}
    new = dataclasses.replace(run_cfg, **(new_budget or old_budget))
    try:
        check_config(new)
        cfg = new.resolved()
    except ValueError as e:
        raise RunError(str(e)) from e
    # config.json keeps the run's identity and states its current budget
    write_config = not has_config or _budget(cfg) != _budget(run_cfg)
    record = {"unix_time": time.time(), "from_step": int(ts.step),
              "from_checkpoint": meta["path"] if meta else None,
              "previous_budget": old_budget, "budget": _budget(cfg), "config_json_updated": write_config}
    return cfg, trainer, ts, record


# ----------------------------------------------------------------------------- the points of a session


@dataclasses.dataclass
class _Point:
    """One run of this session: its directory, config (with this session's budget), trainer, the
    state it starts from, and whether it is frozen (diverged before this session)."""

    name: str
    dir: pathlib.Path
    cfg: Config
    trainer: Trainer
    ts: object
    frozen: bool = False
    record: dict | None = None  #: the resume record (None for a fresh start)


def _begin_fresh(p: _Point) -> None:
    """Write a fresh point's config.json and drop metrics of an earlier, unsaved start."""
    store.write_config(p.dir, p.cfg)
    store.remove_metrics(p.dir)


def _begin_resumed(p: _Point) -> None:
    """What a resume writes, after every point's checks passed: the metrics after the restored step
    are dropped (not for a frozen point: its last rows say why it stopped), a changed budget is
    written to config.json, and the resume is recorded in resumes.jsonl."""
    if not p.frozen:
        truncate_metrics(p.dir, p.record["from_step"])
    if p.record["config_json_updated"]:
        store.write_config(p.dir, p.cfg)
    store.append_resume(p.dir, p.record)


class _OneRun:
    """Layout of :func:`train`: one point, its environments split over ``n_dev`` devices (of every
    process in a multi-process run)."""

    def __init__(self, p: _Point, devices: int | None):
        devs = _train_devices(p.cfg, devices)
        self.n_dev = n_dev = len(devs)
        trainer = _sharded_trainer(p.cfg, p.trainer, devices)
        if n_dev > 1:
            program, self.place = sharding.shard_train_chunk(trainer.chunk, p.ts, sharding.make_mesh(devs),
                                                             learners.of(p.cfg).env_fields)
        else:
            program, self.place = trainer.chunk, jax.device_put
        self.ts = self.place(p.ts)  # committed inputs: no second, hidden compile of the chunk
        self.program = program

    def compile(self) -> float:
        self.chunk, compile_s = compile_chunk(self.program, self.ts)
        return compile_s

    def run(self, active: np.ndarray) -> list[dict | None]:
        ts_new, m = self.chunk(self.ts)
        m = to_python(dist.host(m))
        self.ts = self.place(ts_new)
        return [m]

    def state(self, i: int):
        """The state to checkpoint (several processes: gathered to the host, a collective)."""
        return dist.host(self.ts) if dist.active() else self.ts

    def counters(self) -> list[tuple[int, int, bool]]:
        """(step, trials, diverged) of the one point (several processes: a gather)."""
        step, trials, div = dist.host((self.ts.step, self.ts.trials, self.ts.diverged))
        return [(int(step), int(trials), bool(div))]


class _Points:
    """Layout of :func:`run_points`: the stacked points over ``n_dev`` devices (nmrl/runs/points.py)."""

    def __init__(self, ps: Sequence[_Point], n_dev: int, group: int, order: Sequence[int],
                 devices: Sequence | None = None):
        self.n_dev, self.devices = n_dev, devices
        self.slots = pts.slot_order(len(ps), n_dev, order)
        self.slot_of = {i: j for j, i in enumerate(self.slots) if i >= 0}
        self.ts = self._place(pts.stack_trees([ps[i if i >= 0 else 0].ts for i in self.slots]))
        self.program = pts.points_program(ps[0].trainer.chunk, n_dev, group, devices=devices)
        self.per_dev = len(self.slots) // n_dev
        self._host = None  # the host copy of the states gathered for this chunk's saves (several processes)

    def _place(self, tree):
        return pts.place_points(tree, self.n_dev, devices=self.devices)

    def compile(self) -> float:
        t0 = time.time()
        active_like = self._place(np.zeros(len(self.slots), bool))
        self.chunk = jax.jit(self.program, donate_argnums=0).lower(self.ts, active_like).compile()
        return time.time() - t0

    def run(self, active: np.ndarray) -> list[dict | None]:
        act_slots = np.array([i >= 0 and active[i] for i in self.slots])
        self.ts, m = self.chunk(self.ts, self._place(jnp.asarray(act_slots)))
        self._host = None
        m = dist.host(m)
        return [to_python({k: v[self.slot_of[i]] for k, v in m.items()}) if a else None
                for i, a in enumerate(active)]

    def state(self, i: int):
        """Point ``i``'s state (several processes: from one host copy of every point per chunk,
        gathered at the first save -- a collective every process makes at the same save)."""
        if not dist.active():
            return pts.unstack(self.ts, self.slot_of[i])
        if self._host is None:
            self._host = dist.host(self.ts)
        return pts.unstack(self._host, self.slot_of[i])

    def counters(self) -> list[tuple[int, int, bool]]:
        """(step, trials, diverged) of every point, in point order (several processes: one gather)."""
        step, trials, div = dist.host((self.ts.step, self.ts.trials, self.ts.diverged))
        return [(int(step[j]), int(trials[j]), bool(div[j])) for _, j in sorted(self.slot_of.items())]


def _drive(ps: Sequence[_Point], layout, *, stages: list[list[int]], checkpoint_every: int, keep: int,
           freeze_diverged: bool, compact: bool, on_chunk: Callable[[dict[int, dict]], None] | None,
           stop_message: Callable[[int, int], str], max_chunks: int | None) -> list[dict]:
    """The chunk loop of every run: step the active points of the first unfinished stage, append
    their metrics rows, checkpoint them, report progress, stop on signals. Returns the rows written
    (every point's, in order). A diverged point raises :class:`Diverged` (``freeze_diverged`` False)
    or is frozen at its last good checkpoint while the others go on."""
    writer = dist.is_writer()  # several processes: only process 0 writes (nmrl/runs/distributed.py)
    ckpts = [checkpoint.Checkpointer(p.dir, keep=keep, every_steps=checkpoint_every * p.cfg.chunk_steps)
             if writer else None for p in ps]
    done = np.zeros(len(ps), bool)
    dist.barrier("drive")  # several processes: every one has compiled (counters() may gather)
    for i, (p, (step, trials, div)) in enumerate(zip(ps, layout.counters(), strict=True)):
        done[i] = budget_done(p.cfg, step, trials) or (freeze_diverged and (div or p.frozen))
    rows: list[dict] = []
    unsaved: set[int] = set()  # points whose newest metrics row has no checkpoint yet
    n_chunks = 0

    def save(i: int) -> None:
        guard.at("saving")
        one = layout.state(i)  # every process (a gather when there are several)
        if writer:
            ckpts[i].save(one, ps[i].cfg)
            if compact:
                checkpoint.save_compact(ps[i].dir, one, ps[i].cfg)
        unsaved.discard(i)
        guard.at("training")

    guard = signals.active()
    own_guard = guard is None  # a library call: the loop's own (a command installs one for its whole life)
    if own_guard:
        guard = signals.Guard().install()
    stop = guard  # ``stop.signal``: the first signal received (or agreed on by every process)
    guard.at("training")
    try:
        while not done.all():
            # several processes: start every chunk together (their compiles and process 0's saves take
            # different times; the collectives inside a chunk would wait only gloo's own 30 s)
            dist.barrier(f"chunk-{n_chunks}")
            stage = next(st for st in stages if not all(done[i] for i in st))
            active = np.zeros(len(ps), bool)
            active[[i for i in stage if not done[i]]] = True
            t0 = time.time()
            ms = _allocate(lambda: layout.run(active), "running a chunk", ps[0].cfg)
            wall = time.time() - t0
            n_active = int(active.sum())
            new: dict[int, dict] = {}
            want = np.zeros(len(ps), bool)  # the points this process would checkpoint now
            for i, p in enumerate(ps):
                if not active[i]:
                    continue
                row = metrics_row(p.cfg, ms[i], wall, points=n_active)
                if writer:
                    append_metrics(p.dir, row)
                rows.append(row)
                new[i] = row
                if is_diverged(row):
                    done[i] = True  # its last good checkpoint is kept; frozen from now on
                    if not freeze_diverged:
                        last = ckpts[i].latest_step() if writer else "the newest"
                        norms = ", ".join(f"{k.removesuffix('_norm')} norm {row[k]:.3g}"
                                          for k in learners.norm_keys(row))
                        kept = (f"the last good checkpoint (step {last}) is kept in {p.dir}" if last is not None
                                else "no checkpoint was kept (it diverged in its first chunk)")
                        raise Diverged(
                            f"training diverged at step {row['step']} ({norms}, limit {p.cfg.max_param_norm:g}); "
                            f"{kept}. Try smaller step sizes.")
                    continue
                finished = budget_done(p.cfg, row["step"], row["trials"])
                want[i] = (finished or checkpoint_every == 1 or stop.signal is not None
                           or (writer and ckpts[i].should_save(row["step"])))
                if finished:
                    done[i] = True
            # several processes: process 0's checkpoint decisions, and a signal that reached any of them
            signum, want = _agreed(stop.signal, want)
            for i, row in new.items():
                if is_diverged(row):
                    continue
                if want[i] or signum is not None:
                    save(i)
                else:
                    unsaved.add(i)
            if on_chunk is not None:
                on_chunk(new)
            n_chunks += 1
            if not dist.active():  # one process: a signal during on_chunk stops now, too
                signum = stop.signal
            if signum is not None:
                stop.signal = signum
                for i in sorted(unsaved):  # the signal came after this chunk's saves
                    save(i)
                step = max(r["step"] for r in new.values()) if new else 0
                print(stop_message(stop.signal, step), file=sys.stderr, flush=True)
                raise Stopped(stop.signal, step, rows)
            if max_chunks is not None and n_chunks >= max_chunks:
                break
    finally:
        guard.at("finishing")
        if own_guard:
            guard.restore()
        for c in ckpts:
            if c is not None:
                c.close()
    return rows


def _agreed(signum: int | None, want: np.ndarray) -> tuple[int | None, np.ndarray]:
    """``(signal, save mask)`` every process acts on after a chunk: the largest signal number any
    process received (None: none) and process 0's checkpoint decisions (one small collective; one
    process: its own)."""
    if not dist.active():
        return signum, want
    table = dist.exchange(np.concatenate([[signum or 0], want.astype(np.int32)]))
    s = int(table[:, 0].max())
    return (s or None), table[0, 1:].astype(bool)


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

    Raises :class:`Diverged` when the parameters diverge, :class:`Stopped` after SIGINT/SIGTERM.
    ``max_chunks`` stops after that many chunks (used by tests to interrupt a run).
    """
    out = pathlib.Path(out)
    if step is not None and not resume:
        raise RunError(f"--step={step} picks the checkpoint to resume from and needs --resume "
                       f"(the budget is --steps)")
    guard = signals.active()
    own_guard = guard is None
    if own_guard:
        guard = signals.Guard().install()
    held = None
    started = False  # whether anything of the run was written in this call
    try:
        guard.at("starting")
        if resume:
            held = _hold(out, create=False) if out.is_dir() else None  # before the run is read
            cfg, trainer, ts, record = _resume(cfg, out, given, step)
            _num_shards(cfg, devices)  # a bad device count is refused before anything is written
            if budget_done(cfg, int(ts.step), int(ts.trials)):
                print(f"{out}: nothing to do: the run is at step {int(ts.step)} ({int(ts.trials)} trials), its "
                      f"budget is {budget_text(cfg)}; give a larger "
                      f"--steps or --trials to continue", file=sys.stderr, flush=True)
                return []
            p = _Point(out.name, out, cfg, trainer, ts, record=record)
        else:
            check_config(cfg)
            cfg = cfg.resolved()
            _fresh_out(out)
            trainer = learners.of(cfg).make(cfg)
            _num_shards(cfg, devices)
            _preflight(cfg, trainer)
            held = _hold(out)  # creates the directory (removed again if nothing is written)
            if held is not None:  # a second signal's immediate exit before the first write leaves nothing
                guard.on_exit.append(lambda: None if started else held.release(remove_if_empty=True))
            _fresh_out(out)  # again under the lock: another writer may have finished meanwhile
            ts = _allocate(lambda: jax.jit(trainer.init)(jax.random.PRNGKey(cfg.seed)), "allocating the state", cfg)
            p = _Point(out.name, out, cfg, trainer, ts)
        dist.barrier("train-checked")  # several processes: all have read the run before process 0 writes
        if cfg.steps is not None and cfg.steps % cfg.chunk_steps:
            end = math.ceil(cfg.steps / cfg.chunk_steps) * cfg.chunk_steps
            print(f"note: the budget of {cfg.steps} steps is not a whole number of chunks of {cfg.chunk_steps}: "
                  f"the run stops after whole chunks, at step {end}", file=sys.stderr, flush=True)
        layout = _OneRun(p, devices)
        n_dev = layout.n_dev
        progress = progress and dist.is_writer()
        if progress:
            procs = f", {jax.process_count()} processes" if dist.active() else ""
            print(f"train: {cfg.num_envs} environments on {n_dev} device(s), {cfg.num_envs // n_dev} per device "
                  f"({len(jax.local_devices())} local {jax.local_devices()[0].platform} device(s){procs})",
                  file=sys.stderr, flush=True)
        guard.at("compiling")
        if _compile_needed(guard):
            compile_s = _allocate(layout.compile, "compiling the chunk", cfg)
            if progress:
                print(f"compiled the training chunk ({cfg.num_envs} environments on {n_dev} device(s)) in "
                      f"{compile_s:.1f} s", file=sys.stderr, flush=True)
        signum, _ = _agreed(guard.signal, np.zeros(0, bool))
        if signum is not None:  # stopped before the first chunk: nothing of this session is written
            what = ("nothing of the run was written" if not resume else
                    f"the run in {out} is as it was; continue with: nmrl train --resume --out {out}")
            print(f"stopped by signal {signum} before the first chunk; {what}", file=sys.stderr, flush=True)
            raise Stopped(signum, int(p.ts.step), [])
        guard.at("starting")
        if dist.is_writer():  # every check passed and the chunk compiled: now the run's files
            started = True
            if resume:
                _begin_resumed(p)
            else:
                store.write_config(out, cfg)
        bar = _Progress(cfg, progress, int(p.ts.step) if cfg.steps is not None else int(p.ts.trials))
        try:
            return _drive([p], layout, stages=[[0]], checkpoint_every=1, keep=keep, freeze_diverged=False,
                          compact=False, on_chunk=lambda new: bar.update(new[0]), max_chunks=max_chunks,
                          stop_message=lambda sig, st: (f"stopped by signal {sig} at step {st} (saved); continue "
                                                        f"with: nmrl train --resume --out {out}"))
        finally:
            bar.close()
    finally:
        if held is not None:
            held.release(remove_if_empty=not started)
        if own_guard:
            guard.restore()


# ----------------------------------------------------------------------------- P runs as one program


def _progress_table(names: Sequence[str], rows_by_point: dict, elapsed: float) -> str:
    lines = [f"sweep: {len(names)} points, {elapsed:,.0f} s"]
    w = max(len(n) for n in names)
    for name in names:
        r = rows_by_point.get(name)
        if r is None:
            continue
        flag = "  DIVERGED" if r["diverged"] else ""
        lines.append(f"  {name:<{w}}  trials {r['trials']:>8,}  steps {r['step']:>8,}  "
                     f"avg reward {r['avg_reward']:+.3f}  speed {r['forward_speed']:+.2f} m/s{flag}")
    return "\n".join(lines)


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
    run (:func:`_resume`, with the budget of ``configs``; other fields must be the point's own): from
    its newest checkpoint (its later metrics rows are dropped), else from its compact state
    (statistically, not bitwise, equal: every environment starts a new trial), else (a point of a
    later stage that never ran) from the start. A diverged point stays frozen at its last good
    checkpoint. ``on_chunk()`` runs after every chunk; ``progress`` prints the layout, the compile
    time and (with ``table``) every point's latest metrics. SIGINT/SIGTERM stop the sweep after the
    chunk in flight, every active point saved, with :class:`Stopped`. Returns the rows written.
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
    configs = [c.resolved() for c in configs]
    pts.check_one_program(names, configs)
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
    guard = signals.active()
    own_guard = guard is None
    if own_guard:
        guard = signals.Guard().install()
    holds: list = []
    started = False  # whether anything was written in this call
    try:
        guard.at("starting")
        if out.is_dir():
            holds.append(_hold(out, create=False))  # the sweep's directory, before any of it is read
        _foreign_points(out, names, dirs, configs, resume, known)
        holds += [_hold(d, create=False) for d in dirs if d.is_dir()]  # each existing point, too
        ps: list[_Point] = []
        if resume:
            for n, d, c in zip(names, dirs, configs):
                if not any((d / f).exists() for f in RUN_FILES):  # deleted, or never begun: a fresh point
                    if writer:
                        print(f"nmrl: note: point {n} has no run in {d}: it starts fresh", file=sys.stderr, flush=True)
                    tr = learners.of(c).make(c, env=env)
                    env = env or tr.env
                    ts = jax.jit(tr.init)(jax.random.PRNGKey(c.seed))
                    ps.append(_Point(n, d, c, tr, ts))
                    continue
                # a diverged point stopped saving at its last good step and stays frozen there
                frozen = any(is_diverged(r) for r in read_metrics(d))
                cfg, tr, ts, record = _resume(c, d, dataclasses.asdict(c), None, env=env)
                env = env or tr.env
                ps.append(_Point(n, d, cfg, tr, ts, frozen=frozen, record=record))
            pts.check_one_program(names, [p.cfg for p in ps])
            if all(p.frozen or budget_done(p.cfg, int(p.ts.step), int(p.ts.trials)) for p in ps):
                # nothing to continue: no compile, nothing written (no resume records), as train() does
                if progress and writer:
                    print(f"{out}: nothing to do: every point has reached its budget ({budget_text(ps[0].cfg)}) "
                          f"or diverged; give a larger --steps or --trials to continue", file=sys.stderr, flush=True)
                return []
            _preflight(ps[0].cfg, ps[0].trainer, points=P_)
        else:
            learner = learners.of(configs[0])
            trainers = [learner.make(configs[0], env=env)]
            trainers += [learner.make(c, env=trainers[0].env) for c in configs[1:]]
            _preflight(configs[0], trainers[0], points=P_)
            init = jax.jit(jax.vmap(trainers[0].init))
            keys = jnp.stack([jax.random.PRNGKey(c.seed) for c in configs])
            ts = _allocate(lambda: init(keys, pts.stack_trees([learner.hyper(c) for c in configs])),
                           "allocating the states", configs[0])
            ps = [_Point(n, d, c, tr, pts.unstack(ts, i))
                  for i, (n, d, c, tr) in enumerate(zip(names, dirs, configs, trainers))]
            del ts
        dist.barrier("points-checked")  # several processes: all have read the points before process 0 writes
        layout = _Points(ps, n_dev, group, [i for st in stages for i in st], devices=mesh_devices)
        for p in ps:
            p.ts = None  # the layout holds the states now
        progress = progress and writer
        if progress:
            print(f"sweep: {P_} points x {configs[0].num_envs} environments on {n_dev} "
                  f"{jax.local_devices()[0].platform} device(s), {layout.per_dev} point(s) per device stepped "
                  f"{'one at a time' if group == 1 else f'in vmapped groups of {group}'} "
                  f"({configs[0].num_envs * min(group, layout.per_dev)} environments per device at a time)",
                  file=sys.stderr, flush=True)
        guard.at("compiling")
        if _compile_needed(guard):
            compile_s = _allocate(layout.compile, "compiling the chunk", configs[0])
            if progress:
                print(f"compiled the sweep chunk in {compile_s:.1f} s", file=sys.stderr, flush=True)
        signum, _ = _agreed(guard.signal, np.zeros(0, bool))
        if signum is not None:  # stopped before the first chunk: nothing of this session is written
            what = "nothing was written" if not resume else f"{out} is as it was; continue with --resume"
            print(f"stopped by signal {signum} before the first chunk; {what}", file=sys.stderr, flush=True)
            raise Stopped(signum, 0, [])
        guard.at("starting")
        if writer:  # every check passed and the chunk compiled: lock what is new, check again, then write
            for d in [out, *dirs]:
                if not lock.held(d):
                    holds.append(_hold(d))
            _foreign_points(out, names, dirs, configs, resume, known)  # another writer may have been faster
        started = True
        if before_start is not None:
            before_start()
        if writer:
            for p in ps:
                if p.record is not None:
                    _begin_resumed(p)
                else:
                    _begin_fresh(p)
        last_rows: dict = {}
        t_start = time.time()

        def chunk_done(new: dict[int, dict]) -> None:
            last_rows.update({names[i]: r for i, r in new.items()})
            if on_chunk is not None:
                on_chunk()
            if progress and table:
                print(_progress_table(names, last_rows, time.time() - t_start), file=sys.stderr, flush=True)

        return _drive(ps, layout, stages=stages, checkpoint_every=checkpoint_every, keep=keep,
                      freeze_diverged=True, compact=True, on_chunk=chunk_done, max_chunks=max_chunks,
                      stop_message=lambda sig, st: (f"stopped by signal {sig} after saving every active point; "
                                                    f"continue with --resume"))
    finally:
        for h in reversed(holds):
            if h is not None:
                h.release(remove_if_empty=not started)
        if own_guard:
            guard.restore()


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
