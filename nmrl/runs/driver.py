"""The training run on the Python side: jitted chunks, progress, metrics.jsonl, checkpoints.

Between two chunks of ``chunk_steps`` control steps (one ``jit``-compiled ``lax.scan``, see
nmrl/paper/learner.py) this loop only shows progress, appends one JSON object per chunk to
``OUT/metrics.jsonl`` and saves an orbax checkpoint of the full training state. A run whose
parameters diverge stops with a clear message and keeps its last good checkpoint; SIGINT/SIGTERM
stop the run after the chunk in flight has been saved (:class:`Stopped`; a second signal stops it
at once; the last checkpoint is intact because checkpoints are written atomically).

A run directory has one identity, the config it was created with (``config.json``; see
nmrl/runs/checkpoint.py). A fresh run never starts in a directory that holds any part of a run
(:data:`RUN_FILES`); a resume continues the run with its own config -- only the budget may change,
recorded in ``config.json`` and ``resumes.jsonl`` -- from its newest checkpoint or the one asked
for, and refuses a checkpoint of another run or a corrupted one (naming the newest good one).
Every refusal happens before anything is written.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
import pathlib
import signal
import sys
import time
from typing import Callable
import jax
import numpy as np

from nmrl.runs import checkpoint, sharding
from nmrl.paper.learner import TrainConfig, make_train

METRICS_FILE = "metrics.jsonl"
CONFIG_FILE = checkpoint.RUN_CONFIG
#: One JSON object per resume: the step and checkpoint it continued from, the budget before and after.
RESUMES_FILE = "resumes.jsonl"
#: Any of these in a directory makes it a run: a fresh run refuses to start there.
RUN_FILES = (CONFIG_FILE, METRICS_FILE, checkpoint.CHECKPOINTS, checkpoint.COMPACT_FILE, RESUMES_FILE)
#: Config fields a resume may change (the budget); the others are the run's identity.
BUDGET_FIELDS = checkpoint.RESUMABLE_FIELDS
#: JAX PRNG seeds are 32-bit: larger (or negative) seeds wrap around to another seed's key.
SEED_MAX = 2**32 - 1


class RunError(Exception):
    """A run cannot start or continue (message says why); nothing was written."""


class Diverged(Exception):
    """Training diverged; the last good checkpoint is kept."""


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


def check_config(cfg: TrainConfig) -> None:
    """``cfg.validate()`` and what only shows later (in the environment, the PRNG, the budget): a
    ValueError naming the value and what is allowed, before anything is built or written."""
    for name in ("alpha", "sigma", "gamma", "lam", "control_dt", "stop_prob", "reward_scale"):
        v = getattr(cfg, name)
        if isinstance(v, float) and not math.isfinite(v):
            raise ValueError(f"{name}={v!r} is invalid: must be a finite number")
    cfg.validate()
    if not (isinstance(cfg.seed, int) and not isinstance(cfg.seed, bool) and 0 <= cfg.seed <= SEED_MAX):
        raise ValueError(f"seed={cfg.seed!r} is invalid: must be an integer in [0, {SEED_MAX}] "
                         f"(JAX's PRNG seeds are 32-bit; others wrap around to another seed)")
    ts = physics_timestep()
    n = cfg.control_dt / ts
    if abs(n - round(n)) > 1e-6 or round(n) < 1:
        raise ValueError(f"control_dt={cfg.control_dt!r} is invalid: must be a whole multiple of the physics "
                         f"timestep {ts:g} s (e.g. {ts:g}, {2 * ts:g}, {4 * ts:g})")
    if cfg.trials is not None and cfg.stop_prob == 0:
        raise ValueError(f"trials={cfg.trials} is invalid with stop_prob=0: no trial would ever end; "
                         f"give the budget as --steps")


def _fresh_out(out: pathlib.Path) -> None:
    """Refuse an ``--out`` that holds (part of) a run, is not a directory, or cannot be created."""
    if out.exists() and not out.is_dir():
        raise RunError(f"--out={str(out)!r} is invalid: it exists and is not a directory")
    if out.is_dir():
        held = [n for n in RUN_FILES if (out / n).exists()]
        if held:
            raise RunError(f"{out} already holds a run ({', '.join(held)}); continue it with --resume or "
                           f"choose another --out")
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


def _create_dir(out: pathlib.Path) -> None:
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise RunError(f"--out={str(out)!r} is invalid: cannot create the directory ({e.strerror or e})") from e


def atomic_write_text(path: pathlib.Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def to_python(m: dict) -> dict:
    out = {}
    for k, v in m.items():
        v = np.asarray(v)
        out[k] = bool(v) if v.dtype == bool else (int(v) if np.issubdtype(v.dtype, np.integer) else float(v))
    return out


def read_metrics(run_dir: str | os.PathLike) -> list[dict]:
    p = pathlib.Path(run_dir) / METRICS_FILE
    if not p.exists():
        return []
    return [json.loads(line) for line in p.read_text().splitlines() if line.strip()]


def truncate_metrics(run_dir: pathlib.Path, step: int) -> None:
    """Keep only the metrics of chunks up to the restored checkpoint (resume == uninterrupted);
    the file is not rewritten when it has no later rows."""
    rows = read_metrics(run_dir)
    keep = [r for r in rows if r["step"] <= step]
    if len(keep) == len(rows) and (run_dir / METRICS_FILE).exists():
        return
    atomic_write_text(run_dir / METRICS_FILE, "".join(json.dumps(r) + "\n" for r in keep))


def append_metrics(run_dir: pathlib.Path, row: dict) -> None:
    with open(run_dir / METRICS_FILE, "a") as f:
        f.write(json.dumps(row) + "\n")
        f.flush()
        os.fsync(f.fileno())


def existing_step(run_dir: pathlib.Path) -> int | None:
    """The newest checkpoint step in ``run_dir``, or None when there is none (or no directory)."""
    try:
        return checkpoint.latest_step(run_dir)
    except checkpoint.CheckpointError:
        return None


def _num_shards(cfg: TrainConfig, devices: int | None = None) -> int:
    """Local devices the environment batch is split over: ``devices`` (default: all local devices),
    lowered to the largest count that divides N."""
    avail = len(jax.local_devices())
    if devices is not None and not (isinstance(devices, int) and 1 <= devices <= avail):
        raise RunError(f"devices={devices!r} is invalid: this process has {avail} local device(s)")
    n = avail if devices is None else devices
    while cfg.num_envs % n:
        n -= 1
    return n


def _sharded_trainer(cfg: TrainConfig, trainer, devices: int | None = None):
    n = _num_shards(cfg, devices)
    if n == 1:
        return trainer
    return make_train(cfg, env=trainer.env, axis_name=sharding.AXIS, num_shards=n)


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


def compile_chunk(fn, ts, donate: bool = True):
    """AOT-compile ``fn`` (donating its argument if ``donate``) for ``ts``; returns (compiled, seconds)."""
    t0 = time.time()
    compiled = jax.jit(fn, donate_argnums=0 if donate else ()).lower(ts).compile()
    return compiled, time.time() - t0


def metrics_row(cfg: TrainConfig, m: dict, wall: float, points: int = 1) -> dict:
    """One metrics.jsonl object from a chunk's metrics (``points`` programs shared the wall time)."""
    return {"chunk": m["step"] // cfg.chunk_steps, **m, "total_steps": m["step"] * cfg.num_envs,
            "wall_s": wall, "steps_per_s": points * cfg.chunk_steps * cfg.num_envs / wall}


