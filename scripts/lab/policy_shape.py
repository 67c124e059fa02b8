"""What carries a PPO policy's gait on the paper's robot: its mean, or its noise's state-dependent
scale? Each point's exploring policy (its own noise, k = 1) is rolled out as study 2's noise-scale
check rolls it (8 rollouts of 10 s from the endpoint's perturbed starts, nmrl/analysis/endpoint.py),
and along those states the policy's two heads are read apart:

* ``mean_action_sd``: the standard deviation over time of the deterministic action 20 tanh(mu(s_t))
  (per joint, then averaged over joints and rollouts): how much the mean moves the joints along
  the gait;
* ``noise_action_sd``: the same of a_t - 20 tanh(mu(s_t)), the part of the action the noise adds;
* ``std_mean``, ``std_cv``: the noise's scale sigma std_theta(s_t) (pre-squash) averaged over time,
  and its coefficient of variation over time (0: the scale does not depend on the state);
* ``std_speed_corr``: the correlation over time of the mean scale (over joints) with the trunk's
  forward speed a step later: a gait carried by the noise's scale shows it.

    python scripts/lab/policy_shape.py CELL_DIR [CELL_DIR ...] [--csv OUT.csv]

CELL_DIR is a study cell's directory (its ``points/*`` runs, e.g.
results/exploration2/runs/grid/dt0.02/nmp); PPO runs on the paper's robot only.
"""

from __future__ import annotations

import argparse
import pathlib

COLUMNS = ("cell", "point", "seed", "step", "forward_speed", "mean_action_sd", "noise_action_sd", "std_mean",
           "std_cv", "std_speed_corr")


def shape(point: pathlib.Path, seconds: float = 10.0, rollouts: int = 8, start_noise: float = 0.05) -> dict:
    """The module docstring's measures of one run's newest policy."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from nmrl import learners
    from nmrl.analysis import eval_env
    from nmrl.learners import ppo_networks as nn_
    from nmrl.runs import checkpoint

    meta, cfg, params = checkpoint.restore_params(point)
    cfg = cfg.resolved()
    env = eval_env.of_config(cfg)
    pol = learners.of(cfg).policy(cfg, env)
    nets = nn_.make_networks(cfg.policy_layers, cfg.policy_width, cfg.value_layers, cfg.value_width, env.act_dim,
                             cfg.learn_std)
    scale, _ = nn_.action_range(env)
    sigma = float(cfg.noise.spec().process(cfg.environment.control_dt).sigma)
    n_steps = int(round(seconds / cfg.environment.control_dt))

    def heads(obs):
        return nn_.mean_std(nets, params["policy"], nn_.normalize(params["obs_stats"], obs, cfg.normalize_obs),
                            cfg.min_std)

    def one(key):
        k_reset, k_start = jax.random.split(key)
        s = env.perturb(env.reset(k_reset), k_start, start_noise)
        eps = jax.random.normal(jax.random.fold_in(key, 1), (n_steps, env.act_dim), jnp.float32)

        def step(carry, e):
            s, ns = carry
            ns, xi = pol.noise_step(pol.noise_args, ns, e)
            mu, std = heads(s.obs)
            a = pol.act(params, s.obs, xi)
            s = env.step(s, a)
            return (s, ns), (scale * jnp.tanh(mu), a, sigma * std, s.metrics["forward_speed"])

        _, out = jax.lax.scan(step, (s, pol.noise_init(env.act_dim)), eps)
        return out

    keys = jax.random.split(jax.random.PRNGKey(0), rollouts)
    det, act, std, speed = (np.asarray(x, np.float64) for x in jax.jit(jax.vmap(one))(keys))
    scale_t = std.mean(axis=-1)  # (rollouts, T)
    corr = [np.corrcoef(scale_t[r, :-1], speed[r, 1:])[0, 1] for r in range(rollouts)]
    return {"point": point.name, "seed": int(cfg.budget.seed), "step": int(meta["step"]), "forward_speed": float(speed.mean()),
            "mean_action_sd": float(det.std(axis=1).mean()), "noise_action_sd": float((act - det).std(axis=1).mean()),
            "std_mean": float(std.mean()), "std_cv": float((std.std(axis=1) / std.mean(axis=1)).mean()),
            "std_speed_corr": float(np.nanmean(corr))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cells", nargs="+")
    ap.add_argument("--csv", default=None, help="also write the rows here")
    a = ap.parse_args()
    rows = []
    for c in map(pathlib.Path, a.cells):
        for p in sorted(q for q in (c / "points").glob("*/") if (q / "config.json").exists()):
            r = {"cell": str(c), **shape(p)}
            rows.append(r)
            print(f"{c} {r['point']}: {r['forward_speed']:.2f} m/s; mean action SD {r['mean_action_sd']:.2f}, noise "
                  f"{r['noise_action_sd']:.2f}; std {r['std_mean']:.2f} (CV {r['std_cv']:.2f}, corr with speed "
                  f"{r['std_speed_corr']:+.2f})", flush=True)
    if a.csv:
        from nmrl.runs import store

        store.write_csv(a.csv, COLUMNS, rows)


if __name__ == "__main__":
    main()
