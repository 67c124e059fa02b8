"""The PPO learner (nmrl/learners/ppo.py) against independent computations.

* GAE with truncation and termination, and the whole minibatch loss (networks, white-noise density,
  clipped surrogate, value loss, entropy) against plain NumPy in float64;
* at theta = theta_old the ratio is 1 for data the rollout produced, and the clipped objective's
  gradient equals the unclipped one;
* the ratio's exact conditional likelihood of a correlated process (period resets, a trial reset, a
  learned state-dependent std, a belief carried over an unroll boundary) against the dense Gaussian
  density of the same actions (scipy, float64);
* minibatches are whole unrolls (a flat shuffle over steps fails the test), each once per epoch;
* a chunk under vmap over two points with different traced hyperparameters equals each point alone;
* the defaults at 0.02 s are the Brax baseline's config, and the conversions in seconds hold at 5 ms.
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats

from nmrl import explore, options
from nmrl.learners import contract, ppo, ppo_config
from nmrl.learners import ppo_losses as L
from nmrl.learners import ppo_networks as nn_

try:  # pytest puts tests/ on sys.path (rootdir-relative "prepend" import mode)
    from tiny_env import TinyEnv
except ImportError:  # imported as the package "tests"
    from tests.tiny_env import TinyEnv

REPO = pathlib.Path(__file__).resolve().parents[1]
TINY = dict(num_envs=2, batch_size=4, num_minibatches=2, epochs=2, unroll_s=0.1, policy_layers=2, policy_width=8,
            value_layers=2, value_width=8)  # T = 5 steps, U = 4 unrolls per environment


def _np_mlp(params, x):
    """Brax's MLP in NumPy float64: swish between Dense layers, linear output."""
    layers = sorted(params["params"], key=lambda k: int(k.split("_")[1]))
    for i, name in enumerate(layers):
        p = params["params"][name]
        x = x @ np.asarray(p["kernel"], np.float64) + np.asarray(p["bias"], np.float64)
        if i < len(layers) - 1:
            x = x / (1.0 + np.exp(-x))
    return x


def _np_gae(r, v, boot, term, trunc, gamma, lam):
    """Brax's GAE, one sequence at a time by its definition: the lambda-return advantage A' over the
    trial's steps (zero and a cut trace at a truncation, a zero next value and a cut trace at a
    termination), vs = V + A', and the advantage r + gamma vs_{t+1} - V."""
    T, B = r.shape
    vs, adv = np.zeros((T, B)), np.zeros((T, B))
    for b in range(B):
        a_next = 0.0
        lam_adv = np.zeros(T)
        for t in reversed(range(T)):
            v_next = boot[b] if t == T - 1 else v[t + 1, b]
            if trunc[t, b]:
                lam_adv[t], a_next = 0.0, 0.0
                continue
            c = 0.0 if term[t, b] else 1.0
            delta = r[t, b] + gamma * c * v_next - v[t, b]
            lam_adv[t] = delta + gamma * lam * c * a_next
            a_next = lam_adv[t]
        vs[:, b] = lam_adv + v[:, b]
        for t in range(T):
            if trunc[t, b]:
                continue
            c = 0.0 if term[t, b] else 1.0
            vs_next = boot[b] if t == T - 1 else vs[t + 1, b]
            adv[t, b] = r[t, b] + gamma * c * vs_next - v[t, b]
    return vs, adv


def _flags(rng, T, B):
    term = rng.random((T, B)) < 0.1
    trunc = (rng.random((T, B)) < 0.15) & ~term
    trunc[2, 0], term[4, 1] = True, True  # at least one of each
    return term, trunc


def test_gae_matches_numpy_with_truncation_and_termination():
    rng = np.random.default_rng(0)
    T, B = 9, 4
    r, v, boot = rng.normal(size=(T, B)), rng.normal(size=(T, B)), rng.normal(size=B)
    term, trunc = _flags(rng, T, B)
    want_vs, want_adv = _np_gae(r, v, boot, term, trunc, 0.9, 0.8)
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    vs, adv = L.gae(f32(r), f32(v), f32(boot), f32(term), f32(trunc), jnp.float32(0.9), jnp.float32(0.8))
    np.testing.assert_allclose(np.asarray(vs), want_vs, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.asarray(adv), want_adv, rtol=1e-5, atol=1e-5)
    assert np.all(np.asarray(adv)[trunc] == 0)


