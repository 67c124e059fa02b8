"""Native PPO (nmrl.learners.ppo) against Brax PPO at equal settings, where the native time goes, and
the measurements that size the exploration study (docs/exploration-study.md).

* **Speed**: control steps/s (all environments) with learning at the Brax baseline's settings (64
  environments, unroll 20, minibatches of 512 unrolls, 8 epochs, policy 4x32, value 5x256, one CPU
  device each). Rounds alternate native, Brax, native, ...; the native chunk (one iteration) is
  compiled once, apart, and timed per round; Brax is ``nmrl baseline ppo --devices 1`` in a
  subprocess per round, its speed the median of the per-iteration ``steps_per_s`` after the
  iterations that compile (bench_baseline.WARMUP), whose extra time is its compile time. The ratio
  is the median of the per-round ratios. ``--quick`` keeps every per-sample setting and takes 4
  minibatches per iteration instead of 32 (an iteration of 40,960 control steps), both sides alike.
* **Profile** (native, one iteration, each piece jitted apart, median of the timed calls): the
  environment alone (a ``lax.scan`` of ``vmap(env.step)`` over the iteration's steps, random
  actions), the rollout (physics + policy + exploration noise), the update (observation statistics
  and epochs x minibatches), the update with the value net replaced by a 1x1 one (the difference is
  the value net's share), with both nets 1x1 (what is left: GAE, likelihood, Adam, gathers), and
  with one epoch (the per-epoch cost).
* **Sizing** (``python -m benchmarks.bench_ppo --sizing``): control steps/s with learning of one
  iteration, measured as rollout + update, for several CPU-sized settings at control steps of 20 and
  5 ms, and two points vmapped in one program against the same two one after another.

``run(quick, smoke=False) -> dict``; ``python -m benchmarks.bench_ppo [--quick | --smoke]`` prints it.
Brax is needed for the Brax half only (``pip install -e '.[brax]'``); without it that half is
skipped with a note.
"""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
import statistics
import subprocess
import sys
import tempfile
import time

from benchmarks import subprocess_env

from nmrl import options

#: per-size settings: PPOConfig overrides shared by both contenders, native chunks timed per round,
#: rounds, timed calls per profile piece
SIZES = {
    "smoke": {"cfg": {"num_envs": 8, "batch_size": 8, "num_minibatches": 2, "unroll_s": 0.08}, "chunks": 1,
              "rounds": 1, "reps": 1},
    "quick": {"cfg": {"num_minibatches": 4}, "chunks": 1, "rounds": 2, "reps": 2},
    "full": {"cfg": {}, "chunks": 2, "rounds": 3, "reps": 2},
}
TINY = {"value_layers": 1, "value_width": 1}
TINY_BOTH = {**TINY, "policy_layers": 1, "policy_width": 1}


def _load() -> list[float]:
    return list(os.getloadavg()) if hasattr(os, "getloadavg") else []


def _compile(fn, *args):
    import jax

    t0 = time.perf_counter()
    c = jax.jit(fn).lower(*args).compile()
    return c, time.perf_counter() - t0


def _timed(fn, *args, reps: int = 1):
    """``(last output, [seconds per call])`` of ``reps`` calls (after one untimed call)."""
    import jax

    out = jax.block_until_ready(fn(*args))
    ts = []
    for _ in range(reps):
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn(*args))
        ts.append(time.perf_counter() - t0)
    return out, ts


def _physics(env, n: int, steps: int):
    """``(states, key) -> reward sum``: ``steps`` control steps of ``vmap(env.step)``, random actions."""
    import jax
    import jax.numpy as jnp

    def run(states, key):
        def body(carry, _):
            s, k = carry
            k, sub = jax.random.split(k)
            s = jax.vmap(env.step)(s, jax.random.normal(sub, (n, env.act_dim), jnp.float32))
            return (s, k), jnp.mean(s.reward)

        (_, _), r = jax.lax.scan(body, (states, key), None, length=steps)
        return r.sum()

    return run


def _with_nets(trainer, st, key):
    """``st`` with fresh parameters and Adam state for ``trainer``'s networks (the rollout's data and
    environments kept): lets the update of other network sizes run on the same iteration's data."""
    import optax

    from nmrl.learners import ppo_networks as nn_

    p, v = nn_.init_params(trainer.nets, key, trainer.env.obs_dim)
    return st.replace(policy=p, value=v, opt=optax.scale_by_adam().init({"policy": p, "value": v}))