def is_diverged(m: dict) -> bool:
    return bool(m["diverged"]) or not all(math.isfinite(m[k]) for k in ("theta_norm", "v_norm"))


def budget_done(cfg: TrainConfig, ts_step: int, ts_trials: int) -> bool:
    if cfg.steps is not None:
        return ts_step >= cfg.steps
    return ts_trials >= cfg.trials


class _Progress:
    """A rich progress bar on a terminal, one plain line per chunk otherwise.

    ``done0`` is where this session started (a resumed run): the ETA extrapolates this session's
    own speed, not the run's whole progress over this session's time.
    """

    def __init__(self, cfg: TrainConfig, enabled: bool, done0: int = 0):
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


def _given_changes(ident: TrainConfig, given: dict, out: pathlib.Path) -> None:
    """Refuse options given with ``--resume`` that would change the run's identity, naming them all."""
    base = ident.resolved()
    bad = []
    for k, v in given.items():
        if k in BUDGET_FIELDS:
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


def _budget(cfg: TrainConfig) -> dict:
    return {k: getattr(cfg, k) for k in BUDGET_FIELDS}


def _resume(cfg: TrainConfig, out: pathlib.Path, given: dict | None, step: int | None):
    """Everything a resume checks and reads, nothing written: (config, trainer, state, record)."""
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
    if not steps:
        rows = read_metrics(out)
        if run_cfg is None or rows or step is not None:
            why = (f"; its {METRICS_FILE} has {len(rows)} row(s) that cannot be continued: choose another --out"
                   if rows else "")
            raise RunError(f"--resume: no checkpoint found in {out}" + why)
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
    if given is not None:
        _given_changes(run_cfg, given, out)
        new_budget = {k: given.get(k) for k in BUDGET_FIELDS}
    else:  # library callers: the budget of ``cfg``, if it has one
        new_budget = _budget(cfg)
    if all(v is None for v in new_budget.values()):
        new_budget = None
    trainer = make_train(run_cfg)

    def load(s: int):
        meta = checkpoint.load_metadata(out, s)
        checkpoint.check_identity(meta, run_cfg, source)
        return meta, checkpoint.restore(out, trainer, step=s)

    if not steps:  # created, stopped before its first checkpoint: start it again, as it would have
        meta, ts = None, jax.jit(trainer.init)(jax.random.PRNGKey(run_cfg.seed))
        old_budget = _budget(run_cfg)
    else:
        try:  # the newest checkpoint or the one asked for (newest_good with a step: no fallback)
            s, (meta, ts), _ = checkpoint.newest_good(out, load, step if step is not None else steps[-1])
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
            others = [s for s in steps if s != (step if step is not None else steps[-1])]
            raise RunError(f"{e}" + (f" (other checkpoints: --step {others})" if others else "")) from e
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