def _random_batch(rng, cfg, B, obs_dim, act_dim, K=1):
    T = cfg.unroll_length
    term, trunc = _flags(rng, T, B)
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    return ppo.Batch(obs=f32(rng.normal(size=(B, T, obs_dim))), x=f32(rng.normal(size=(B, T, act_dim))),
                     logp=f32(rng.normal(size=(B, T)) - 2.0), fresh=jnp.ones((B, T), bool),
                     reward=f32(rng.normal(size=(B, T))), termination=f32(term.T), truncation=f32(trunc.T),
                     next_obs=f32(rng.normal(size=(B, obs_dim))), mean0=jnp.zeros((B, K, act_dim), jnp.float32),
                     cov0=jnp.broadcast_to(jnp.eye(K, dtype=jnp.float32), (B, K, K)))


def test_minibatch_loss_matches_numpy():
    """The whole loss of one minibatch (white noise, learned std, tanh, normalised observations and
    advantages) against a float64 NumPy implementation of Brax's compute_ppo_loss."""
    cfg = options.build(ppo_config.PPOConfig, **TINY, exploration="white", sigma=0.8, entropy_cost=0.01, clip_eps=0.2,
                               reward_scale=0.5, discount_horizon_s=0.1, gae_horizon_s=0.05, control_dt=0.02)
    env = TinyEnv()
    tr = ppo.make_ppo(cfg, env)
    st = tr.init(jax.random.PRNGKey(1))
    rng = np.random.default_rng(1)
    B, T, n = 6, cfg.unroll_length, env.act_dim
    b = _random_batch(rng, cfg, B, env.obs_dim, n)
    stats = nn_.ObsStats(count=jnp.float32(10.0), mean=jnp.asarray(rng.normal(size=3), jnp.float32),
                         summed_var=jnp.ones(3, jnp.float32), std=jnp.asarray([0.5, 1.5, 2.0], jnp.float32))
    eps = jnp.asarray(rng.normal(size=(B, T, n)), jnp.float32)
    params = {"policy": st.policy, "value": st.value}
    h = st.hyper
    total, sums = tr.loss(params, stats, b, h, eps, float(B * T))

    d = lambda a: np.asarray(a, np.float64)  # noqa: E731
    obs_n = (d(b.obs) - d(stats.mean)) / d(stats.std)
    out = _np_mlp(st.policy, obs_n)
    mu, raw = out[..., :n], out[..., n:]
    std = np.log1p(np.exp(raw)) + cfg.min_std
    s = cfg.noise.sigma * std
    logp = np.sum(scipy.stats.norm.logpdf(d(b.x), mu, s), axis=-1)
    values = _np_mlp(st.value, obs_n)[..., 0]
    boot = _np_mlp(st.value, (d(b.next_obs) - d(stats.mean)) / d(stats.std))[..., 0]
    gamma, lam = math.exp(-0.02 / 0.1), math.exp(-0.02 / 0.05)
    vs, adv = _np_gae(cfg.reward_scale * d(b.reward).T, values.T, boot, d(b.termination).T > 0,
                      d(b.truncation).T > 0, gamma, lam)
    vs, adv = vs.T, adv.T
    adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    rho = np.exp(logp - d(b.logp))
    pl = -np.minimum(rho * adv, np.clip(rho, 0.8, 1.2) * adv)
    vl = 0.5 * cfg.vf_coef * (vs - values) ** 2
    xs = mu + s * d(eps)
    ent = np.sum(0.5 + 0.5 * np.log(2 * np.pi) + np.log(s) + np.log(1 - np.tanh(xs) ** 2), axis=-1)
    want = (pl.sum() + vl.sum() - cfg.entropy_cost * ent.sum()) / (B * T)
    np.testing.assert_allclose(float(total), want, rtol=2e-4)
    np.testing.assert_allclose(float(sums["policy_loss"]), pl.sum(), rtol=2e-4, atol=1e-4)
    np.testing.assert_allclose(float(sums["value_loss"]), vl.sum(), rtol=2e-4)
    np.testing.assert_allclose(float(sums["entropy"]), ent.sum(), rtol=2e-4)
    np.testing.assert_allclose(float(sums["clip_frac"]), np.sum(np.abs(rho - 1) > 0.2), atol=0.5)


