"""Where one PPO iteration of the second exploration study's 2.5 ms grid spends its time, on one device.

A grid cell at 2.5 ms runs each device's seeds vmapped together (``nmrl sweep --group``): per
iteration a device rolls out ``--seeds`` x 64 environments for U T = 256 x 160 control steps and
then takes 8 epochs x 32 minibatches of Adam steps. This script builds that program (by default
white exploration at the study's settings: value net 2x64, trials of 5 s, the 0.0025 s timestep, C
physics), compiles the vmapped ``rollout`` and ``learn`` of nmrl/learners/ppo.py apart and times
each (wall and process CPU seconds, best of ``--repeats``). It takes the options of ``nmrl train
--learner ppo`` (generated from PPOConfig's declarations), so an arm is its exploration options,
e.g. the study's colored arm ``--exploration colored --beta 0.5 --sigma 0.4``; its default
``--num-minibatches 8`` shortens the iteration (U = 512 x 8 / 64 unrolls per environment) without
changing the work per control step. Then, for the rollout's physics, one callback's cost at the
device's batch: the host step alone (``CPhysics._callback`` called from Python), the same inside a
jitted ``lax.scan`` through ``jax.pure_callback``, and a callback of the same shapes that does no
physics (``--no-callback`` skips this part).

    .venv/bin/python scripts/lab/ppo_cost_split.py [--seeds 4] [--repeats 2] [--no-callback]
        [nmrl train's PPO options, e.g. --num-minibatches 4 --exploration ou --corr-time-s 0.01]

It uses one XLA device (the update's kernels may still use every core through XLA's thread pool:
compare its wall and CPU seconds). Timings depend on the load: run it on a quiet machine for
numbers, or beside other work for the split only.
"""

from __future__ import annotations

import os

os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import time  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from nmrl import options
from nmrl.cli.config_options import add_config_options, get_learner, given_options  # noqa: E402
from nmrl.cli.exploration_options import add_exploration_options  # noqa: E402
from nmrl.learners.ppo import make_ppo  # noqa: E402
from nmrl.learners.ppo_config import PPOConfig  # noqa: E402
from nmrl.paper.env import HalfCheetah  # noqa: E402
from nmrl.physics import mujoco_c  # noqa: E402


#: the second exploration study's 2.5 ms grid settings (nmrl/experiments/exploration2_cells.py), but
#: 8 of its 32 minibatches per epoch
STUDY = dict(num_envs=64, batch_size=512, num_minibatches=8, epochs=8, control_dt=0.0025, reward_scale=0.125,
             value_layers=2, value_width=64, physics="c", physics_timestep=0.0025, trial_s=5.0)


def _best(fn, repeats: int) -> tuple[float, float]:
    """(wall, process CPU) seconds of the fastest of ``repeats`` blocking calls."""
    best = (float("inf"), float("inf"))
    for _ in range(repeats):
        w, c = time.perf_counter(), time.process_time()
        jax.block_until_ready(fn())
        best = min(best, (time.perf_counter() - w, time.process_time() - c))
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=4, help="seeds vmapped together on the device (a grid cell: 4)")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--callback-steps", type=int, default=1000, help="control steps timed per callback variant")
    ap.add_argument("--no-callback", action="store_true", help="time the rollout and the update only")
    learner = get_learner("ppo")
    add_config_options(ap, learner=learner)
    add_exploration_options(ap, learner)
    ap.set_defaults(learner="ppo")
    a = ap.parse_args()
    cfg = options.build(PPOConfig, **{**STUDY, **given_options(a)}).resolved()
    env = HalfCheetah(dataclasses.replace(cfg.environment.env_config(), threads=1))
    tr = make_ppo(cfg, env)
    st = jax.jit(jax.vmap(tr.init))(jax.random.split(jax.random.PRNGKey(0), a.seeds))
    keys = jax.random.split(jax.random.PRNGKey(1), a.seeds)
    roll = jax.jit(jax.vmap(tr.rollout)).lower(st, keys).compile()
    _, data = roll(st, keys)
    learn = jax.jit(jax.vmap(tr.learn)).lower(st, data, keys).compile()
    n = a.seeds * cfg.budget.num_envs * cfg.iteration_steps
    rw, rc = _best(lambda: roll(st, keys), a.repeats)
    lw, lc = _best(lambda: learn(st, data, keys), a.repeats)
    print(f"{cfg.noise.spec()}:")
    print(f"{a.seeds} seeds x {cfg.budget.num_envs} environments, {cfg.iteration_steps} control steps each "
          f"({n:,} environment steps), {cfg.epochs} epochs x {cfg.num_minibatches} minibatches:")
    for name, w, c in (("rollout", rw, rc), ("update", lw, lc)):
        print(f"  {name:8s} {w:7.1f} s wall {c:7.1f} s CPU   {1e6 * w / n:6.2f} us wall, "
              f"{1e6 * c / n:6.2f} us CPU per environment step")
    if a.no_callback:
        return

    c = env.c
    b = a.seeds * cfg.budget.num_envs
    steps = a.callback_steps
    bits = mujoco_c.to_bits(np.tile(c.initial_state(), (b, 1)))
    act = np.full((b, c.plant.act_dim), 0.1, np.float32)

    def direct():
        x = bits
        for _ in range(steps):
            x = c._callback(x, act)[0]
        return x

    sb, sa = jnp.asarray(bits), jnp.asarray(act)
    shapes = jax.eval_shape(lambda s: jax.vmap(c.advance)(s, sa), sb)
    zeros = tuple(np.zeros(x.shape, x.dtype) for x in shapes)[1:]

    def in_scan(step):
        return jax.jit(lambda s: jax.lax.scan(lambda x, _: (step(x), None), s, None, length=steps)[0]).lower(
            sb).compile()

    physics = in_scan(lambda s: jax.vmap(c.advance)(s, sa).state)
    empty = in_scan(lambda s: jax.pure_callback(lambda x, _a: (x, *zeros), tuple(shapes), s, sa)[0])
    physics(sb), empty(sb)
    print(f"one physics callback of {b} environments from the initial pose, action 0.1 "
          f"({steps} control steps):")
    for name, fn in (("the host step called from Python", direct), ("through pure_callback in a jitted scan",
                                                                     lambda: physics(sb)),
                     ("a callback of the same shapes without physics", lambda: empty(sb))):
        w, _ = _best(fn, a.repeats)
        print(f"  {name:48s} {1e6 * w / steps:8.0f} us per control step")


if __name__ == "__main__":
    main()
