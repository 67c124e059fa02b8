"""MuJoCo C physics inside the jitted program (``--physics c``) against MJX and against MuJoCo C alone.

In one worker subprocess with one host device per core (``nmrl sweep``'s layout), contenders
interleaved round by round so that a background load touches them alike:

* (a) the C environment in the program: a jitted ``lax.scan`` of ``vmap(env.step)`` (B = 64, the
  PD torque per substep, observation and reward in JAX) on one device, against ``mujoco.batch``
  alone stepping the same B simulations with the same PD law in a Python loop, both with the same
  threads: the ratio is what the callback boundary costs;
* (b) the paper's 24-point sweep with learning (l in {1, 2, 3, 5, 10, 15, 20, 30} x 3 seeds, 32
  environments per point, ``nmrl.runs.points.points_program`` over every device) on C against the
  same on MJX, the C sweep laid out on one device with a batch of ``cores`` threads, and the C
  sweep with each device's points vmapped together (``--group``: one callback steps all of a
  device's environments), grouped once with the networks' fast arctan (the default) and once with
  XLA's (``--arctan xla``, the runs made before the option);
* (c) the C sweep against MuJoCo C's own throughput at the same batch (32; grouped: 32 x the
  points per device) and threads (``cores``, ``mujoco.batch`` with the PD law): the share of the
  limit the program reaches;
* (d) the native PPO at the exploration study's settings (64 environments, value 2x64), one
  iteration (rollout + update) on C against MJX, at 20 and 5 ms (``--quick``: 5 ms), with 4
  minibatches per iteration (the study's 32 only change how many);
* (e) the second exploration study's grid layout at 2.5 ms: 8 seeds of that PPO on C over the
  devices, each device's seeds vmapped together (``--group 8``) against a seed at a time, one
  iteration of one minibatch of the study's 512 unrolls of 0.4 s (``--quick``: 128).

Control steps per second of the whole machine; compile times apart. ``--quick`` fewer rounds and
steps; ``smoke`` the smallest setting. ``run(quick, smoke=False) -> dict``;
``python -m benchmarks --only physics_c``.
"""

from __future__ import annotations

import dataclasses
import statistics
import sys
import time

from benchmarks import worker_main

from nmrl import options

LS = (1, 2, 3, 5, 10, 15, 20, 30)
SEEDS = 3
NUM_ENVS = 32
ENV_BATCH = 64
SMOKE = {"ls": (1, 10), "seeds": 1, "num_envs": 4, "chunk_steps": 4, "rounds": 1, "env_steps": 8}


def batch_alone(n: int, threads: int, steps: int) -> float:
    """Control steps/s of ``mujoco.batch`` stepping n simulations of the paper's robot with the PD
    law of Sec. V-A per substep (zero action), no JAX."""
    import mujoco
    import mujoco.batch
    import numpy as np

    from nmrl.paper import c_plant
    from nmrl.paper.env import MODEL_PATH

    m = c_plant.with_limit_sensors(mujoco.MjSpec.from_file(str(MODEL_PATH)))
    b = mujoco.batch.Batch(m, n, threads)
    qpos, qvel, ctrl = b.bind("qpos"), b.bind("qvel"), b.bind("ctrl")
    act = np.zeros((n, 6))
    n_sub = 4

    def go(k):
        for _ in range(k):
            for _ in range(n_sub):
                ctrl[:], _over = c_plant.pd_law(qpos, qvel, act)
                b.step()
                _ = b.sensordata

    go(5)
    t0 = time.perf_counter()
    go(steps)
    return n * steps / (time.perf_counter() - t0)


