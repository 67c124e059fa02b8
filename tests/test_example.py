"""examples/nm_exploration_example.py, the exploration scheme reused on another MJX robot:

* its policy gradient equals autodiff of the same estimator written with dense linear algebra:
  each period's log-density of the Delta-sampled actions under N(m(theta), Lambda_hat (x) Sigma)
  (jax.scipy's multivariate normal, Lambda_hat = [alpha^(Delta |i - j|)]), weighted by the
  return-to-go minus the per-period mean computed here in numpy, so the reshapes that cut the
  rollout into periods are checked too;
* its noise is the process (4): within a period the exploring actions' deviations from a~ have
  lag-1 correlation alpha and variance sigma^2, across a period boundary correlation 0 (Monte Carlo);
* it learns: the deterministic policy's average reward per step rises well above the untrained
  arm's;
* bad arguments exit with status 2 and the value named.

One configuration (l = 5, Delta = 2) is compiled once for the module."""

from __future__ import annotations

import importlib.util
import pathlib
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.scipy.stats import multivariate_normal

SCRIPT = pathlib.Path(__file__).resolve().parents[1] / "examples" / "nm_exploration_example.py"


def _module():
    spec = importlib.util.spec_from_file_location("nm_exploration_example", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


ex = _module()
CFG = ex.ExampleConfig(l=5, delta=2, num_envs=16, steps=60, iterations=30, seed=3)


@pytest.fixture(scope="module")
def example():
    return ex.make_example(CFG)


def _nonzero_params(example, key):
    params, _ = example.init(key)  # the paper's initial actor has zero output weights: a~ = 0
    leaves, tree = jax.tree.flatten(params)
    keys = jax.random.split(jax.random.fold_in(key, 1), len(leaves))
    return jax.tree.unflatten(tree, [x + 0.3 * jax.random.normal(k, x.shape) for x, k in zip(leaves, keys)])


def test_policy_gradient_equals_dense_gaussian_autodiff(example):
    key = jax.random.PRNGKey(0)
    params = _nonzero_params(example, key)
    traj = example.rollout(params, jax.random.PRNGKey(1), 1.0)
    got = example.policy_gradient(params, traj)

    l, K, N, d = CFG.l, CFG.periods, CFG.num_envs, ex.ACT_DIM
    r = np.asarray(traj.reward)  # (T, N)
    G = np.array([[r[k * l:, n].sum() for n in range(N)] for k in range(K)])  # return-to-go of period k
    adv = G - G.mean(axis=1, keepdims=True)
    idx = np.arange(0, l, CFG.delta)  # 0, 2, 4: L = 1 + floor((l - 1) / Delta) Delta = 5
    lam_hat = CFG.alpha ** np.abs(idx[:, None] - idx[None, :])  # alpha^(Delta |i - j|), i, j sample numbers
    cov = jnp.asarray(np.kron(lam_hat, CFG.sigma ** 2 * np.eye(d)))  # vec row-major: (sample, action)
    actor = ex.Perceptron(hidden=CFG.hidden, out=d)

    rows = np.arange(K)[:, None] * l + idx[None, :]  # (K, L): the sampled steps of period k
    S = jnp.moveaxis(traj.obs[rows], 2, 1)  # (K, N, L, obs)
    A = jnp.moveaxis(traj.act[rows], 2, 1)  # (K, N, L, d)

    def log_density(p, s, a):  # one period: ln N(vec A_hat; vec m(theta), Lambda_hat (x) Sigma)
        return multivariate_normal.logpdf(a.reshape(-1), actor.apply(p, s).reshape(-1), cov)

    def surrogate(p):
        logp = jax.vmap(jax.vmap(log_density, (None, 0, 0)), (None, 0, 0))(p, S, A)  # (K, N)
        return jnp.sum(jnp.asarray(adv) * logp) / (K * N)

    want = jax.jit(jax.grad(surrogate))(params)
    for g, w in zip(jax.tree.leaves(got), jax.tree.leaves(want)):
        np.testing.assert_allclose(np.asarray(g), np.asarray(w), rtol=2e-3, atol=2e-4 * float(np.abs(w).max()))
    assert max(float(np.abs(w).max()) for w in jax.tree.leaves(want)) > 1e-3  # not a vacuous zero


def test_exploring_actions_follow_the_piecewise_ar_process(example):
    params = _nonzero_params(example, jax.random.PRNGKey(2))
    devs = []
    for i in range(8):
        traj = example.rollout(params, jax.random.PRNGKey(10 + i), 1.0)
        devs.append(np.asarray(traj.act - jax.vmap(lambda s: ex.Perceptron(CFG.hidden, ex.ACT_DIM)
                                                   .apply(params, s))(traj.obs)) / CFG.sigma)
    u = np.concatenate(devs, axis=1)  # (T, 8N, d), standardized: xi_t
    t = np.arange(CFG.steps - 1)
    inside = t % CFG.l != CFG.l - 1  # (t, t + 1) in one period
    pairs_in = (u[:-1][inside] * u[1:][inside]).mean()
    pairs_across = (u[:-1][~inside] * u[1:][~inside]).mean()
    n_in, n_across = u[:-1][inside].size, u[:-1][~inside].size
    # 5 standard errors; x3 where the samples within a period are correlated (effective n smaller)
    assert abs((u ** 2).mean() - 1.0) < 3 * 5 * np.sqrt(2 / u.size)  # variance sigma^2: xi ~ N(0, 1)
    assert abs(pairs_in - CFG.alpha) < 3 * 5 * np.sqrt((1 + CFG.alpha ** 2) / n_in)  # lag-1: alpha
    assert abs(pairs_across) < 5 * np.sqrt(1 / n_across)  # independent across a period boundary


def test_it_learns_to_reach(example):
    key = jax.random.PRNGKey(CFG.seed)
    params, opt_state = example.init(key)
    before = float(example.evaluate(params, jax.random.PRNGKey(99)))
    for i in range(CFG.iterations):
        params, opt_state, _ = example.update(params, opt_state, jax.random.fold_in(key, i))
    after = float(example.evaluate(params, jax.random.PRNGKey(99)))
    # the untrained arm stays ~0.21 m from the target on average; a reaching policy ~0.09-0.10 m
    assert before < -0.18
    assert after > before + 0.06, (before, after)


@pytest.mark.parametrize("argv, named", [(["--l", "0"], "l=0"), (["--l", "7"], "steps=60 is invalid with l=7"),
                                         (["--alpha", "1.5"], "alpha"), (["--sigma", "-1"], "sigma=-1"),
                                         (["--delta", "0"], "delta=0")])
def test_bad_arguments_are_refused(argv, named, capsys):
    assert ex.main(argv) == 2
    assert named in capsys.readouterr().err
