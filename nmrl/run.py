"""The training run on the Python side: jitted chunks, progress, metrics.jsonl, checkpoints.

Between two chunks of ``chunk_steps`` control steps (one ``jit``-compiled ``lax.scan``, see
nmrl/learner.py) this loop only shows progress, appends one JSON object per chunk to
``OUT/metrics.jsonl`` and saves an orbax checkpoint of the full training state. A run whose
parameters diverge stops with a clear message and keeps its last good checkpoint; SIGINT/SIGTERM
stop the run after the chunk in flight has been saved (a second signal stops it at once; the last
checkpoint is intact because checkpoints are written atomically).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import pathlib
import signal
import sys
import time
import jax
import numpy as np

from nmrl import checkpoint, sharding
from nmrl.learner import TrainConfig, make_train

METRICS_FILE = "metrics.jsonl"
CONFIG_FILE = "config.json"


class RunError(Exception):
    """A run cannot start or continue (message says why); nothing was written."""


class Diverged(Exception):
    """Training diverged; the last good checkpoint is kept."""


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
    """Keep only the metrics of chunks up to the restored checkpoint (resume == uninterrupted)."""
    rows = [r for r in read_metrics(run_dir) if r["step"] <= step]
    atomic_write_text(run_dir / METRICS_FILE, "".join(json.dumps(r) + "\n" for r in rows))


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
    """A rich progress bar on a terminal, one plain line per chunk otherwise."""

    def __init__(self, cfg: TrainConfig, enabled: bool):
        self.cfg = cfg
        self.enabled = enabled
        self.rich = enabled and sys.stderr.isatty()
        self.t0 = time.time()
        if self.rich:
            from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

            self.bar = Progress(TextColumn("[bold]train[/]"), BarColumn(), TextColumn("{task.percentage:>5.1f}%"),
                                TimeRemainingColumn(), TextColumn("{task.description}"), transient=False)
            total = cfg.steps if cfg.steps is not None else cfg.trials
            self.task = self.bar.add_task("compiling…", total=total)
            self.bar.start()

    def update(self, row: dict) -> None:
        if not self.enabled:
            return
        cfg = self.cfg
        done = row["step"] if cfg.steps is not None else row["trials"]
        total = cfg.steps if cfg.steps is not None else cfg.trials
        text = (f"trials {row['trials']:,}  steps {row['total_steps']:,}  {row['steps_per_s']:,.0f} steps/s  "
                f"avg reward {row['avg_reward']:+.3f}  speed {row['forward_speed']:+.2f} m/s")
        if self.rich:
            self.bar.update(self.task, completed=min(done, total), description=text)
        else:
            elapsed = time.time() - self.t0
            frac = min(done / total, 1.0)
            eta = elapsed * (1 - frac) / frac if frac > 0 else float("nan")
            print(f"[{100 * frac:5.1f}%] {text}  ETA {eta:,.0f}s", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.rich:
            self.bar.stop()


def train(cfg: TrainConfig, out: str | os.PathLike, *, resume: bool = False, progress: bool = True,
          keep: int = 3, max_chunks: int | None = None, devices: int | None = None) -> list[dict]:
    """Run (or resume) training into ``out``; returns the metrics rows written in this call.

    The N environments are split over ``devices`` local devices (default: every one; on a CPU
    nmrl.devices exposes one per core), each stepping its N/D environments; the summed update is
    ``psum``-ed (equal to the 1-device run up to float rounding, tests/test_sharding.py).

    ``max_chunks`` stops after that many chunks (used by tests to interrupt a run).
    """
    out = pathlib.Path(out)
    if resume:
        if existing_step(out) is None:
            raise RunError(f"--resume: no checkpoint found in {out}")
        saved = checkpoint.load_config(out)
        # The budget may be extended on resume; everything else is the run's own.
        cfg = dataclasses.replace(saved, steps=cfg.steps, trials=cfg.trials) if (
            cfg.steps is not None or cfg.trials is not None) else saved
        cfg = cfg.resolved()
        trainer = make_train(cfg)
        ts = checkpoint.restore(out, trainer)
        trainer = _sharded_trainer(cfg, trainer, devices)
        truncate_metrics(out, int(ts.step))
    else:
        cfg = cfg.resolved()
        if existing_step(out) is not None:
            raise RunError(f"{out} already holds a run; continue it with --resume or choose another --out")
        trainer = make_train(cfg)
        out.mkdir(parents=True, exist_ok=True)
        atomic_write_text(out / CONFIG_FILE, json.dumps(dataclasses.asdict(cfg), indent=2) + "\n")
        (out / METRICS_FILE).unlink(missing_ok=True)
        ts = jax.jit(trainer.init)(jax.random.PRNGKey(cfg.seed))
        trainer = _sharded_trainer(cfg, trainer, devices)
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

    stop = {"signal": None}

    def on_signal(signum, _frame):
        if stop["signal"] is not None:
            raise KeyboardInterrupt
        stop["signal"] = signum
        print(f"\nsignal {signum}: stopping after the chunk in flight is saved (again to stop now)",
              file=sys.stderr, flush=True)

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    bar = _Progress(cfg, progress)
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
                print(f"stopped by signal at step {m['step']}; continue with: nmrl train --resume --out {out}",
                      file=sys.stderr)
                break
            if max_chunks is not None and n_chunks >= max_chunks:
                break
    finally:
        bar.close()
        for s, h in old.items():
            signal.signal(s, h)
    return rows