def _nm_cfg(**kw):
    base = dict(TINY, exploration="nm-periods", sigma=0.7, period_s=0.12, corr_time_s=0.05)
    base.update(kw)
    return options.build(ppo_config.PPOConfig, **base)


@pytest.fixture(scope="module")
def nm_trainer():
    """Tiny trainer with a correlated process (period 6 steps, phi = exp(-0.4)) on the tiny env."""
    return ppo.make_ppo(_nm_cfg(), TinyEnv(stop_prob=0.1))


def test_ratio_is_one_and_clipped_gradient_is_unclipped_at_theta_old(nm_trainer):
    tr = nm_trainer
    st = tr.init(jax.random.PRNGKey(3))
    (_, _, _), data = jax.jit(tr.rollout)(st, jax.random.PRNGKey(4))
    assert bool(jnp.any(data.fresh[:, :, 1:])) and bool(jnp.any(~data.fresh))  # resets inside unrolls
    # the rollout's own log-densities are the exact conditional ones of the update, at theta_old
    lp = tr.seq_logp(st.policy, st.obs_stats, data, st.hyper.process)
    np.testing.assert_allclose(np.asarray(lp), np.asarray(data.logp), atol=2e-5, rtol=1e-5)
    mb = jax.tree.map(lambda a: a[0], tr.minibatches(data, jax.random.PRNGKey(5)))
    params = {"policy": st.policy, "value": st.value}
    eps = jnp.zeros(mb.x.shape, jnp.float32)
    h0 = st.hyper._replace(entropy_cost=jnp.float32(0.0), vf_coef=jnp.float32(1e-30))
    g_clip = jax.grad(lambda p: tr.loss(p, st.obs_stats, mb, h0, eps)[0])(params)["policy"]
    g_free = jax.grad(lambda p: tr.loss(p, st.obs_stats, mb, h0._replace(clip_eps=jnp.float32(1e9)), eps)[0])(
        params)["policy"]
    flat = lambda t: np.concatenate([np.ravel(x) for x in jax.tree.leaves(t)])  # noqa: E731
    assert np.linalg.norm(flat(g_free)) > 0
    np.testing.assert_allclose(flat(g_clip), flat(g_free), rtol=1e-6, atol=1e-9)


