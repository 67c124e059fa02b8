"""Cost of the exploration processes (nmrl.explore) per control step of 64 environments.

For every process (white, nm-periods, ou: K = 1; colored: the default K = 6) and n = 6 action
dimensions (the Half-Cheetah's), all jitted, compile (first call) apart from steady state:

* ``sample``: a ``lax.scan`` of T control steps of ``nmrl.explore.sample`` for 64 environments
  (draw, advance the latent state, filter belief and logp) -- what a rollout adds per step;
* ``log_prob``: ``vmap(log_prob)`` over the 64 environments' T-step fragments, and
  ``log_prob_grad``: its value and gradient in xi -- what a PPO update adds per sample;
* ``marginal`` (reference): the per-step marginal Gaussian log-density and its gradient, the
  density CN-PPO and pink-noise-rl use (it ignores the correlation).

Time per control step is reported relative to ``white`` measured in the same round; the contenders
run in interleaved rounds (white, nm-periods, ou, colored, white, ...) so that a background load
affects all alike, and the median over rounds is reported.

It also confirms that the paper's tridiagonal likelihood path (nmrl.paper.likelihood) stays >= 100x
faster than the dense solve at l = 1000, with bench_likelihood's contenders and timer.

    python -m benchmarks --only explore [--quick]
    python -m benchmarks.bench_explore [--quick]       # prints the JSON
"""

from __future__ import annotations

import os
import statistics
import time

from benchmarks import bench_likelihood  # sets OPENBLAS_NUM_THREADS before numpy / jax

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import nmrl.explore as ex  # noqa: E402

DT = 0.02
BATCH = 64
ACT = 6
PROCESSES = ("white", "nm-periods", "ou", "colored")
OPS = ("sample", "log_prob", "log_prob_grad")


def _block(x):
    return jax.tree_util.tree_map(lambda a: a.block_until_ready(), x)


def _contenders(T: int) -> dict:
    """{(process, op): (jitted fn, args)}, plus the marginal reference."""
    out = {}
    rng = np.random.default_rng(0)
    xi = jnp.asarray(rng.standard_normal((BATCH, T, ACT)), jnp.float32)
    keys = jax.random.split(jax.random.key(0), T)

    def rollout(proc, ns, keys):
        def step(ns, k):
            xi, logp, fresh, ns = ex.sample(proc, ns, k)
            return ns, (xi, logp, fresh)
        return jax.lax.scan(step, ns, keys)

    lp = jax.vmap(ex.log_prob, in_axes=(None, 0, 0, 0, 0))

    def lp_sum(proc, m, P, xi, fresh):
        return jnp.sum(lp(proc, m, P, xi, fresh))

    for name in PROCESSES:
        proc = ex.ExplorationSpec(name).process(DT)
        K = proc.phi.shape[0]
        ns = ex.init(proc, jax.random.key(1), BATCH, ACT)
        fresh = jnp.asarray(np.broadcast_to(np.arange(T) % min(int(proc.period), 10**9) == 0, (BATCH, T)))
        m0, P0 = jnp.zeros((BATCH, K, ACT)), jnp.broadcast_to(jnp.eye(K), (BATCH, K, K))
        out[(name, "sample")] = (jax.jit(rollout), (proc, ns, keys))
        out[(name, "log_prob")] = (jax.jit(lp), (proc, m0, P0, xi, fresh))
        out[(name, "log_prob_grad")] = (jax.jit(jax.value_and_grad(lp_sum, argnums=3)), (proc, m0, P0, xi, fresh))

    def marginal(sigma, xi):
        return jnp.sum(jax.scipy.stats.norm.logpdf(xi, 0.0, sigma))

    out[("marginal", "log_prob_grad")] = (jax.jit(jax.value_and_grad(marginal, argnums=1)), (jnp.float32(1.0), xi))
    return out


