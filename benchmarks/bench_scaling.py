"""Training-chunk throughput on 1 vs 2 CPU devices: the sweep's shard_map path over points.

A worker subprocess with ``XLA_FLAGS=--xla_force_host_platform_device_count=2`` builds P = 2 sweep
points (l = 10, seeds 0 and 1, ``num_envs`` environments each) and times, interleaved (1dev, 2dev,
1dev, ...; medians of the per-round ratio):

* ``1dev``: ``jit(vmap(trainer.chunk))`` with the stacked state on device 0 only;
* ``2dev``: ``nmrl.runs.sharding.shard_map_batch(vmap(trainer.chunk))`` with the points split over the
  two devices by ``nmrl.runs.sharding.shard_batch`` -- exactly what ``nmrl sweep`` runs with 2 devices.

In full mode a second worker without the flag (a plain 1-device process) times ``1dev`` alone, as a
check that forcing 2 host devices does not slow the 1-device program (not interleaved: a separate
process, so only roughly comparable).

Only the points axis is measured here; a single run's environment batch split over devices (its
summed update ``psum``-ed) is what bench_distributed.py times through ``nmrl train``.

Every worker runs with a timeout: a 2-device shard_map of the bare environment has been seen to
hang at batch 4096 (docs/performance.md), and a hang is reported as ``{"error": "timeout ..."}``
with whatever the worker printed, instead of blocking the harness.

``run(quick, smoke=False) -> dict`` (``smoke``: 4 environments per point, 4-step chunks, one
round); ``python benchmarks/bench_scaling.py [--quick]`` prints it.
"""

from __future__ import annotations

import json
import os
import pathlib
import statistics
import subprocess
import sys
import time

from nmrl import options

ROOT = pathlib.Path(__file__).resolve().parents[1]

POINTS = 2
NUM_ENVS = 64  # per point; the same in quick and full mode (compile-cache reuse)
CHUNK_STEPS = 32
L = 10
SMOKE = {"num_envs": 4, "chunk_steps": 4, "rounds": 1}


def _worker(modes: list[str], rounds: int, num_envs: int = NUM_ENVS, chunk_steps: int = CHUNK_STEPS) -> dict:
    import jax
    import jax.numpy as jnp

    from benchmarks.bench_learning import interleave, timing
    from nmrl.runs import sharding
    from nmrl.learners.ac_config import Hyper, TrainConfig
    from nmrl.learners.ac_train import make_train
    from nmrl.runs.loop import compile_chunk

    devs = jax.local_devices()
    configs = [options.build(TrainConfig, num_envs=num_envs, chunk_steps=chunk_steps, l=L, seed=s).resolved()
               for s in range(POINTS)]
    trainer = make_train(configs[0])
    keys = jnp.stack([jax.random.PRNGKey(c.budget.seed) for c in configs])
    hypers = jax.tree.map(lambda *x: jnp.stack(x), *[Hyper.from_config(c) for c in configs])
    stacked = jax.block_until_ready(jax.jit(jax.vmap(trainer.init))(keys, hypers))
    program = jax.vmap(trainer.chunk)
    calls, info, box = {}, {}, {}
    for mode in modes:
        if mode == "1dev":
            place = lambda t: jax.device_put(t, devs[0])  # noqa: E731
            fn = program
        elif mode == "2dev":
            if len(devs) < 2:
                raise RuntimeError(f"2dev needs 2 devices, have {len(devs)}")
            mesh = sharding.make_mesh(devs[:2])
            place = lambda t, mesh=mesh: sharding.shard_batch(t, mesh)  # noqa: E731
            fn = sharding.shard_map_batch(program, mesh, jit=False)
        else:
            raise ValueError(mode)
        ts = place(stacked)
        compiled, compile_s = compile_chunk(fn, ts, donate=False)
        t0 = time.perf_counter()
        out, m = compiled(ts)
        jax.block_until_ready((out, m))
        first = time.perf_counter() - t0
        box[mode] = place(out)
        info[mode] = {"compile_s": compile_s, "first_call_s": first}
        print(json.dumps({"mode": mode, **info[mode]}), file=sys.stderr, flush=True)

        def call(mode=mode, compiled=compiled, place=place):
            out, m = compiled(box[mode])
            jax.block_until_ready((out, m))
            box[mode] = place(out)

        calls[mode] = call
    times = interleave(calls, rounds)
    work = POINTS * num_envs * chunk_steps
    res = {"devices": len(devs), "modes": {}}
    for mode in modes:
        res["modes"][mode] = {**info[mode], **timing(times[mode], work)}
    if "1dev" in times and "2dev" in times:
        res["speedup_2dev_over_1dev"] = statistics.median(
            [a / b for a, b in zip(times["1dev"], times["2dev"])])
    return res