def test_exact_likelihood_ratio_matches_dense_gaussian(nm_trainer):
    """Two unrolls of one environment: the actions of the second under theta != theta_old,
    conditioned on the first's noise (stored belief), against the dense Gaussian of (5)/(7)."""
    tr = nm_trainer
    cfg = tr.config
    T, n = cfg.unroll_length, 2
    proc = cfg.noise.spec().process(cfg.environment.control_dt)
    phi, sigma, period = float(proc.phi[0]), float(proc.sigma), int(proc.period)
    assert (T, period) == (5, 6)
    rng = np.random.default_rng(7)
    obs = jnp.asarray(rng.normal(size=(2 * T, 3)), jnp.float32)
    stats = nn_.obs_init(3)
    old = tr.init(jax.random.PRNGKey(8)).policy
    new = jax.tree.map(lambda p: p + 0.3 * jnp.asarray(rng.normal(size=p.shape), jnp.float32), old)
    # the behaviour: the process's own sampler, a trial ended after step 7
    ns = explore.init(proc, jax.random.PRNGKey(9), 1, n)
    xis, fresh, beliefs = [], [], []
    for t in range(2 * T):
        if t == T:
            beliefs.append(explore.belief(ns))
        xi, _, fr, ns = explore.sample(proc, ns, jax.random.PRNGKey(100 + t))
        if t == 7:
            ns = explore.reset(proc, ns, jnp.array([True]))
        xis.append(np.asarray(xi[0])), fresh.append(bool(fr[0]))
    xis = np.array(xis)
    assert fresh == [True, False, False, False, False, False, True, False, True, False]
    mu_o, std_o = nn_.mean_std(tr.nets, old, obs, cfg.min_std)
    x = np.asarray(mu_o) + np.asarray(std_o) * xis  # x = mu_old + std_old * xi (eq. (6), learned scale)
    mean0, cov0, _ = beliefs[0]
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    b2 = ppo.Batch(obs=obs[None, T:], x=f32(x[None, T:]), logp=jnp.zeros((1, T)), fresh=jnp.asarray([fresh[T:]]),
                   reward=jnp.zeros((1, T)), termination=jnp.zeros((1, T)), truncation=jnp.zeros((1, T)),
                   next_obs=obs[None, 0], mean0=mean0, cov0=cov0)

    # dense reference: xi over the 10 steps, cov sigma^2 phi^|t-s| within a segment, 0 across
    seg = np.cumsum(fresh)
    C = np.array([[sigma**2 * phi ** abs(t - s) if seg[t] == seg[s] else 0.0 for s in range(2 * T)]
                  for t in range(2 * T)])
    C11, C12, C22 = C[:T, :T], C[:T, T:], C[T:, T:]
    Km = np.linalg.solve(C11, C12).T  # (T, T): E[xi2 | xi1] = Km xi1 (per action dimension)
    Cc = C22 - C12.T @ np.linalg.solve(C11, C12)

    def dense_logp(params, upto):
        mu, std = (np.asarray(a, np.float64) for a in nn_.mean_std(tr.nets, params, obs, cfg.min_std))
        xi1 = (x[:T] - np.asarray(mu_o[:T], np.float64)) / np.asarray(std_o[:T], np.float64)  # rollout's xi
        m = mu[T:T + upto] + std[T:T + upto] * (Km @ xi1)[:upto]
        total = 0.0
        for j in range(n):
            S = np.diag(std[T:T + upto, j])
            total += scipy.stats.multivariate_normal(m[:, j], S @ Cc[:upto, :upto] @ S).logpdf(x[T:T + upto, j])
        return total

    for params in (old, new):
        lp = np.asarray(tr.seq_logp(params, stats, b2, proc))[0]
        for upto in range(1, T + 1):  # every prefix: each per-step term is the exact conditional
            np.testing.assert_allclose(lp[:upto].sum(), dense_logp(params, upto), rtol=1e-4, atol=1e-3)
    ratio = np.exp(np.sum(np.asarray(tr.seq_logp(new, stats, b2, proc)) - np.asarray(tr.seq_logp(old, stats, b2, proc))))
    want = np.exp(dense_logp(new, T) - dense_logp(old, T))
    np.testing.assert_allclose(ratio, want, rtol=2e-3)
    assert abs(math.log(want)) > 0.5  # theta moved far enough for the ratio to mean something


def test_minibatches_are_whole_unrolls_each_once_per_epoch():
    cfg = options.build(ppo_config.PPOConfig, num_envs=2, batch_size=4, num_minibatches=3, epochs=1, unroll_s=0.08, policy_layers=1,
                               policy_width=4, value_layers=1, value_width=4)
    tr = ppo.make_ppo(cfg, TinyEnv())
    N, U, T = 2, cfg.unrolls_per_env, cfg.unroll_length
    assert (U, T) == (6, 4)
    e, u, t = np.meshgrid(np.arange(N), np.arange(U), np.arange(T), indexing="ij")
    code = (1000 * e + 10 * u + t).astype(np.float32)  # (N, U, T): which step of which unroll
    z = lambda *s: jnp.zeros(s, jnp.float32)  # noqa: E731
    data = ppo.Batch(obs=jnp.asarray(np.repeat(code[..., None], 3, -1)), x=z(N, U, T, 2), logp=z(N, U, T),
                     fresh=jnp.zeros((N, U, T), bool), reward=jnp.asarray(code), termination=z(N, U, T),
                     truncation=z(N, U, T), next_obs=jnp.asarray(code[:, :, -1:].repeat(3, -1) + 1),
                     mean0=z(N, U, 1, 2), cov0=z(N, U, 1, 1))
    mbs = np.asarray(tr.minibatches(data, jax.random.PRNGKey(0)).reward)  # (M, batch, T)
    assert mbs.shape == (3, 4, T)
    seen = []
    for m in range(3):
        per_env = [0, 0]
        for row in mbs[m]:
            env, unr = int(row[0]) // 1000, (int(row[0]) % 1000) // 10
            np.testing.assert_array_equal(row, code[env, unr])  # the whole unroll, in order
            per_env[env] += 1
            seen.append((env, unr))
        assert per_env == [2, 2]
    assert sorted(seen) == [(a, b) for a in range(N) for b in range(U)]
    # the stored per-unroll fields travel with their unroll
    nxt = np.asarray(tr.minibatches(data, jax.random.PRNGKey(0)).next_obs)[..., 0]
    np.testing.assert_array_equal(nxt, mbs[..., -1] + 1)
    # and the permutation changes with the key (a shuffle, not a fixed split)
    other = np.asarray(tr.minibatches(data, jax.random.PRNGKey(1)).reward)
    assert not np.array_equal(other, mbs)


