"""Training throughput vs environment-only throughput at the same batch size (the learner's overhead).

* ``train``: ``trainer.chunk`` (nmrl/learners/ac_train.py) -- ``chunk_steps`` control steps of every
  environment with the full Table II learning step (actor 31-100-6, critic 31-200-1, the paper's
  sizes; nm-period l = 10, Delta = 4), AOT-compiled with its state donated.
* ``env``: a ``lax.scan`` of ``jax.vmap(env.step)`` over the same number of control steps with random
  actions of the same shape (N, 6), on the trainer's own environment (same physics, auto-reset).

Both are compiled first (compile time reported apart), then timed interleaved (env, train, env,
train, ...) so that a background load hits both alike; the figures are medians. ``overhead =
1 - train/env`` is the fraction of the environment-only throughput that learning costs (goal < 30%).

    python benchmarks/bench_learning.py [--quick]

``run(quick, smoke=False) -> dict``; ``python -m benchmarks`` collects it.
"""

from __future__ import annotations

import os
import pathlib
import statistics
import sys
import time
from typing import Callable

os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", os.path.expanduser("~/.cache/nmrl/xla"))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

from nmrl import options

#: chunk length (control steps per environment per call); the same in quick and full mode so a
#: quick run reuses the full run's persistent compile cache
CHUNK_STEPS = 32
FULL_BATCHES = (64, 256)
QUICK_BATCHES = (64,)
#: the smallest setting (``smoke``): one batch of 8, 4-step chunks, one round -- runs the paths, measures nothing
SMOKE = {"batches": (8,), "chunk_steps": 4, "rounds": 1}


def interleave(calls: dict[str, Callable[[], object]], rounds: int) -> dict[str, list[float]]:
    """Call every entry of ``calls`` once per round, in order (A, B, A, B, ...); wall times per name.

    Each callable must block until its result is ready (and carry its own state forward).
    """
    times: dict[str, list[float]] = {k: [] for k in calls}
    for _ in range(rounds):
        for k, f in calls.items():
            t0 = time.perf_counter()
            f()
            times[k].append(time.perf_counter() - t0)
    return times


def timing(times: list[float], work: float) -> dict:
    """Summary of one contender's wall times; ``work`` = control steps per call."""
    med = statistics.median(times)
    return {"median_s": med, "min_s": min(times), "times_s": times, "control_steps_per_s": work / med,
            "control_steps_per_s_best": work / min(times)}