def worker_subprocess(ndev: int, modes: list[str], rounds: int, timeout: float, num_envs: int = NUM_ENVS,
                      chunk_steps: int = CHUNK_STEPS) -> dict:
    env = dict(os.environ)
    env["JAX_PLATFORMS"] = "cpu"
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    env.setdefault("JAX_COMPILATION_CACHE_DIR", os.path.expanduser("~/.cache/nmrl/xla"))
    flags = f"--xla_force_host_platform_device_count={ndev}" if ndev > 1 else ""
    extra = os.environ.get("XLA_FLAGS", "")
    extra = " ".join(f for f in extra.split() if not f.startswith("--xla_force_host_platform_device_count"))
    env["XLA_FLAGS"] = f"{flags} {extra}".strip()
    cmd = [sys.executable, str(pathlib.Path(__file__).resolve()), "--worker", "--rounds", str(rounds),
           "--num-envs", str(num_envs), "--chunk-steps", str(chunk_steps), "--modes", *modes]
    t0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout)
        stdout, stderr, rc = p.stdout, p.stderr, p.returncode
    except subprocess.TimeoutExpired as e:
        stdout = ""
        stderr = e.stderr.decode(errors="replace") if isinstance(e.stderr, bytes) else (e.stderr or "")
        rc = "timeout"
    wall = time.perf_counter() - t0
    if rc != 0 or not stdout.strip():
        done = [json.loads(l) for l in stderr.splitlines() if l.startswith('{"mode"')]
        what = f"timeout after {timeout:.0f} s (hang?)" if rc == "timeout" else f"worker rc={rc}"
        return {"xla_flags": env["XLA_FLAGS"], "error": what, "compiled_before_failure": done,
                "stderr_tail": stderr[-1500:], "wall_s": wall}
    res = json.loads(stdout.strip().splitlines()[-1])
    res["xla_flags"] = env["XLA_FLAGS"]
    res["wall_s"] = wall
    return res


def run(quick: bool = False, smoke: bool = False) -> dict:
    rounds = SMOKE["rounds"] if smoke else 2 if quick else 7
    num_envs, chunk_steps = (SMOKE["num_envs"], SMOKE["chunk_steps"]) if smoke else (NUM_ENVS, CHUNK_STEPS)
    timeout = 600  # per worker: catches a hang; two compiles on a loaded 2-core machine take minutes
    t0 = time.perf_counter()
    out = {
        "benchmark": "training chunk (sweep points) on 1 vs 2 CPU devices via nmrl.runs.sharding shard_map",
        "quick": quick, "smoke": smoke,
        "config": {"points": POINTS, "l": L, "num_envs_per_point": num_envs, "chunk_steps": chunk_steps,
                   "rounds": rounds, "timeout_s": timeout, "split": "points (sweep axis)",
                   "statistic": "median over rounds of the per-round ratio t_1dev/t_2dev"},
        "two_device_process": worker_subprocess(2, ["1dev", "2dev"], rounds, timeout, num_envs, chunk_steps),
        "one_device_process": None,
    }
    if not quick:
        out["one_device_process"] = worker_subprocess(1, ["1dev"], rounds, timeout, num_envs, chunk_steps)
    two = out["two_device_process"]
    out["speedup_2dev_over_1dev"] = two.get("speedup_2dev_over_1dev")
    out["hung_or_failed"] = "error" in two
    out["load_avg"] = list(os.getloadavg())
    out["wall_s"] = time.perf_counter() - t0
    sp = out["speedup_2dev_over_1dev"]
    print(f"scaling: 2 devices / 1 device = {sp:.2f}x" if sp else f"scaling: {two.get('error')}",
          file=sys.stderr, flush=True)
    return out


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--smoke", action="store_true")
    ap.add_argument("--worker", action="store_true")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--num-envs", type=int, default=NUM_ENVS)
    ap.add_argument("--chunk-steps", type=int, default=CHUNK_STEPS)
    ap.add_argument("--modes", nargs="+", default=["1dev", "2dev"])
    a = ap.parse_args()
    if a.worker:
        print(json.dumps(_worker(a.modes, a.rounds, a.num_envs, a.chunk_steps)))
    else:
        print(json.dumps(run(a.quick, a.smoke), indent=1))