def test_chunk_vmap_over_points_equals_each_point_alone():
    env = TinyEnv(stop_prob=0.1)
    cfgs = [_nm_cfg(learning_rate=1e-3, entropy_cost=1e-3, clip_eps=0.3, discount_horizon_s=0.4, sigma=0.7),
            _nm_cfg(learning_rate=3e-3, entropy_cost=1e-2, clip_eps=0.1, discount_horizon_s=0.2, sigma=1.3,
                    corr_time_s=0.2, period_s=0.3, gae_horizon_s=0.1, seed=1)]
    assert contract.program_key(cfgs[0]) == contract.program_key(cfgs[1])
    tr = ppo.make_ppo(cfgs[0], env)
    states = [tr.init(jax.random.PRNGKey(c.budget.seed), ppo_config.Hyper.from_config(c.resolved())) for c in cfgs]
    chunk = jax.jit(tr.chunk)
    alone = [chunk(s) for s in states]
    both_s, both_m = jax.jit(jax.vmap(tr.chunk))(jax.tree.map(lambda *a: jnp.stack(a), *states))
    for i, (s1, m1) in enumerate(alone):
        assert float(m1["updates_in_chunk"]) == 2 * 2
        for a, b in zip(jax.tree.leaves((s1.policy, s1.value, s1.opt, s1.obs_stats, s1.noise)),
                        jax.tree.leaves(jax.tree.map(lambda a: a[i], (both_s.policy, both_s.value, both_s.opt,
                                                                      both_s.obs_stats, both_s.noise)))):
            np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-5, atol=1e-6)
        for k, v in m1.items():
            np.testing.assert_allclose(np.asarray(both_m[k][i]), np.asarray(v), rtol=1e-4, atol=1e-6, err_msg=k)
    assert not np.allclose(np.asarray(alone[0][1]["avg_reward"]), np.asarray(alone[1][1]["avg_reward"]))


def test_defaults_are_the_brax_baseline_and_times_are_in_seconds():
    base = json.loads((REPO / "results/baseline_ppo/ppo_s0/config.json").read_text())
    c = ppo_config.PPOConfig().resolved()
    h = ppo_config.Hyper.from_config(c)
    assert (c.unroll_length, c.batch_size, c.num_minibatches, c.epochs, c.budget.num_envs) == (
        base["unroll_length"], base["batch_size"], base["num_minibatches"], base["num_updates_per_batch"],
        base["num_envs"])
    assert (c.learning_rate, c.entropy_cost, c.reward_scale, c.normalize_obs) == (
        base["learning_rate"], base["entropy_cost"], base["reward_scaling"], base["normalize_observations"])
    assert ((c.policy_width,) * c.policy_layers, (c.value_width,) * c.value_layers) == (
        tuple(base["policy_hidden"]), tuple(base["value_hidden"]))
    assert (c.environment.control_dt, c.environment.stop_prob) == (base["control_dt"], base["stop_prob"])
    assert float(h.gamma) == np.float32(base["discounting"]) and float(h.lam) == np.float32(0.95)
    assert c.iteration_steps * c.budget.num_envs == base["batch_size"] * base["num_minibatches"] * base["unroll_length"]
    assert nn_.ACTION_SCALE == 20.0 and c.noise.exploration == "white"
    # 5 ms: the same seconds, 4x the steps; the discount per second unchanged
    f = options.build(ppo_config.PPOConfig, control_dt=0.005).resolved()
    hf = ppo_config.Hyper.from_config(f)
    assert f.unroll_length == 80 and f.iteration_steps == 4 * c.iteration_steps
    np.testing.assert_allclose(float(hf.gamma) ** 4, 0.95, rtol=1e-6)
    nm = options.build(ppo_config.PPOConfig, exploration="nm-periods", control_dt=0.005).resolved()
    assert int(ppo_config.Hyper.from_config(nm).process.period) == 40  # 0.2 s


