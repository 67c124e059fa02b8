"""The paper's 24-point sweep with learning: the layout of nmrl sweep vs one vmap on one device vs MuJoCo C.

In one run (a worker subprocess with ``XLA_FLAGS=--xla_force_host_platform_device_count=<cores>``,
the contenders interleaved round by round: a, b, a, b, ...):

* (a) ``new``: the layout of ``nmrl sweep`` (nmrl/runs/points.py ``points_program``): the 24 points
  (l in {1, 2, 3, 5, 10, 15, 20, 30} x 3 seeds) of ``NUM_ENVS`` environments each, split over every
  device with ``shard_map``, stepped one after another on each device (``lax.map``), with learning;
* (b) ``single_vmap``: the layout of results/fig3_fast: the same 24 points with 64 environments
  each, ``jax.vmap`` over all points, on one device;
* (c) ``mujoco_c``: MuJoCo C (``mujoco.rollout``, one thread per core) on the same model, open-loop
  random controls, batch 64, as the physical reference (no learning).

All in control steps per second for the whole machine; compile time reported apart. ``--quick``:
fewer steps per call and rounds; ``smoke``: 2 points of 4 environments, one round (the harness's
paths only). ``run(quick, smoke=False) -> dict``; ``python -m benchmarks --only sweep``.
"""

from __future__ import annotations

import statistics
import sys
import time

from benchmarks import worker_main

from nmrl import options

LS = (1, 2, 3, 5, 10, 15, 20, 30)
SEEDS = 3
NUM_ENVS = 32  # per point, the layout of nmrl sweep (scripts/run/fig3_paper.sh)
OLD_NUM_ENVS = 64  # per point, results/fig3_fast
CHUNK_STEPS = {True: 10, False: 40}  # control steps per call, (a); (b) runs the same total work
#: the smallest setting: l = 1, 10, one seed, 4 (a) / 8 (b) environments, 4-step calls, one round
SMOKE = {"ls": (1, 10), "seeds": 1, "num_envs": 4, "old_num_envs": 8, "chunk_steps": 4, "rounds": 1,
         "c_batch": 8, "c_steps": 64}