def run_worker(module: str, size: list[str], cores: int, timeout: float) -> dict:
    """Run ``python -m <module> --worker <size>`` with one XLA host device per core; its last stdout
    line as JSON (RuntimeError with its stderr's tail when it fails)."""
    import json
    import subprocess
    import sys

    env = dict(os.environ)
    flags = " ".join(f for f in env.get("XLA_FLAGS", "").split()
                     if not f.startswith("--xla_force_host_platform_device_count"))
    env["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={cores}".strip()
    from nmrl.runs import devices  # the thread pool nmrl's own commands give these devices

    if (pool := devices.pool_threads(cores)) is not None:
        env["PJRT_NPROC"] = str(pool)
    p = subprocess.run([sys.executable, "-m", module, "--worker", *size],
                       env=env, capture_output=True, text=True, timeout=timeout)
    if p.returncode != 0:
        raise RuntimeError(f"{module.split('.')[-1]} worker failed (rc {p.returncode}): {p.stderr[-2000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def worker_section(module: str, quick: bool, smoke: bool, timeout: float) -> dict:
    """A section measured in its own worker (:func:`run_worker`, one device per core) at its size:
    ``quick``, ``smoke``, the worker's result, the load average before and after, and the wall seconds."""
    from nmrl.runs.devices import cpu_cores

    t0 = time.perf_counter()
    load = [load_avg()]
    w = run_worker(module, ["--smoke"] if smoke else ["--quick"] if quick else [], cpu_cores(), timeout)
    load.append(load_avg())
    return {"quick": quick, "smoke": smoke, "worker": w, "load_avg": load, "wall_s": time.perf_counter() - t0}


def load_avg() -> list[float]:
    return list(os.getloadavg()) if hasattr(os, "getloadavg") else []


def env_rollout(env, n_steps: int):
    """``(states, key) -> ((states, key), reward_sum)``: n_steps of vmap(env.step) with a ~ N(0, 1)."""

    def rollout(carry):
        states, key = carry

        def body(carry, _):
            s, k = carry
            k, sub = jax.random.split(k)
            a = jax.random.normal(sub, (s.obs.shape[0], env.act_dim), jnp.float32)
            s = jax.vmap(env.step)(s, a)
            return (s, k), jnp.mean(s.reward)

        (s, k), r = jax.lax.scan(body, (states, key), None, length=n_steps)
        return (s, k), r.sum()

    return rollout


def measure(batch: int, chunk_steps: int, rounds: int) -> dict:
    from nmrl.learners.ac_config import TrainConfig
    from nmrl.learners.ac_train import make_train
    from nmrl.runs.loop import compile_chunk

    cfg = options.build(TrainConfig, num_envs=batch, chunk_steps=chunk_steps, l=10, seed=0)
    trainer = make_train(cfg)
    env = trainer.env
    work = batch * chunk_steps

    t0 = time.perf_counter()
    ts = jax.jit(trainer.init)(jax.random.PRNGKey(0))
    jax.block_until_ready(ts)
    init_s = time.perf_counter() - t0
    train_chunk, train_compile = compile_chunk(trainer.chunk, ts)
    t0 = time.perf_counter()
    ts, m = train_chunk(ts)  # first execution (warm-up)
    jax.block_until_ready((ts, m))
    train_first = time.perf_counter() - t0

    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(1), batch))
    key = jax.random.PRNGKey(2)
    env_fn, env_compile = compile_chunk(env_rollout(env, chunk_steps), (states, key))
    t0 = time.perf_counter()
    carry, _ = jax.block_until_ready(env_fn((states, key)))
    env_first = time.perf_counter() - t0

    box = {"ts": ts, "env": carry}

    def do_train():
        box["ts"], m = train_chunk(box["ts"])
        jax.block_until_ready((box["ts"], m))

    def do_env():
        box["env"], r = env_fn(box["env"])
        jax.block_until_ready((box["env"], r))

    times = interleave({"env": do_env, "train": do_train}, rounds)
    env_t, train_t = timing(times["env"], work), timing(times["train"], work)
    # ratio per round (adjacent calls share the same background load), then its median
    per_round = [e / t for e, t in zip(times["env"], times["train"])]
    ratio = statistics.median(per_round)
    return {
        "batch": batch, "chunk_steps": chunk_steps, "rounds": rounds,
        "compile_s": {"train": train_compile, "env": env_compile, "init": init_s},
        "first_call_s": {"train": train_first, "env": env_first},
        "train": train_t, "env": env_t,
        "train_over_env": ratio,
        "train_over_env_of_medians": train_t["control_steps_per_s"] / env_t["control_steps_per_s"],
        "overhead": 1.0 - ratio,
        "diverged": bool(box["ts"].diverged),
        "load_avg": load_avg(),
    }


def run(quick: bool = False, smoke: bool = False) -> dict:
    batches = SMOKE["batches"] if smoke else QUICK_BATCHES if quick else FULL_BATCHES
    rounds = SMOKE["rounds"] if smoke else 3 if quick else 9
    chunk_steps = SMOKE["chunk_steps"] if smoke else CHUNK_STEPS
    t0 = time.perf_counter()
    res = []
    for B in batches:
        r = measure(B, chunk_steps, rounds)
        res.append(r)
        print(f"learning B={B}: train {r['train']['control_steps_per_s']:,.0f} ctrl steps/s, env "
              f"{r['env']['control_steps_per_s']:,.0f}; overhead {100 * r['overhead']:.1f}% "
              f"(compile train {r['compile_s']['train']:.1f} s, env {r['compile_s']['env']:.1f} s)",
              file=sys.stderr, flush=True)
    return {
        "benchmark": "training chunk vs environment-only scan, same batch and chunk length, interleaved",
        "quick": quick, "smoke": smoke,
        "config": {"batches": list(batches), "chunk_steps": chunk_steps, "rounds": rounds,
                   "network": {"actor": [31, 100, 6], "critic": [31, 200, 1]}, "l": 10, "delta": 4,
                   "statistic": "median over rounds of the per-round ratio env_time/train_time"},
        "results": res,
        "goal": "overhead < 0.30",
        "goal_met": all(r["overhead"] < 0.30 for r in res),
        "wall_s": time.perf_counter() - t0,
    }


if __name__ == "__main__":
    from benchmarks import main

    main(run)