@pytest.mark.parametrize("kw, name", [
    (dict(unroll_s=0.01), "unroll_s"), (dict(discount_horizon_s=0.0), "discount_horizon_s"),
    (dict(gae_horizon_s=float("nan")), "gae_horizon_s"), (dict(exploration="pink"), "exploration"),
    (dict(num_envs=48), "num_envs"), (dict(chunk_steps=1000), "chunk_steps"), (dict(squash="sigmoid"), "squash"),
    (dict(exploration="nm-periods", period_s=0.01), "period_s"), (dict(learning_rate=-1.0), "learning_rate"),
    (dict(steps=10, trials=10), "budget"),
])
def test_bad_config_names_the_value(kw, name):
    with pytest.raises(ValueError, match=name):
        options.build(ppo_config.PPOConfig, **kw).resolved()


def test_registered_and_config_round_trips():
    lr = contract.get("ppo")
    c = options.build(ppo_config.PPOConfig, exploration="ou", corr_time_s=0.3, seed=4).resolved()
    assert contract.of(c) is lr and contract.config_from_dict(json.loads(json.dumps(contract.config_dict(c)))) == c
    assert set(lr.policy_fields) <= set(lr.compact_fields)
    assert {f.name for f in dataclasses.fields(ppo.PPOState)} >= {"step", "trials", "diverged", "key", "hyper",
                                                                   *lr.env_fields, *lr.compact_fields}
    assert set(lr.hyper_fields) <= set(options.leaves(ppo_config.PPOConfig))


def test_deterministic_policy_is_the_squashed_mean(nm_trainer):
    tr = nm_trainer
    st = tr.init(jax.random.PRNGKey(2))
    stats = nn_.ObsStats(count=jnp.float32(5), mean=jnp.ones(3), summed_var=jnp.ones(3), std=2 * jnp.ones(3))
    pol = ppo.policy(tr.config, tr.env)
    obs = jnp.asarray([0.3, -1.0, 2.0], jnp.float32)
    a = pol.act({"policy": st.policy, "obs_stats": stats}, obs, jnp.zeros(2))
    out = _np_mlp(st.policy, (np.asarray(obs, np.float64) - 1.0) / 2.0)
    np.testing.assert_allclose(np.asarray(a), 20.0 * np.tanh(out[:2]), rtol=1e-5)
    # the exploring policy's noise is the run's process: period 6, within a period corr phi^k
    ns = pol.noise_init(2)
    xs = []
    for t in range(12):
        ns, xi = pol.noise_step(pol.noise_args, ns, jnp.asarray(np.random.default_rng(t).normal(size=2), jnp.float32))
        xs.append(np.asarray(xi))
    assert np.all(np.isfinite(xs)) and np.asarray(xs).shape == (12, 2)


SHARD_CHECK = r'''
import json, sys
sys.path.insert(0, sys.argv[1])
import jax, jax.numpy as jnp
from tiny_env import TinyEnv
from nmrl.learners import ppo, ppo_config
from nmrl.runs import sharding
cfg = ppo_config.PPOConfig(num_envs=4, batch_size=4, num_minibatches=2, epochs=2, unroll_s=0.1, policy_layers=1,
                           policy_width=8, value_layers=1, value_width=8, exploration="nm-periods")
env = TinyEnv(stop_prob=0.1)
one = ppo.make_ppo(cfg, env)
two = ppo.make_ppo(cfg, env, axis_name=sharding.AXIS, num_shards=2)
st = one.init(jax.random.PRNGKey(0))
s1, m1 = jax.jit(one.chunk)(st)
program, place = sharding.shard_train_chunk(two.chunk, st, sharding.make_mesh(), env_fields=("env", "noise"))
s2, m2 = program(place(st))
leaves = lambda s: [x.tolist() for x in jax.tree.leaves((s.policy, s.value, s.opt, s.obs_stats, s.noise))]
print(json.dumps({"devices": len(jax.devices()), "m1": {k: float(v) for k, v in m1.items()},
                  "m2": {k: float(v) for k, v in m2.items()}, "s1": leaves(s1), "s2": leaves(s2)}))
'''