def _worker(quick: bool, smoke: bool) -> dict:
    import jax
    import jax.numpy as jnp

    from benchmarks.bench_learning import interleave, timing
    from nmrl.learners.ppo import make_ppo
    from nmrl.learners.ppo_config import PPOConfig
    from nmrl.paper.env import EnvConfig, HalfCheetah
    from nmrl.learners.ac_config import Hyper, TrainConfig
    from nmrl.learners.ac_train import make_train
    from nmrl.physics.mujoco_c import threads_per_device
    from nmrl.runs import points
    from nmrl.runs.devices import cpu_cores

    n_dev, cores = len(jax.local_devices()), cpu_cores()
    rounds = SMOKE["rounds"] if smoke else 2 if quick else 4
    out: dict = {"devices": n_dev, "cores": cores, "threads_per_device": threads_per_device()}

    # (a) the environment in the program vs mujoco.batch alone, one device, `cores` threads
    n_steps = SMOKE["env_steps"] if smoke else 100 if quick else 400
    env = HalfCheetah(EnvConfig(physics="c", threads=cores))
    s0 = jax.device_put(jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(0), ENV_BATCH)),
                        jax.local_devices()[0])
    zero = jnp.zeros((ENV_BATCH, 6))
    f = jax.jit(lambda s: jax.lax.scan(lambda s, _: (jax.vmap(env.step)(s, zero), ()), s, None,
                                       length=n_steps)[0])
    box = {"s": jax.block_until_ready(f(s0))}

    def do_env():
        box["s"] = jax.block_until_ready(f(box["s"]))

    alone: list[float] = []
    times = interleave({"env": do_env, "alone": lambda: alone.append(batch_alone(ENV_BATCH, cores, n_steps))},
                       rounds)
    env_rate = timing(times["env"], ENV_BATCH * n_steps)["control_steps_per_s"]
    out["a_env"] = {"batch": ENV_BATCH, "threads": cores, "in_program": env_rate,
                    "batch_alone": statistics.median(alone), "ratio": env_rate / statistics.median(alone)}

    # (b) the 24-point sweep with learning: C over the devices, MJX over the devices, C on one device
    ls, seeds = (SMOKE["ls"], SMOKE["seeds"]) if smoke else (LS, SEEDS)
    num_envs = SMOKE["num_envs"] if smoke else NUM_ENVS
    T = SMOKE["chunk_steps"] if smoke else 10 if quick else 40

    def sweep(physics: str, n_use: int, group: int = 1, arctan: str = "fast"):
        cfgs = [options.build(TrainConfig, num_envs=num_envs, chunk_steps=T, l=l, seed=s, physics=physics,
                            arctan=arctan).resolved() for l in ls for s in range(seeds)]
        env_cfg = dataclasses.replace(cfgs[0].environment.env_config(), threads=max(1, cores // n_use))
        tr = make_train(cfgs[0], HalfCheetah(env_cfg))
        keys = jnp.stack([jax.random.PRNGKey(c.budget.seed) for c in cfgs])
        ts = jax.jit(jax.vmap(tr.init))(keys, points.stack_trees([Hyper.from_config(c) for c in cfgs]))
        call, compile_s = points_call(tr.chunk, ts, len(cfgs), n_use, group)
        return call, compile_s, len(cfgs) * num_envs * T

    calls, compiles, work = {}, {}, 0
    per_dev = -(-len(ls) * seeds // n_dev)  # the points one device holds
    for name, physics, n_use, group, arctan in (("c", "c", n_dev, 1, "fast"), ("mjx", "mjx", n_dev, 1, "fast"),
                                                ("c_one_device", "c", 1, 1, "fast"),
                                                ("c_grouped", "c", n_dev, per_dev, "fast"),
                                                ("c_grouped_xla_arctan", "c", n_dev, per_dev, "xla")):
        calls[name], compiles[name], work = sweep(physics, n_use, group, arctan)
    times = interleave(calls, rounds)
    rates = {k: timing(v, work)["control_steps_per_s"] for k, v in times.items()}
    per_round = [(work / c) / (work / m) for c, m in zip(times["c"], times["mjx"])]
    out["b_sweep"] = {"points": len(ls) * seeds, "num_envs_per_point": num_envs, "chunk_steps": T,
                      "c_grouped_points_per_call": per_dev,
                      "c_grouped_over_c": statistics.median(c / g for c, g in zip(times["c"], times["c_grouped"])),
                      "fast_over_xla_arctan": statistics.median(x / f for x, f in zip(times["c_grouped_xla_arctan"],
                                                                                       times["c_grouped"])),
                      "rates": rates, "compile_s": compiles, "c_over_mjx": statistics.median(per_round),
                      "c_over_mjx_per_round": per_round}

    # (c) the limit: MuJoCo C alone at the sweep's batch and threads
    limit = statistics.median(batch_alone(num_envs, cores, n_steps) for _ in range(rounds))
    limit_g = statistics.median(batch_alone(num_envs * per_dev, cores, n_steps) for _ in range(rounds))
    out["c_limit"] = {"batch": num_envs, "threads": cores, "batch_alone": limit,
                      "sweep_c_over_limit": rates["c"] / limit,
                      "grouped_batch": num_envs * per_dev, "grouped_batch_alone": limit_g,
                      "sweep_c_grouped_over_limit": rates["c_grouped"] / limit_g,
                      "sweep_c_grouped_xla_arctan_over_limit": rates["c_grouped_xla_arctan"] / limit_g}

    # (d) native PPO, one iteration (rollout + update), 64 environments, value 2x64, at 20 and 5 ms
    out["d_ppo"] = {}
    for dt in (0.005,) if quick else (0.02, 0.005):
        mb = 2 if smoke else 4
        ppo = {}
        for physics in ("c", "mjx"):
            cfg = options.build(PPOConfig, num_envs=ENV_BATCH, control_dt=dt, reward_scale=dt / 0.02, value_layers=2,
                            value_width=64, num_minibatches=mb, physics=physics).resolved()
            tr = make_ppo(cfg)
            st = jax.jit(tr.init)(jax.random.PRNGKey(0))
            t0 = time.perf_counter()
            fn = jax.jit(tr.chunk, donate_argnums=0).lower(st).compile()
            b2 = {"st": st, "compile_s": time.perf_counter() - t0, "work": ENV_BATCH * cfg.budget.chunk_steps}

            def call(fn=fn, b2=b2):
                b2["st"], m = fn(b2["st"])
                jax.block_until_ready(m)

            call()
            ppo[physics] = (call, b2)
        t = interleave({k: v[0] for k, v in ppo.items()}, max(1, rounds // 2) if not smoke else 1)
        r = {k: timing(t[k], ppo[k][1]["work"])["control_steps_per_s"] for k in t}
        out["d_ppo"][f"{dt * 1000:g}ms"] = {"num_minibatches": mb, "rates": r, "c_over_mjx": r["c"] / r["mjx"],
                                            "compile_s": {k: ppo[k][1]["compile_s"] for k in ppo}}
    out["e_ppo_group"] = _ppo_group(n_dev, cores, rounds, quick, smoke)
    return out


def points_call(chunk, ts, n_points: int, n_use: int, group: int):
    """``(call, compile_s)``: the points' stacked states ``ts`` laid out over ``n_use`` devices as the
    sweep lays them (nmrl.runs.points), their program compiled apart, and ``call()`` running one
    chunk of every point (blocking; it carries the states on), already run once."""
    import jax
    import jax.numpy as jnp

    from nmrl.runs import points

    slots = points.slot_order(n_points, n_use)
    ts = points.place_points(points.stack_trees([points.unstack(ts, max(i, 0)) for i in slots]), n_use)
    act = points.place_points(jnp.asarray([i >= 0 for i in slots]), n_use)
    t0 = time.perf_counter()
    fn = jax.jit(points.points_program(chunk, n_use, group), donate_argnums=0).lower(ts, act).compile()
    compile_s = time.perf_counter() - t0
    box = {"ts": ts}

    def call():
        box["ts"], m = fn(box["ts"], act)
        jax.block_until_ready(m)

    call()
    return call, compile_s


def _ppo_group(n_dev: int, cores: int, rounds: int, quick: bool, smoke: bool) -> dict:
    """(e): 8 seeds of PPO at 2.5 ms on C (trials of 5 s, the 0.0025 s timestep) over the devices,
    ``group`` 1 against 8, interleaved; control steps per second of the whole machine."""
    import jax
    import jax.numpy as jnp

    from benchmarks.bench_learning import interleave, timing
    from nmrl.learners.ppo import make_ppo
    from nmrl.learners.ppo_config import PPOConfig
    from nmrl.paper.env import HalfCheetah

    seeds, dt = (2, 0.02) if smoke else (8, 0.0025)
    cfg = options.build(PPOConfig, num_envs=4 if smoke else ENV_BATCH, batch_size=4 if smoke else 128 if quick else 512,
                    num_minibatches=1, control_dt=dt, reward_scale=dt / 0.02,
                    value_layers=2, value_width=64, physics="c", physics_timestep=0.0025, trial_s=5.0).resolved()
    tr = make_ppo(cfg, HalfCheetah(dataclasses.replace(cfg.environment.env_config(), threads=max(1, cores // n_dev))))
    calls, compiles = {}, {}
    for group in (1, seeds):
        st = jax.jit(jax.vmap(tr.init))(jnp.stack([jax.random.PRNGKey(s) for s in range(seeds)]))
        calls[group], compiles[group] = points_call(tr.chunk, st, seeds, n_dev, group)
    times = interleave(calls, max(1, rounds // 2) if not smoke else 1)
    work = seeds * cfg.budget.num_envs * cfg.budget.chunk_steps
    rates = {f"group_{g}": timing(times[g], work)["control_steps_per_s"] for g in calls}
    return {"seeds": seeds, "control_dt": dt, "num_minibatches": cfg.num_minibatches, "rates": rates,
            "grouped_over_one_at_a_time": statistics.median(a / b for a, b in zip(times[1], times[seeds])),
            "compile_s": {f"group_{g}": c for g, c in compiles.items()}}


def run(quick: bool = False, smoke: bool = False, timeout: float = 3600) -> dict:
    from benchmarks.bench_learning import worker_section

    sec = worker_section("benchmarks.bench_physics_c", quick, smoke, timeout)
    w = sec["worker"]
    sw = w["b_sweep"]
    res = {
        "benchmark": "--physics c: the C env in the program vs mujoco.batch alone; the 24-point sweep with "
                     "learning on C vs MJX vs MuJoCo C alone; native PPO one iteration on C vs MJX",
        **sec,
        "goal": "the sweep with learning on C >= 0.6x MuJoCo C alone at the same batch and threads "
                "(either layout: a point at a time, or each device's points grouped)",
        "goal_met": bool(max(w["c_limit"]["sweep_c_over_limit"], w["c_limit"]["sweep_c_grouped_over_limit"]) >= 0.6),
    }
    print(f"physics_c: env in program {w['a_env']['ratio']:.2f}x mujoco.batch alone; sweep C "
          f"{sw['rates']['c']:,.0f} vs MJX {sw['rates']['mjx']:,.0f} ctrl steps/s ({sw['c_over_mjx']:.2f}x), "
          f"C on one device {sw['rates']['c_one_device']:,.0f}, C grouped {sw['rates']['c_grouped']:,.0f}; "
          f"sweep C / MuJoCo C alone {w['c_limit']['sweep_c_over_limit']:.2f} (grouped "
          f"{w['c_limit']['sweep_c_grouped_over_limit']:.2f}, with XLA's arctan "
          f"{w['c_limit']['sweep_c_grouped_xla_arctan_over_limit']:.2f}); PPO C/MJX "
          + ", ".join(f"{k} {v['c_over_mjx']:.2f}x" for k, v in w["d_ppo"].items())
          + f"; PPO 2.5 ms, 8 seeds grouped / one at a time {w['e_ppo_group']['grouped_over_one_at_a_time']:.2f}x",
          file=sys.stderr, flush=True)
    return res


if __name__ == "__main__":
    worker_main(_worker, run)