def _learn_s(cfg, st, data, key, reps: int) -> dict:
    """Compile and time ``trainer.learn`` for ``cfg`` on ``data``."""
    from nmrl.learners.ppo import make_ppo

    tr = make_ppo(cfg)
    s = _with_nets(tr, st, key)
    fn, comp = _compile(tr.learn, s, data, key)
    _, ts = _timed(fn, s, data, key, reps=reps)
    return {"s": statistics.median(ts), "calls_s": ts, "compile_s": comp}


def profile(cfg, reps: int) -> dict:
    """Where one native iteration's time goes (module docstring): seconds per piece, medians."""
    import jax

    from nmrl.learners.ppo import make_ppo

    tr = make_ppo(cfg)
    c = tr.config
    n, steps = c.budget.num_envs, c.unrolls_per_env * c.unroll_length
    key = jax.random.PRNGKey(0)
    st = jax.jit(tr.init)(key)
    states = st.env
    phys, phys_c = _compile(_physics(tr.env, n, steps), states, key)
    _, phys_t = _timed(phys, states, key, reps=reps)
    roll, roll_c = _compile(tr.rollout, st, key)
    (_, data), roll_t = _timed(roll, st, key, reps=reps)
    learn = _learn_s(c, st, data, key, reps)
    tiny_v = _learn_s(options.replace(c, **TINY), st, data, key, reps)
    tiny_pv = _learn_s(options.replace(c, **TINY_BOTH), st, data, key, reps)
    one_epoch = _learn_s(dataclasses.replace(c, epochs=1), st, data, key, reps)
    r, p, u = statistics.median(roll_t), statistics.median(phys_t), learn["s"]
    it = r + u
    work = n * steps
    return {
        "control_steps_per_iteration": work,
        "seconds": {"physics_alone": p, "rollout": r, "policy_and_noise": r - p, "update": u,
                    "update_value_net": u - tiny_v["s"], "update_policy_net": tiny_v["s"] - tiny_pv["s"],
                    "update_rest": tiny_pv["s"], "update_one_epoch": one_epoch["s"],
                    "update_per_epoch": (u - one_epoch["s"]) / max(c.epochs - 1, 1)},
        "share_of_iteration": {"physics": p / it, "policy_and_noise": (r - p) / it,
                               "update_value_net": (u - tiny_v["s"]) / it,
                               "update_policy_net": (tiny_v["s"] - tiny_pv["s"]) / it,
                               "update_rest": tiny_pv["s"] / it},
        "control_steps_per_s": {"physics_alone": work / p, "rollout": work / r, "rollout_plus_update": work / it},
        "calls_s": {"physics_alone": phys_t, "rollout": roll_t, "update": learn["calls_s"],
                    "update_value_1x1": tiny_v["calls_s"], "update_both_1x1": tiny_pv["calls_s"],
                    "update_one_epoch": one_epoch["calls_s"]},
        "compile_s": {"physics_alone": phys_c, "rollout": roll_c, "update": learn["compile_s"],
                      "update_value_1x1": tiny_v["compile_s"], "update_both_1x1": tiny_pv["compile_s"],
                      "update_one_epoch": one_epoch["compile_s"]},
        "load_avg": _load(),
    }


class Native:
    """The native chunk (one iteration), compiled once; ``round()`` times ``chunks`` chunks."""

    def __init__(self, cfg, chunks: int):
        import jax

        from nmrl.learners.ppo import make_ppo

        self.tr = make_ppo(cfg)
        self.st = jax.jit(self.tr.init)(jax.random.PRNGKey(0))
        self.fn, self.compile_s = _compile(self.tr.chunk, self.st)
        self.chunks = chunks
        self.work = self.tr.config.budget.num_envs * self.tr.config.budget.chunk_steps

    def round(self) -> dict:
        import jax

        rates = []
        for _ in range(self.chunks):
            t0 = time.perf_counter()
            self.st, m = jax.block_until_ready(self.fn(self.st))
            rates.append(self.work / (time.perf_counter() - t0))
        return {"control_steps_per_s": statistics.median(rates), "per_chunk_steps_per_s": rates,
                "avg_reward": float(m["avg_reward"]), "load_avg": _load()}