def _tridiagonal_vs_dense(rounds: int) -> dict:
    """bench_likelihood's tridiagonal and dense-solve contenders at l = 1000, alternated."""
    l = 1000
    rng = np.random.default_rng(1)
    u = jnp.asarray(rng.standard_normal((l, bench_likelihood.N_ACT)), jnp.float32)
    args = (u, jnp.float32(bench_likelihood.ALPHA), jnp.ones((bench_likelihood.N_ACT,), jnp.float32))
    runs: dict = {"tridiagonal": [], "dense_solve": []}
    for _ in range(rounds):
        for name, fn in (("tridiagonal", bench_likelihood.tridiagonal), ("dense_solve", bench_likelihood.dense_solve)):
            runs[name].append(bench_likelihood.time_jitted(fn, args, min_time=0.05, max_reps=50))
    med = {k: statistics.median(r["median_s"] for r in v) for k, v in runs.items()}
    ratio = med["dense_solve"] / med["tridiagonal"]
    return {"l": l, "n": bench_likelihood.N_ACT, "median_s": med,
            "compile_s": {k: v[0]["compile_s"] for k, v in runs.items()},
            "dense_over_tridiagonal": ratio, "goal": ">= 100x", "goal_met": ratio >= 100.0}


def run(quick: bool = False, smoke: bool = False) -> dict:
    """Time every (process, op) in interleaved rounds; ratios to white per round, medians reported.
    ``smoke``: the smallest setting (T = 10, one round), which only checks that everything runs."""
    T = 10 if smoke else 200 if quick else 1000
    rounds = 1 if smoke else 5 if quick else 15
    t_start = time.perf_counter()
    load = [list(os.getloadavg())]
    cont = _contenders(T)
    compile_s = {}
    for key, (f, args) in cont.items():
        t0 = time.perf_counter()
        _block(f(*args))
        compile_s[key] = time.perf_counter() - t0
    times: dict = {key: [] for key in cont}
    for _ in range(rounds):
        for key, (f, args) in cont.items():
            reps = []
            for _ in range(3):
                t0 = time.perf_counter()
                _block(f(*args))
                reps.append(time.perf_counter() - t0)
            times[key].append(min(reps))
    load.append(list(os.getloadavg()))
    results = []
    ratio: dict = {op: {} for op in OPS}
    for (name, op), ts in times.items():
        base = times.get(("white", op))
        per_round = [t / b for t, b in zip(ts, base)] if base else None
        med = statistics.median(ts)
        results.append({"process": name, "op": op, "K": 6 if name == "colored" else 1, "T": T, "batch": BATCH,
                        "act_dim": ACT, "compile_s": compile_s[(name, op)], "median_s": med,
                        "us_per_control_step": med / T * 1e6,
                        "ratio_to_white": statistics.median(per_round) if per_round else None})
        if per_round:
            ratio[op][name] = statistics.median(per_round)
        print(f"{name:11s} {op:14s} compile {compile_s[(name, op)]:6.2f} s   {med / T * 1e6:8.2f} us/step"
              f"{'' if not per_round else f'   {statistics.median(per_round):5.2f}x white'}", flush=True)
    marg = times[("marginal", "log_prob_grad")]
    ratio["colored_log_prob_grad_over_marginal"] = statistics.median(
        [a / b for a, b in zip(times[("colored", "log_prob_grad")], marg)])
    tri = _tridiagonal_vs_dense(1 if smoke else 3 if quick else 5)
    print(f"tridiagonal vs dense solve, l = 1000: {tri['dense_over_tridiagonal']:.0f}x", flush=True)
    return {
        "benchmark": "nmrl.explore: sampling and likelihood per control step of 64 environments, vs white",
        "quick": quick,
        "smoke": smoke,
        "config": {"control_dt": DT, "batch": BATCH, "act_dim": ACT, "T": T, "rounds": rounds,
                   "processes": {p: ex.ExplorationSpec(p).to_dict() for p in PROCESSES},
                   "statistic": "per round: best of 3 calls; reported: median over interleaved rounds",
                   "compile": "first call (trace + compile + one run), apart"},
        "machine": bench_likelihood.machine(),
        "results": results,
        "ratio_to_white": ratio,
        "tridiagonal_vs_dense": tri,
        "load_avg": load,
        "wall_s": time.perf_counter() - t_start,
    }


if __name__ == "__main__":
    from benchmarks import main

    main(run)
