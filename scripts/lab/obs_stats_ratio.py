"""How much of PPO's first-iteration approx_kl and clip fraction comes from the observation statistics?

PPO (nmrl/learners/ppo.py, as Brax) updates the running observation statistics with an iteration's
observations before its update, so the update's first minibatch already evaluates log pi_theta_old
through normalised inputs that differ from those the actions were sampled with. This script takes a
PPO run directory (its config and latest checkpoint), rolls out one iteration from the run's
initial state and one from its checkpoint, and evaluates the batch's log-density at the *unchanged*
policy parameters twice: with the statistics the rollout used and with those after the update's
statistics step. It prints, for each, approx_kl = mean(rho - 1 - log rho), the share of ratios
outside [1 - eps, 1 + eps] and mean |log rho|; with the sampling statistics all three are 0 up to
float rounding (the recorded log-density is recomputed), so what remains with the updated statistics
is the statistics' share alone, before any gradient step.

    .venv/bin/python scripts/lab/obs_stats_ratio.py RUN_DIR [--key 7]
"""

from __future__ import annotations

import argparse
import json

import jax
import numpy as np

from nmrl.learners import ppo_networks
from nmrl.learners.ppo import make_ppo
from nmrl.learners.ppo_config import PPOConfig
from nmrl.runs import checkpoint


def statistics_share(tr, st, key: jax.Array, clip_eps: float) -> dict:
    """The three numbers of the module docstring for one iteration's rollout from ``st``."""
    _, data = tr.rollout(st, key)
    updated = ppo_networks.obs_update(st.obs_stats, data.obs, lambda x: x)
    out = {}
    for name, stats in (("stats_at_sampling", st.obs_stats), ("stats_after_update", updated)):
        log_rho = np.asarray(tr.seq_logp(st.policy, stats, data, st.hyper.process) - data.logp, np.float64)
        rho = np.exp(log_rho)
        out[name] = {"approx_kl": float(np.mean(rho - 1.0 - log_rho)),
                     "clip_frac": float(np.mean(np.abs(rho - 1.0) > clip_eps)),
                     "mean_abs_log_ratio": float(np.mean(np.abs(log_rho)))}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", help="a PPO run directory with a checkpoint")
    ap.add_argument("--key", type=int, default=7, help="PRNG key of both rollouts")
    a = ap.parse_args(argv)
    meta, cfg, _ = checkpoint.restore_params(a.run)
    if not isinstance(cfg, PPOConfig):
        ap.error(f"{a.run} is not a PPO run")
    tr = make_ppo(cfg)
    key = jax.random.PRNGKey(a.key)
    first = statistics_share(tr, tr.init(jax.random.PRNGKey(cfg.budget.seed)), key, float(cfg.clip_eps))
    later = statistics_share(tr, checkpoint.restore(a.run, tr), key, float(cfg.clip_eps))
    print(json.dumps({"run": a.run, "first_iteration": first, f"after_step_{int(meta.get('step', -1))}": later}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