def brax_round(cfg, timeout: float) -> dict:
    """``nmrl baseline ppo --devices 1`` for WARMUP + 1 iterations at ``cfg``'s batch settings."""
    from benchmarks.bench_baseline import WARMUP

    opts = ["--num-envs", str(cfg.budget.num_envs), "--batch-size", str(cfg.batch_size), "--num-minibatches",
            str(cfg.num_minibatches), "--unroll-length", str(cfg.unroll_length)]
    with tempfile.TemporaryDirectory(prefix="nmrl_bench_brax_") as tmp:
        out = pathlib.Path(tmp) / "ppo"
        t0 = time.perf_counter()
        try:
            p = subprocess.run([sys.executable, "-m", "nmrl.cli", "baseline", "ppo", "--out", str(out), "--devices",
                                "1", "--max-iterations", str(WARMUP + 1), "--quiet", *opts], env=subprocess_env(),
                               capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return {"error": f"timeout after {timeout:.0f} s"}
        if p.returncode:
            return {"error": f"exit status {p.returncode}: {p.stderr[-800:]}"}
        rows = [json.loads(x) for x in (out / "metrics.jsonl").read_text().splitlines()]
        rows = [r for r in rows if r["step"] > 0]
        rates = [r["steps_per_s"] for r in rows[WARMUP:]]
        steady = statistics.median(rates)
        spi = cfg.budget.num_envs * cfg.iteration_steps
        return {"control_steps_per_s": steady, "per_iteration_steps_per_s": [r["steps_per_s"] for r in rows],
                "compile_s": sum(r["wall_s"] for r in rows[:WARMUP]) - WARMUP * spi / steady,
                "avg_reward": rows[-1].get("train_reward_per_step"), "wall_s": time.perf_counter() - t0,
                "load_avg": _load()}


def run(quick: bool = False, smoke: bool = False) -> dict:
    from nmrl.adapters import brax_env
    from nmrl.learners.ppo_config import PPOConfig

    size = SIZES["smoke" if smoke else "quick" if quick else "full"]
    cfg = options.build(PPOConfig, **size["cfg"]).resolved()
    t0 = time.perf_counter()
    load0 = _load()
    native = Native(cfg, size["chunks"])
    runs: dict = {"native": [], "brax": []}
    ratios = []
    for _ in range(size["rounds"]):
        a = native.round()
        runs["native"].append(a)
        if brax_env.HAVE_BRAX:
            b = brax_round(cfg, 3600)
            runs["brax"].append(b)
            if "error" not in b:
                ratios.append(a["control_steps_per_s"] / b["control_steps_per_s"])
    prof = profile(cfg, size["reps"])
    med = lambda k: statistics.median([r["control_steps_per_s"] for r in runs[k] if "error" not in r] or [0])  # noqa: E731
    out = {
        "benchmark": "native PPO vs Brax PPO, control steps/s with learning at equal settings (one CPU device "
                     "each), and the native iteration's profile",
        "quick": quick, "smoke": smoke,
        "config": {k: getattr(cfg, k) for k in ("num_envs", "unroll_length", "batch_size", "num_minibatches",
                                                "epochs", "policy_layers", "policy_width", "value_layers",
                                                "value_width", "exploration", "control_dt")},
        "rounds": size["rounds"], "native_compile_s": native.compile_s, "runs": runs,
        "native_control_steps_per_s": med("native"),
        "brax_control_steps_per_s": med("brax") if ratios else None,
        "native_over_brax": statistics.median(ratios) if ratios else None,
        "profile": prof,
        "load_avg_at_start": load0, "load_avg_at_end": _load(), "wall_s": time.perf_counter() - t0,
    }
    if not brax_env.HAVE_BRAX:
        out["brax_skipped"] = "Brax is not installed (pip install -e '.[brax]'): the native half only"
    r = out["native_over_brax"]
    print(f"ppo: native / Brax control steps per s = {r:.2f}x" if r else "ppo: no Brax ratio",
          file=sys.stderr, flush=True)
    return out


# ----------------------------------------------------------------------------- sizing of the study

#: the update variants sized per control step (PPOConfig overrides on top of SIZING_BASE)
VARIANTS = {
    "p4x32_v5x256_e8": {},
    "p4x32_v2x128_e8": {"value_layers": 2, "value_width": 128},
    "p4x32_v2x64_e8": {"value_layers": 2, "value_width": 64},
    "p4x32_v2x64_e4": {"value_layers": 2, "value_width": 64, "epochs": 4},
    "p2x32_v2x64_e4": {"policy_layers": 2, "value_layers": 2, "value_width": 64, "epochs": 4},
}
#: one minibatch of 512 unrolls per epoch: every per-sample cost of the Brax settings (each sample
#: goes through both nets ``epochs`` times, minibatches of 512 unrolls), 1/32 of the iteration
SIZING_BASE = {"num_minibatches": 1}
COLORED_VARIANTS = ("p4x32_v2x64_e4",)


def sizing(dts=(0.02, 0.005), reps: int = 2, vmap_check: bool = True) -> dict:
    """Control steps/s with learning (rollout + update of one iteration, timed apart) per setting and
    control step, for white and colored exploration, plus 2 points vmapped vs one after another."""
    import jax

    from nmrl.learners.ppo import make_ppo
    from nmrl.learners.ppo_config import PPOConfig

    res: dict = {"load_avg_at_start": _load(), "settings": []}
    key = jax.random.PRNGKey(0)
    for dt in dts:
        for expl, names in (("white", tuple(VARIANTS)), ("colored", COLORED_VARIANTS)):
            base = options.build(PPOConfig, control_dt=dt, exploration=expl, **SIZING_BASE).resolved()
            tr = make_ppo(base)
            st = jax.jit(tr.init)(key)
            n, steps = base.budget.num_envs, base.iteration_steps
            row0 = {"control_dt": dt, "exploration": expl, "control_steps_per_iteration": n * steps}
            if expl == "white":
                phys, pc = _compile(_physics(tr.env, n, steps), st.env, key)
                _, pt = _timed(phys, st.env, key, reps=reps)
                res["settings"].append({**row0, "name": "physics_alone", "s": statistics.median(pt),
                                        "calls_s": pt, "compile_s": pc, "load_avg": _load()})
            roll, rc = _compile(tr.rollout, st, key)
            (_, data), rt = _timed(roll, st, key, reps=reps)
            r = statistics.median(rt)
            res["settings"].append({**row0, "name": "rollout_p4x32", "s": r, "calls_s": rt, "compile_s": rc,
                                    "load_avg": _load()})
            print(f"sizing dt={dt} {expl}: rollout {r:.1f} s", file=sys.stderr, flush=True)
            for name in names:
                cfg = options.replace(base, **VARIANTS[name])
                u = _learn_s(cfg, st, data, key, reps)
                work = n * steps
                res["settings"].append({**row0, "name": name, "rollout_s": r, "update_s": u["s"],
                                        "update_calls_s": u["calls_s"], "compile_s": u["compile_s"],
                                        "control_steps_per_s": work / (r + u["s"]),
                                        "simulated_s_per_wall_s": work * dt / (r + u["s"]), "load_avg": _load()})
                print(f"sizing dt={dt} {expl} {name}: update {u['s']:.1f} s, "
                      f"{work / (r + u['s']):,.0f} control steps/s", file=sys.stderr, flush=True)
    if vmap_check:
        res["vmap"] = vmap_two_points(reps)
    res["load_avg_at_end"] = _load()
    return res


def vmap_two_points(reps: int) -> dict:
    """One iteration (rollout then update) of 2 points vmapped in one program on one device, against
    the same iteration of one point called twice (20 ms, white, value 2x64, 4 epochs)."""
    import jax

    from nmrl.learners.ppo import make_ppo
    from nmrl.learners.ppo_config import PPOConfig

    cfg = options.build(PPOConfig, **SIZING_BASE, **VARIANTS["p4x32_v2x64_e4"]).resolved()
    tr = make_ppo(cfg)

    def it(st, key):
        k1, k2 = jax.random.split(key)
        (_, _, acc), data = tr.rollout(st, k1)
        params, _, _, _ = tr.learn(st, data, k2)
        return params, acc

    keys = jax.random.split(jax.random.PRNGKey(0), 2)
    sts = jax.jit(jax.vmap(tr.init))(keys)
    one_st = jax.tree.map(lambda a: a[0], sts)
    one, c1 = _compile(it, one_st, keys[0])
    two, c2 = _compile(jax.vmap(it), sts, keys)
    t_one, t_two = [], []
    jax.block_until_ready(one(one_st, keys[0]))
    jax.block_until_ready(two(sts, keys))
    for _ in range(reps):  # interleaved: 2 sequential single-point calls, then one vmapped call
        t0 = time.perf_counter()
        jax.block_until_ready(one(one_st, keys[0]))
        jax.block_until_ready(one(one_st, keys[1]))
        t_one.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        jax.block_until_ready(two(sts, keys))
        t_two.append(time.perf_counter() - t0)
    work = 2 * cfg.budget.num_envs * cfg.iteration_steps
    return {"setting": "20 ms, white, p4x32_v2x64_e4, one minibatch per epoch",
            "two_one_after_another_s": t_one, "two_vmapped_s": t_two,
            "control_steps_per_s_sequential": work / statistics.median(t_one),
            "control_steps_per_s_vmapped": work / statistics.median(t_two),
            "vmapped_over_sequential_speed": statistics.median(t_one) / statistics.median(t_two),
            "compile_s": {"one": c1, "vmapped": c2}, "load_avg": _load()}


if __name__ == "__main__":
    if "--sizing" in sys.argv:
        print(json.dumps(sizing(), indent=1, default=float))
    else:
        from benchmarks import main

        main(run)
