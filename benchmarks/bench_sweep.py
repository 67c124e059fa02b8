"""One vmapped sweep program vs the same points run one after another (nmrl/sweep.py's claim).

P = 4 points, l in {1, 10} x seeds {0, 1}, ``num_envs`` environments each, ``chunk_steps`` control
steps per chunk:

* ``sweep``: ``jax.vmap(trainer.chunk)`` over the stacked states of all P points, one call per
  chunk (what ``nmrl sweep`` runs on one device);
* ``sequential``: ``trainer.chunk`` of one point, called once per point (P calls per chunk, the same
  total steps; what P separate ``nmrl train`` runs would do one after another). l is a traced value,
  so one compiled single-point program serves every point (each separate run would compile its own,
  the same, program: P x ``compile_s.sequential`` in total).

Compile time is reported apart; then the two are timed interleaved (sweep, P sequential calls,
sweep, ...), medians of the per-round times. Per-point throughput = control steps of one point per
second of wall time spent on all points / P, i.e. ``N * chunk_steps / (t / P)``; the goal is
sweep >= sequential.

``run(quick) -> dict``; ``python benchmarks/bench_sweep.py [--quick]`` prints it.
"""

from __future__ import annotations

import os
import pathlib
import statistics
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", os.path.expanduser("~/.cache/nmrl/xla"))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

from benchmarks.bench_learning import interleave, load_avg, timing  # noqa: E402

LS = (1, 10)
SEEDS = 2
NUM_ENVS = 32  # per point; the same in quick and full mode (compile-cache reuse)
CHUNK_STEPS = 32


def run(quick: bool = False) -> dict:
    from nmrl.learner import Hyper, TrainConfig, make_train
    from nmrl.run import compile_chunk

    rounds = 2 if quick else 9
    t_start = time.perf_counter()
    base = TrainConfig(num_envs=NUM_ENVS, chunk_steps=CHUNK_STEPS)
    configs = [TrainConfig(num_envs=NUM_ENVS, chunk_steps=CHUNK_STEPS, l=l, seed=s).resolved()
               for l in LS for s in range(SEEDS)]
    P = len(configs)
    trainer = make_train(base)
    init = jax.jit(jax.vmap(trainer.init))
    keys = jnp.stack([jax.random.PRNGKey(c.seed) for c in configs])
    hypers = jax.tree.map(lambda *x: jnp.stack(x), *[Hyper.from_config(c) for c in configs])
    stacked = jax.block_until_ready(init(keys, hypers))
    singles = [jax.tree.map(lambda x, i=i: x[i], stacked) for i in range(P)]

    sweep_fn, sweep_compile = compile_chunk(jax.vmap(trainer.chunk), stacked)
    one_fn, one_compile = compile_chunk(trainer.chunk, singles[0])
    box = {"sweep": stacked, "seq": singles}
    t0 = time.perf_counter()
    box["sweep"], m = sweep_fn(box["sweep"])
    jax.block_until_ready((box["sweep"], m))
    sweep_first = time.perf_counter() - t0
    t0 = time.perf_counter()
    for i in range(P):
        box["seq"][i], m = one_fn(box["seq"][i])
        jax.block_until_ready((box["seq"][i], m))
    seq_first = time.perf_counter() - t0

    def do_sweep():
        box["sweep"], m = sweep_fn(box["sweep"])
        jax.block_until_ready((box["sweep"], m))

    def do_seq():
        for i in range(P):
            box["seq"][i], m = one_fn(box["seq"][i])
            jax.block_until_ready((box["seq"][i], m))

    times = interleave({"sweep": do_sweep, "sequential": do_seq}, rounds)
    work = P * NUM_ENVS * CHUNK_STEPS  # control steps per round, all points
    sw, sq = timing(times["sweep"], work), timing(times["sequential"], work)
    for t in (sw, sq):
        t["per_point_control_steps_per_s"] = t["control_steps_per_s"] / P
    ratio = statistics.median([q / s for s, q in zip(times["sweep"], times["sequential"])])
    # the two compute the same thing; with the paper's network sizes XLA may pick different dot
    # kernels for the batched (vmapped) and the single program, so compare up to the last bits
    diffs = [float(jnp.max(jnp.abs(a[i] - b)))
             for i in range(P)
             for a, b in zip(jax.tree.leaves((box["sweep"].theta, box["sweep"].v)),
                             jax.tree.leaves((box["seq"][i].theta, box["seq"][i].v)))]
    same = max(diffs) == 0.0
    res = {
        "benchmark": "vmapped sweep chunk vs the same points one after another, interleaved",
        "quick": quick,
        "config": {"ls": list(LS), "seeds": SEEDS, "points": P, "num_envs_per_point": NUM_ENVS,
                   "chunk_steps": CHUNK_STEPS, "rounds": rounds,
                   "statistic": "median over rounds of the per-round ratio t_sequential/t_sweep"},
        "compile_s": {"sweep": sweep_compile, "sequential_one_point": one_compile,
                      "sequential_total_if_separate_runs": P * one_compile},
        "first_call_s": {"sweep": sweep_first, "sequential": seq_first},
        "sweep": sw, "sequential": sq,
        "sweep_over_sequential": ratio,
        "sweep_over_sequential_of_medians": sw["control_steps_per_s"] / sq["control_steps_per_s"],
        "results_identical": same,
        "params_max_abs_diff": max(diffs),
        "steps_per_point_compared": int(box["sweep"].step[0]),
        "goal": "sweep >= sequential per point",
        "goal_met": ratio >= 1.0,
        "load_avg": load_avg(),
        "wall_s": time.perf_counter() - t_start,
    }
    print(f"sweep: {P} points x {NUM_ENVS} envs: sweep {sw['per_point_control_steps_per_s']:,.0f}, sequential "
          f"{sq['per_point_control_steps_per_s']:,.0f} ctrl steps/s per point; ratio {ratio:.2f} "
          f"(compile sweep {sweep_compile:.1f} s, one point {one_compile:.1f} s)", file=sys.stderr, flush=True)
    return res


if __name__ == "__main__":
    import json

    print(json.dumps(run("--quick" in sys.argv), indent=1))
