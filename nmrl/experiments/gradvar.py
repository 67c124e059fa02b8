"""Variance of the actor's gradient estimate per nm-period (the quantity behind eq. (1)).

For a fixed policy theta and critic v (no learning: beta = 0), every completed period k of every
environment gives the actor's gradient estimate of Table II without traces,

    g_k = d_k * grad_theta ln pi_Ahat(Ahat_k; S_k, theta),     d_k = r_bar_k + gamma^l V(s') - V(s),

(eq. (7) with Delta-sampling; nmrl/learners/ac_train.py accumulates sum_k g_k and sum_k |g_k|^2 when
``grad_stats`` is on). From n periods this module reports

* ``trcov``: tr Cov(g_k), the total variance of one period's estimate (unbiased, n - 1);
* ``mean_sq``: |E g_k|^2, the squared norm of its mean, unbiased (|g_bar|^2 - trcov / n);
* ``snr_per_s``: the signal-to-noise ratio of the sum of the estimates over one simulated second of
  one environment, (1/T) |E g|^2 / trcov for periods of T seconds (periods treated as independent).

Eq. (1) is the reason to look: with white noise (l = 1) at a finer control step delta, one action's
perturbation changes the trajectory, and hence d_k, less and less while the number of estimates
per second grows, so the signal per second need not grow with them. nm-periods of a fixed
duration keep the perturbation per period the same at every delta.

Standard errors come from independent batches (chunks): every batch gives its own trcov, and the
95% interval is the t-interval over batches.
"""

from __future__ import annotations

from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from nmrl import learners, options
from nmrl.learners.ac_config import Hyper, TrainConfig
from nmrl.analysis.stats import mean_ci95
from nmrl.runs.points import stack_trees


def summarize(n: np.ndarray, g_sum: np.ndarray, g_sqnorm: np.ndarray, period_s: float) -> dict:
    """Statistics of g_k from per-batch sums: ``n[b]`` periods, ``g_sum[b]`` = sum g_k (a vector),
    ``g_sqnorm[b]`` = sum |g_k|^2. Returns trcov, mean_sq, snr_per_s with 95% half-widths over batches.
    """
    n = np.asarray(n, np.float64)
    g_sum = np.asarray(g_sum, np.float64)
    g_sqnorm = np.asarray(g_sqnorm, np.float64)
    if n.ndim != 1 or g_sum.shape[0] != n.shape[0] or g_sqnorm.shape != n.shape:
        raise ValueError(f"inconsistent batch sums: n {n.shape}, g_sum {g_sum.shape}, g_sqnorm {g_sqnorm.shape}")
    if np.any(n < 2):
        raise ValueError(f"every batch needs at least 2 periods, got counts {n.tolist()}")

    def stats(nn, gs, gq):
        trcov = (gq - np.sum(gs * gs, axis=-1) / nn) / (nn - 1)
        mean_sq = np.sum(gs * gs, axis=-1) / nn**2 - trcov / nn
        return trcov, mean_sq

    tot_trcov, tot_mean_sq = stats(n.sum(), g_sum.sum(0), g_sqnorm.sum())
    b_trcov, b_mean_sq = stats(n, g_sum, g_sqnorm)
    B = len(n)
    half = lambda x: mean_ci95(x)[1] if B > 1 else float("nan")  # noqa: E731
    return {
        "periods": int(n.sum()),
        "batches": B,
        "trcov": float(tot_trcov),
        "trcov_ci": half(b_trcov),
        "mean_sq": float(tot_mean_sq),
        "mean_sq_ci": half(b_mean_sq),
        "snr_per_s": float(tot_mean_sq / (tot_trcov * period_s)),
    }


def measure(configs: Sequence[TrainConfig], policies: Sequence[tuple], *, batches: int, seed: int = 0,
            warmup: int = 1) -> list[dict]:
    """Run every config (the same program, differing in Hyper fields only) with the given
    ``(theta, v)`` for ``warmup`` + ``batches`` chunks without learning (the warm-up chunks, where
    all environments start together from the reset pose, are not counted); returns per-batch sums
    per point.

    ``configs[i]`` is paired with ``policies[i]``. Step sizes are forced to 0 and ``grad_stats`` on.
    """
    if len(configs) != len(policies) or not configs:
        raise ValueError(f"need one policy per config, got {len(policies)} policies for {len(configs)} configs")
    if not (isinstance(batches, int) and batches >= 2):
        raise ValueError(f"batches={batches!r} is invalid: need an integer >= 2 for an interval")
    cfgs = [options.replace(c, beta_theta=0.0, beta_v=0.0, grad_stats=True, steps=None, trials=None)
            .resolved() for c in configs]
    trainer = learners.get("ac").make(cfgs[0])  # with the run's environment (its --env)
    keys = jnp.stack([jax.random.PRNGKey(seed + i) for i in range(len(cfgs))])
    ts = jax.jit(jax.vmap(trainer.init))(keys, stack_trees([Hyper.from_config(c) for c in cfgs]))
    f32 = lambda t: jax.tree.map(lambda a: jnp.asarray(a, jnp.float32), t)  # noqa: E731
    ts = jax.device_put(ts.replace(theta=stack_trees([f32(p[0]) for p in policies]),
                                   v=stack_trees([f32(p[1]) for p in policies])))
    chunk = jax.jit(jax.vmap(trainer.chunk))
    sums = [{"n": [], "g_sum": [], "g_sqnorm": []} for _ in cfgs]
    for b in range(warmup + batches):
        ts, m = chunk(ts)
        if b < warmup:
            continue
        m = jax.device_get(m)
        for i in range(len(cfgs)):
            sums[i]["n"].append(int(m["periods_in_chunk"][i]))
            sums[i]["g_sum"].append(np.asarray(m["g_sum"][i], np.float64))
            sums[i]["g_sqnorm"].append(float(m["g_sqnorm"][i]))
    return sums


__all__ = ("summarize", "measure")
