"""The actor-critic's per-step cost in the grouped C sweep (benchmarks/bench_physics_c.py's (b'') and
(c)): the 24-point sweep with learning, each device's 12 points vmapped together, against MuJoCo C
alone at the same batch (384) and threads, interleaved in one process with one device per core.

``python scripts/lab/ac_step_cost.py [--rounds R] [--steps T]`` prints control steps per second of
both, their ratio, and the microseconds per environment step of the learning (the sweep's step
minus MuJoCo C's). Run it on a quiet machine; it sets the devices itself.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

from nmrl import options


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=40, help="control steps per chunk")
    ap.add_argument("--dump", default=None, help="a folder for XLA's HLO after optimisation")
    args = ap.parse_args()
    from nmrl.runs import devices

    cores = devices.configure(None)
    if args.dump:
        os.environ["XLA_FLAGS"] = os.environ.get("XLA_FLAGS", "") + f" --xla_dump_to={args.dump} --xla_dump_hlo_as_text"
    import dataclasses

    import jax
    import jax.numpy as jnp

    from benchmarks.bench_learning import interleave, timing
    from benchmarks.bench_physics_c import LS, NUM_ENVS, SEEDS, batch_alone, points_call
    from nmrl.learners.ac_config import Hyper, TrainConfig
    from nmrl.learners.ac_train import make_train
    from nmrl.paper.env import HalfCheetah
    from nmrl.runs import points

    n_dev = len(jax.local_devices())
    cfgs = [options.build(TrainConfig, num_envs=NUM_ENVS, chunk_steps=args.steps, l=l, seed=s, physics="c").resolved()
            for l in LS for s in range(SEEDS)]
    per_dev = -(-len(cfgs) // n_dev)
    env_cfg = dataclasses.replace(cfgs[0].environment.env_config(), threads=max(1, cores // n_dev))
    tr = make_train(cfgs[0], HalfCheetah(env_cfg))
    keys = jnp.stack([jax.random.PRNGKey(c.budget.seed) for c in cfgs])
    ts = jax.jit(jax.vmap(tr.init))(keys, points.stack_trees([Hyper.from_config(c) for c in cfgs]))
    call, compile_s = points_call(tr.chunk, ts, len(cfgs), n_dev, per_dev)
    work = len(cfgs) * NUM_ENVS * args.steps
    alone: list[float] = []
    times = interleave({"sweep": call, "alone": lambda: alone.append(
        batch_alone(NUM_ENVS * per_dev, cores, args.steps * 5))}, args.rounds)
    rate = timing(times["sweep"], work)["control_steps_per_s"]
    lim = statistics.median(alone)
    print(f"devices {n_dev}, cores {cores}, compile {compile_s:.1f} s; grouped sweep {rate:,.0f} control steps/s, "
          f"MuJoCo C alone (B = {NUM_ENVS * per_dev}) {lim:,.0f}: ratio {rate / lim:.3f}; per environment step "
          f"{1e6 / rate:.1f} us, of it MuJoCo C {1e6 / lim:.1f} us, the rest {1e6 / rate - 1e6 / lim:.1f} us")


if __name__ == "__main__":
    main()