def _worker(quick: bool, smoke: bool = False) -> dict:
    import jax
    import jax.numpy as jnp

    from benchmarks.bench_learning import interleave, timing
    from nmrl.learners.ac_config import Hyper, TrainConfig
    from nmrl.learners.ac_train import make_train
    from nmrl.runs import points

    n_dev = len(jax.local_devices())
    T = SMOKE["chunk_steps"] if smoke else CHUNK_STEPS[quick]
    rounds = SMOKE["rounds"] if smoke else 2 if quick else 5
    ls, seeds = (SMOKE["ls"], SMOKE["seeds"]) if smoke else (LS, SEEDS)
    num_envs, old_num_envs = (SMOKE["num_envs"], SMOKE["old_num_envs"]) if smoke else (NUM_ENVS, OLD_NUM_ENVS)

    def build(n_envs, chunk_steps):
        cfgs = [options.build(TrainConfig, num_envs=n_envs, chunk_steps=chunk_steps, l=l, seed=s).resolved()
                for l in ls for s in range(seeds)]
        tr = make_train(cfgs[0])
        keys = jnp.stack([jax.random.PRNGKey(c.budget.seed) for c in cfgs])
        hyp = points.stack_trees([Hyper.from_config(c) for c in cfgs])
        return tr, jax.jit(jax.vmap(tr.init))(keys, hyp), len(cfgs)

    # (a) the layout of nmrl sweep; its slots padded to a multiple of the devices as run_points does
    tr_a, ts_a, P = build(num_envs, T)
    slots = points.slot_order(P, n_dev)
    ts_a = points.place_points(points.stack_trees([points.unstack(ts_a, max(i, 0)) for i in slots]), n_dev)
    act = points.place_points(jnp.asarray([i >= 0 for i in slots]), n_dev)
    t0 = time.perf_counter()
    fa = jax.jit(points.points_program(tr_a.chunk, n_dev), donate_argnums=0).lower(ts_a, act).compile()
    compile_a = time.perf_counter() - t0
    # (b) one vmap over all points, on one device; the same control steps per call
    T_b = max(1, T * num_envs // old_num_envs)
    tr_b, ts_b, _ = build(old_num_envs, T_b)
    ts_b = jax.device_put(ts_b, jax.local_devices()[0])
    t0 = time.perf_counter()
    fb = jax.jit(jax.vmap(tr_b.chunk), donate_argnums=0).lower(ts_b).compile()
    compile_b = time.perf_counter() - t0
    box = {"a": ts_a, "b": ts_b}

    def do_a():
        box["a"], m = fa(box["a"], act)
        jax.block_until_ready(m)

    def do_b():
        box["b"], m = fb(box["b"])
        jax.block_until_ready(m)

    do_a(), do_b()  # warm-up
    times = interleave({"new": do_a, "single_vmap": do_b}, rounds)
    work_a, work_b = P * num_envs * T, P * old_num_envs * T_b
    ta, tb = timing(times["new"], work_a), timing(times["single_vmap"], work_b)
    ratios = [(work_a / a) / (work_b / b) for a, b in zip(times["new"], times["single_vmap"])]
    return {"devices": n_dev, "points": P, "new": {**ta, "num_envs_per_point": num_envs, "chunk_steps": T,
                                                   "compile_s": compile_a},
            "single_vmap": {**tb, "num_envs_per_point": old_num_envs, "chunk_steps": T_b, "compile_s": compile_b},
            "speedup_per_round": ratios, "speedup": statistics.median(ratios), "rounds": rounds}


def run(quick: bool = False, smoke: bool = False, timeout: float = 1800) -> dict:
    from benchmarks.bench_env import c_rollout
    from benchmarks.bench_learning import load_avg, run_worker
    from nmrl.runs.devices import cpu_cores

    t0 = time.perf_counter()
    ncpu = cpu_cores()
    load = [load_avg()]
    c_batch, c_steps = (SMOKE["c_batch"], SMOKE["c_steps"]) if smoke else (64, 4096)
    c_reps = 1 if smoke else 2 if quick else 3
    c_before = c_rollout([c_batch], c_steps, [ncpu], repeats=c_reps)[0]
    size = ["--smoke"] if smoke else ["--quick"] if quick else []
    w = run_worker("benchmarks.bench_sweep", size, ncpu, timeout)
    load.append(load_avg())
    c_after = c_rollout([c_batch], c_steps, [ncpu], repeats=c_reps)[0]
    c_ctrl = statistics.mean([c_before["control_steps_per_s"], c_after["control_steps_per_s"]])
    a = w["new"]["control_steps_per_s"]
    hours = 24 * 1e5 * 250 / a / 3600
    res = {
        "benchmark": "24-point sweep with learning, control steps/s of the whole machine: the layout of nmrl sweep vs "
                     "single vmap on one device vs MuJoCo C",
        "quick": quick, "smoke": smoke,
        "worker": w,
        "mujoco_c": {"nthreads": ncpu, "batch": c_batch, "control_steps_per_s": c_ctrl, "runs": [c_before, c_after]},
        "sweep_ctrl_steps_per_s": a,
        "sweep_speedup_over_single_vmap": w["speedup"],
        "sweep_over_mujoco_c": a / c_ctrl,
        "hours_for_1e5_trials_x_24_points": hours,
        "goal": "(a) >= 20,000 control steps/s and >= 4x (b); compile <= 60 s",
        "goal_met": bool(a >= 20_000 and w["speedup"] >= 4 and w["new"]["compile_s"] <= 60),
        "load_avg": load,
        "wall_s": time.perf_counter() - t0,
    }
    print(f"sweep: new {a:,.0f} ctrl steps/s ({w['devices']} dev), single vmap "
          f"{w['single_vmap']['control_steps_per_s']:,.0f}, speedup {w['speedup']:.2f}x, MuJoCo C {c_ctrl:,.0f}; "
          f"compile {w['new']['compile_s']:.1f} s; 10^5 trials x 24 points: {hours:.1f} h",
          file=sys.stderr, flush=True)
    return res


if __name__ == "__main__":
    worker_main(_worker, run)
