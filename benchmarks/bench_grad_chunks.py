"""PPO's minibatch gradient taken whole against taken in parts (``--grad-chunks``), in the second
exploration study's 2.5 ms grid layout.

In one worker subprocess with one host device per core (``nmrl sweep``'s layout): 8 seeds of the
native PPO at 2.5 ms on C (64 environments, value 2x64, trials of 5 s, the 0.0025 s timestep, white
exploration), each device's seeds vmapped together (``--group 8``), one iteration per call with the
study's minibatches of 512 unrolls of 0.4 s (fewer of them per iteration: 4, ``--quick`` 2; the
study's 32 only change how many). The contenders differ only in ``grad_chunks``: 1 (each
minibatch's gradient at once, 82k samples per seed) against 8 (its 8 parts of 64 unrolls in turn,
the advantages normalised over the whole minibatch first; nmrl/learners/ppo.py), and in a full run
also 2 and 4; interleaved round by round so that a background load touches them alike. Control
steps per second of the whole machine (rollout and update: what a grid cell's chunk costs) and the
per-round ratio against the whole-minibatch gradient; compile times apart.

``run(quick, smoke=False) -> dict``; ``python -m benchmarks --only grad_chunks``.
"""

from __future__ import annotations

import dataclasses
import statistics
import sys

from benchmarks import worker_main

from nmrl import options

SMOKE = {"seeds": 2, "num_envs": 4, "batch_size": 8, "control_dt": 0.02, "chunks": (1, 2)}


def _worker(quick: bool, smoke: bool) -> dict:
    import jax
    import jax.numpy as jnp

    from benchmarks.bench_learning import interleave, timing
    from benchmarks.bench_physics_c import points_call
    from nmrl.learners.ppo import make_ppo
    from nmrl.learners.ppo_config import PPOConfig
    from nmrl.paper.env import HalfCheetah
    from nmrl.physics.mujoco_c import threads_per_device
    from nmrl.runs.devices import cpu_cores

    n_dev, cores = len(jax.local_devices()), cpu_cores()
    if smoke:
        seeds, dt, chunks, rounds = SMOKE["seeds"], SMOKE["control_dt"], SMOKE["chunks"], 1
        size = dict(num_envs=SMOKE["num_envs"], batch_size=SMOKE["batch_size"], num_minibatches=1)
    else:
        seeds, dt, chunks, rounds = 8, 0.0025, (1, 8) if quick else (1, 2, 4, 8), 2 if quick else 3
        size = dict(num_envs=64, batch_size=512, num_minibatches=2 if quick else 4)
    calls, compiles, work = {}, {}, None
    for c in chunks:
        cfg = options.build(PPOConfig, **size, grad_chunks=c, control_dt=dt, reward_scale=dt / 0.02, value_layers=2,
                        value_width=64, physics="c", physics_timestep=0.0025, trial_s=5.0).resolved()
        tr = make_ppo(cfg, HalfCheetah(dataclasses.replace(cfg.environment.env_config(), threads=max(1, cores // n_dev))))
        st = jax.jit(jax.vmap(tr.init))(jnp.stack([jax.random.PRNGKey(s) for s in range(seeds)]))
        calls[c], compiles[c] = points_call(tr.chunk, st, seeds, n_dev, seeds)
        work = seeds * cfg.budget.num_envs * cfg.budget.chunk_steps
    times = interleave(calls, rounds)
    rates = {f"chunks_{c}": timing(times[c], work)["control_steps_per_s"] for c in chunks}
    over = {f"chunks_{c}": statistics.median(a / b for a, b in zip(times[1], times[c])) for c in chunks[1:]}
    return {"devices": n_dev, "cores": cores, "threads_per_device": threads_per_device(), "seeds": seeds,
            "control_dt": dt, "num_minibatches": size["num_minibatches"], "rounds": rounds,
            "control_steps_per_call": work, "rates": rates, "times_s": {f"chunks_{c}": times[c] for c in chunks},
            "speedup_over_whole": over, "compile_s": {f"chunks_{c}": s for c, s in compiles.items()}}


def run(quick: bool = False, smoke: bool = False, timeout: float = 3600) -> dict:
    from benchmarks.bench_learning import worker_section

    res = {"benchmark": "PPO at 2.5 ms in the grid layout, one iteration: each minibatch's gradient in parts "
                        "(--grad-chunks) vs at once",
           **worker_section("benchmarks.bench_grad_chunks", quick, smoke, timeout)}
    w = res["worker"]
    print("grad_chunks: " + ", ".join(f"{k.split('_')[1]} parts {v:.2f}x" for k, v in w["speedup_over_whole"].items())
          + f" the whole minibatch's gradient ({w['rates']['chunks_1']:,.0f} ctrl steps/s)", file=sys.stderr, flush=True)
    return res


if __name__ == "__main__":
    worker_main(_worker, run)