@pytest.mark.slow
def test_sharded_chunk_equals_unsharded():
    """Two CPU devices (shard_map over the environments, as nmrl/runs/sharding.py runs a learner):
    the same draws, minibatches and updates as one device, up to float rounding."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2", "JAX_PLATFORMS": "cpu"}
    out = subprocess.run([sys.executable, "-c", SHARD_CHECK, str(REPO / "tests")], env=env, capture_output=True,
                         text=True, timeout=600, check=True).stdout
    r = json.loads(out.strip().splitlines()[-1])
    assert r["devices"] == 2
    for k, v in r["m1"].items():
        np.testing.assert_allclose(r["m2"][k], v, rtol=1e-5, atol=1e-6, err_msg=k)
    for a, b in zip(r["s1"], r["s2"]):
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-5, atol=1e-6)


def test_divergence_undoes_the_update_and_freezes_the_point():
    """A parameter norm above max_param_norm after an iteration: that iteration's update (parameters,
    Adam, observation statistics) is undone, ``diverged`` is set and stays, the rollouts go on."""
    cfg = options.build(ppo_config.PPOConfig, **{**TINY, "epochs": 1}, max_param_norm=1.0)  # the initial policy's norm is > 1
    tr = ppo.make_ppo(cfg, TinyEnv())
    st0 = tr.init(jax.random.PRNGKey(0))
    chunk = jax.jit(tr.chunk)
    st1, m1 = chunk(st0)
    st2, m2 = chunk(st1)
    assert bool(m1["diverged"]) and bool(m2["diverged"]) and int(m2["step"]) == 2 * cfg.resolved().budget.chunk_steps
    for a, b in zip(jax.tree.leaves((st0.policy, st0.value, st0.opt, st0.obs_stats)),
                    jax.tree.leaves((st2.policy, st2.value, st2.opt, st2.obs_stats))):
        np.testing.assert_array_equal(np.asarray(b), np.asarray(a))
    assert not np.array_equal(np.asarray(st2.env.obs), np.asarray(st0.env.obs))


@pytest.mark.parametrize("max_grad_norm", [None, 1e9, 1e-12])
def test_max_grad_norm_clips_the_gradient_before_adam(max_grad_norm):
    """One Adam step (one epoch of one minibatch) from the initial parameters: Adam's first step is
    -lr g / (|g| + 1e-8) per element, so an unclipped gradient (no clip, or a bound far above its
    norm) moves every parameter with |g| >> 1e-8 by lr, while one clipped to global norm c moves
    each by at most lr c / 1e-8 (optax.clip_by_global_norm before scale_by_adam, as Brax's PPO)."""
    cfg = options.build(ppo_config.PPOConfig, **{**TINY, "epochs": 1, "num_minibatches": 1, "unroll_s": 0.2},
                               max_grad_norm=max_grad_norm)  # one unroll per environment: one Adam step
    tr = ppo.make_ppo(cfg, TinyEnv())
    st0 = tr.init(jax.random.PRNGKey(0))
    st1, _ = jax.jit(tr.chunk)(st0)
    assert cfg.resolved().unrolls_per_env == 2 and cfg.resolved().budget.chunk_steps == cfg.resolved().unroll_length * 2
    moved = np.concatenate([np.abs(np.asarray(b) - np.asarray(a)).ravel()
                            for a, b in zip(jax.tree.leaves(st0.policy), jax.tree.leaves(st1.policy))])
    lr = cfg.learning_rate
    if max_grad_norm == 1e-12:
        assert moved.max() <= lr * max_grad_norm / 1e-8 * 1.01
    else:
        assert np.quantile(moved, 0.5) == pytest.approx(lr, rel=1e-3)  # most elements: a full step lr


@pytest.mark.parametrize("period_wise", [False, True])
def test_a_minibatch_gradient_taken_in_parts_is_the_whole_minibatchs(period_wise):
    """``grad_chunks``: each minibatch's gradient summed over parts of its unrolls, the advantages
    normalised over the whole minibatch, gives the whole minibatch's Adam steps up to float rounding
    (one iteration's ``learn``: 2 epochs x 2 minibatches of 8 unrolls, in 1, 2 and 4 parts). The
    parts' gradients with each part's advantages normalised on their own (what a plain gradient
    accumulation would take) differ from the whole's by far more than that rounding."""
    kw = dict(TINY, batch_size=8, num_envs=2, unroll_s=0.2)
    if period_wise:
        kw.update(exploration="nm-periods", sigma=0.7, period_s=0.06, corr_time_s=0.05, period_wise=True)
    env = TinyEnv(stop_prob=0.1)
    whole = ppo.make_ppo(options.build(ppo_config.PPOConfig, **kw), env)
    st = whole.init(jax.random.PRNGKey(3))
    _, data = whole.rollout(st, jax.random.PRNGKey(4))
    assert float(jnp.std(data.reward)) > 0
    ref = whole.learn(st, data, jax.random.PRNGKey(5))[0]
    moved = max(float(jnp.max(jnp.abs(a - b))) for a, b in
                zip(jax.tree.leaves(ref), jax.tree.leaves({"policy": st.policy, "value": st.value})))
    assert moved > 1e-4  # 4 Adam steps of lr 3e-4 moved the parameters
    for chunks in (2, 4):
        tr = ppo.make_ppo(options.build(ppo_config.PPOConfig, **kw, grad_chunks=chunks), env)
        got = tr.learn(st, data, jax.random.PRNGKey(5))[0]
        for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(ref)):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=0, atol=1e-6)
    # the control: one minibatch's gradient from its 4 parts each normalised alone
    mb = jax.tree.map(lambda a: a[0], whole.minibatches(data, jax.random.PRNGKey(6)))
    params, eps = {"policy": st.policy, "value": st.value}, jnp.zeros(mb.x.shape, jnp.float32)
    g_whole = jax.grad(whole.loss, has_aux=True)(params, st.obs_stats, mb, st.hyper, eps)[0]
    parts = [jax.grad(whole.loss, has_aux=True)(params, st.obs_stats, jax.tree.map(lambda a: a[i::4], mb),
                                                 st.hyper, eps[i::4], float(8 * whole.config.unroll_length))[0]
             for i in range(4)]
    g_alone = jax.tree.map(lambda *g: sum(g), *parts)
    gap = max(float(jnp.max(jnp.abs(a - b))) for a, b in zip(jax.tree.leaves(g_alone), jax.tree.leaves(g_whole)))
    assert gap > 1e-3 * max(float(jnp.max(jnp.abs(a))) for a in jax.tree.leaves(g_whole))