def train(cfg: TrainConfig, out: str | os.PathLike, *, resume: bool = False, progress: bool = True,
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
    if resume:
        cfg, trainer, ts, record = _resume(cfg, out, given, step)
        _num_shards(cfg, devices)  # a bad device count is refused before anything is written
        if budget_done(cfg, int(ts.step), int(ts.trials)):
            print(f"{out}: nothing to do: the run is at step {int(ts.step)} ({int(ts.trials)} trials), its budget "
                  f"is {'steps' if cfg.steps is not None else 'trials'}={cfg.steps or cfg.trials}; give a larger "
                  f"--steps or --trials to continue", file=sys.stderr, flush=True)
            return []
        truncate_metrics(out, int(ts.step))
        if record["config_json_updated"]:
            atomic_write_text(out / CONFIG_FILE, json.dumps(dataclasses.asdict(cfg), indent=2) + "\n")
        with open(out / RESUMES_FILE, "a") as f:
            f.write(json.dumps(record) + "\n")
        trainer = _sharded_trainer(cfg, trainer, devices)
    else:
        check_config(cfg)
        cfg = cfg.resolved()
        _fresh_out(out)
        trainer = make_train(cfg)
        _num_shards(cfg, devices)
        _create_dir(out)
        atomic_write_text(out / CONFIG_FILE, json.dumps(dataclasses.asdict(cfg), indent=2) + "\n")
        ts = jax.jit(trainer.init)(jax.random.PRNGKey(cfg.seed))
        trainer = _sharded_trainer(cfg, trainer, devices)
    if cfg.steps is not None and cfg.steps % cfg.chunk_steps:
        end = math.ceil(cfg.steps / cfg.chunk_steps) * cfg.chunk_steps
        print(f"note: the budget of {cfg.steps} steps is not a whole number of chunks of {cfg.chunk_steps}: "
              f"the run stops after whole chunks, at step {end}", file=sys.stderr, flush=True)
    n_dev = _num_shards(cfg, devices)
    if progress:
        print(f"train: {cfg.num_envs} environments on {n_dev} device(s), {cfg.num_envs // n_dev} per device "
              f"({len(jax.local_devices())} local {jax.local_devices()[0].platform} device(s))",
              file=sys.stderr, flush=True)
    if n_dev > 1:
        program, place = sharding.shard_train_chunk(trainer.chunk, ts,
                                                    sharding.make_mesh(jax.local_devices()[:n_dev]))
    else:
        program, place = trainer.chunk, jax.device_put
    ts = place(ts)  # committed inputs: no second, hidden compile of the chunk
    chunk, compile_s = compile_chunk(program, ts)
    if progress:
        print(f"compiled the training chunk ({cfg.num_envs} environments on {n_dev} device(s)) in "
              f"{compile_s:.1f} s", file=sys.stderr, flush=True)

    stop, restore_signals = stop_on_signals()
    bar = _Progress(cfg, progress, int(ts.step) if cfg.steps is not None else int(ts.trials))
    rows: list[dict] = []
    n_chunks = 0
    try:
        while not budget_done(cfg, int(ts.step), int(ts.trials)):
            t0 = time.time()
            ts_new, m = chunk(ts)
            m = to_python(jax.device_get(m))
            wall = time.time() - t0
            row = metrics_row(cfg, m, wall)
            bad = is_diverged(m)
            ts = place(ts_new)
            append_metrics(out, row)
            rows.append(row)
            if bad:
                raise Diverged(
                    f"training diverged at step {m['step']} (theta norm {m['theta_norm']:.3g}, v norm "
                    f"{m['v_norm']:.3g}, limit {cfg.max_param_norm:g}); the last good checkpoint "
                    f"(step {checkpoint.latest_step(out)}) is kept in {out}. Try smaller step sizes.")
            checkpoint.save(out, ts, cfg, keep=keep)
            bar.update(row)
            n_chunks += 1
            if stop["signal"] is not None:
                print(f"stopped by signal {stop['signal']} at step {m['step']} (saved); continue with: "
                      f"nmrl train --resume --out {out}", file=sys.stderr, flush=True)
                raise Stopped(stop["signal"], m["step"], rows)
            if max_chunks is not None and n_chunks >= max_chunks:
                break
    finally:
        bar.close()
        restore_signals()
    return rows

