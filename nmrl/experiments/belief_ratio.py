"""How far PPO's ratio at a fragment boundary is from the full conditional, for one update.

PPO's per-step density of a correlated process (docs/exploration.md, "What is conditioned on at a
rollout fragment's boundary") rebuilds an unroll's own noise under the current θ,
ξ_t(θ) = (x_t − μ_θ(s_t)) / σ_θ(s_t), and conditions its first steps on the filter belief stored at
the unroll's start, which the rollout computed from the trial's earlier noise under θ_old:

    (a)  log π_θ(x_t | ξ_<0(θ_old), ξ_0..t−1(θ))          what PPO's ratio uses,
    (b)  log π_θ(x_t | ξ_<t(θ))                             the full conditional, the trial's whole
                                                            noise rebuilt under θ.

Both equal log π_old at θ = θ_old. :func:`compare` measures them after one real update: it rolls
out one iteration under θ_old, runs PPO's update on it (θ_new, with the observation statistics the
update uses), and evaluates (a) per unroll from its stored belief and (b) over each environment's
unrolls joined in time order, starting from the first unroll's stored belief; (b) is the full
conditional only on the steps whose trial began inside the iteration (the filter restarts there),
so the statistics are over those steps of the second and later unrolls. Reported: the mean and
99th percentile of |(a) − (b)| per step, the same of the update's own log-ratio |(a) − log π_old|
for scale, and the share of steps whose clipping (|ratio − 1| > ε) differs between (a) and (b).
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np

from nmrl.learners.ppo import PPOState, make_ppo
from nmrl.learners.ppo_config import PPOConfig


def parts(cfg: PPOConfig, st: PPOState, key: jax.Array, env: Any = None) -> dict[str, np.ndarray]:
    """One iteration from ``st`` (θ_old) and its update: per environment and step (N, U T), the
    log-densities ``a``, ``b`` and ``old`` (log π_old), ``inside`` (the step's trial began in the
    iteration; the first unroll excluded), and the iteration's ``data`` with the update's ``policy``
    and observation ``stats``."""
    cfg = cfg.resolved()
    if cfg.noise.exploration not in ("ou", "colored"):
        raise ValueError(f"exploration={cfg.noise.exploration!r} is invalid: the comparison needs a process whose noise "
                         f"restarts only with a trial (ou, colored)")
    tr = make_ppo(cfg, env)
    k_roll, k_sgd = jax.random.split(key)
    _, data = tr.rollout(st, k_roll)  # (N, U, T, ...)
    params, _, stats, _ = tr.learn(st, data, k_sgd)
    proc, pol = st.hyper.process, params["policy"]
    N, U, T = data.reward.shape
    a = tr.seq_logp(pol, stats, data, proc).reshape(N, U * T)  # each unroll from its stored belief
    joined = lambda v: v.reshape((N, U * T) + v.shape[3:])  # noqa: E731
    whole = data._replace(obs=joined(data.obs), x=joined(data.x), fresh=joined(data.fresh),
                          mean0=data.mean0[:, 0], cov0=data.cov0[:, 0])  # each environment's unrolls in time order
    b = tr.seq_logp(pol, stats, whole, proc)
    inside = np.cumsum(np.asarray(joined(data.fresh)), axis=1) > 0  # the noise restarts only with a trial
    inside[:, :T] = False  # the first unroll: (a) and (b) are the same there
    return {"a": np.asarray(a, np.float64), "b": np.asarray(b, np.float64),
            "old": np.asarray(joined(data.logp), np.float64), "inside": inside,
            "data": data, "policy": pol, "stats": stats}


def compare(cfg: PPOConfig, st: PPOState, key: jax.Array, env: Any = None) -> dict:
    """The statistics of the module docstring for one update from ``st``."""
    p = parts(cfg, st, key, env)
    m = p["inside"]
    d = np.abs(p["a"] - p["b"])[m]
    own = np.abs(p["a"] - p["old"])[m]
    eps = float(cfg.clip_eps)
    clip_a = np.abs(np.exp(p["a"] - p["old"]) - 1.0) > eps
    clip_b = np.abs(np.exp(p["b"] - p["old"]) - 1.0) > eps
    return {"steps": int(m.sum()), "mean_abs_diff": float(d.mean()), "p99_abs_diff": float(np.quantile(d, 0.99)),
            "mean_abs_log_ratio": float(own.mean()), "p99_abs_log_ratio": float(np.quantile(own, 0.99)),
            "clip_differs": float(np.mean(clip_a[m] != clip_b[m]))}


def main(argv: list[str] | None = None) -> int:
    """``python -m nmrl.experiments.belief_ratio POINT [--key K]``: :func:`compare` for one update
    from a run's compact state (its environments start new trials), printed as JSON."""
    import argparse
    import json
    import pathlib

    from nmrl.runs import checkpoint, compact

    ap = argparse.ArgumentParser(prog="python -m nmrl.experiments.belief_ratio", description=main.__doc__)
    ap.add_argument("point", type=pathlib.Path, help="a PPO run directory with compact.npz (ou or colored)")
    ap.add_argument("--key", type=int, default=0, help="PRNG key of the iteration's rollout and update")
    a = ap.parse_args(argv)
    meta, cfg, _ = checkpoint.restore_params(a.point)
    if not isinstance(cfg, PPOConfig):
        ap.error(f"{a.point} is not a PPO run")
    st = compact.restore_compact(a.point, make_ppo(cfg))
    out = {"point": str(a.point), "step": int(meta.get("step", -1)), "exploration": cfg.noise.exploration,
           "control_dt": cfg.environment.control_dt, **compare(cfg, st, jax.random.PRNGKey(a.key))}
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