def test_grad_chunks_must_divide_each_environments_unrolls_of_a_minibatch():
    with pytest.raises(ValueError, match=r"grad_chunks=3 is invalid: must divide the 4 unrolls"):
        options.build(ppo_config.PPOConfig, **dict(TINY, batch_size=8), grad_chunks=3).validate()


def test_a_ppo_chunk_beats_each_unroll_and_epoch_without_changing_its_numbers(tmp_path, capsys, monkeypatch):
    """The progress line inside a long PPO iteration (nmrl/learners/heartbeat.py): one beat per unroll
    of the rollout and per epoch of the update, in order, and the run's metrics equal a run without a
    listener (the callback feeds nothing back); traced in only where the program calls the host anyway
    (C physics), so that an MJX program stays in the persistent compile cache."""
    from nmrl.learners import heartbeat
    from nmrl.runs import driver, loop

    cfg = options.build(ppo_config.PPOConfig, **TINY, env="paper-cheetah", physics="c", seed=3)
    cfg = options.replace(cfg, steps=cfg.resolved().iteration_steps, chunk_steps=cfg.resolved().iteration_steps)
    beats = []
    with heartbeat.listening(lambda *b: beats.append(b)):
        rows = driver.train(cfg, tmp_path / "a", progress=False)
    U, E = cfg.resolved().unrolls_per_env, cfg.epochs
    assert beats == [("rollout", u, U) for u in range(1, U + 1)] + [("update", e, E) for e in range(1, E + 1)]
    monkeypatch.setattr(loop, "BEAT_S", 0.0)
    quiet = driver.train(cfg, tmp_path / "b", progress=True)
    lines = [l for l in capsys.readouterr().err.splitlines() if "in the chunk:" in l]
    assert lines[0].endswith(f"rollout 1/{U} (unrolls)") and lines[-1].endswith(f"update {E}/{E} (epochs)")
    assert [r["avg_reward"] for r in rows] == [r["avg_reward"] for r in quiet]
    assert [r["policy_norm"] for r in rows] == [r["policy_norm"] for r in quiet]
    mjx = driver.train(options.replace(cfg, physics="mjx"), tmp_path / "c", progress=True)
    assert mjx and "in the chunk:" not in capsys.readouterr().err  # MJX's program stays cacheable: no beats
