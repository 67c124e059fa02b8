"""Tests of nmrl.paper.noise and nmrl.paper.likelihood (eqs. (4)-(7), Sec. IV) and of nmrl.paper.toy
(Sec. II).

Every check is against an independent computation: Monte Carlo moments vs eq. (5),
dense float64 solves vs the tridiagonal closed form, ``jax.grad`` of the dense Gaussian
log-density (7) vs the vjp likelihood ratio, and formula (1) vs simulation.
"""

from __future__ import annotations

import math
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.scipy.stats import multivariate_normal

from nmrl.paper import likelihood as LR
from nmrl.paper import noise as N
from nmrl.paper import toy

OBS, HID, ACT = 31, 8, 6

# jitted entry point (apply_fn and delta are static); eager calls are also exercised below
lr_jit = jax.jit(LR.likelihood_ratio, static_argnums=(0, 6))


# --------------------------------------------------------------------------- helpers


def dense_lambda(l: int, alpha: float) -> np.ndarray:
    i = np.arange(l)
    return alpha ** np.abs(i[:, None] - i[None, :]).astype(np.float64)


@jax.jit
def mlp_init(key: jax.Array) -> dict:
    obs, hid, act = OBS, HID, ACT
    k1, k2, k3, k4 = jax.random.split(key, 4)
    return {
        "W1": jax.random.normal(k1, (obs, hid)) / math.sqrt(obs),
        "b1": 0.3 * jax.random.normal(k2, (hid,)),
        "W2": jax.random.normal(k3, (hid, act)),
        "b2": 0.3 * jax.random.normal(k4, (act,)),
    }


def mlp_apply(params: dict, S: jax.Array) -> jax.Array:
    """Two-layer perceptron with arctan hidden units and linear output (paper Sec. V-C)."""
    return jnp.arctan(S @ params["W1"] + params["b1"]) @ params["W2"] + params["b2"]


def to64(tree):
    return jax.tree_util.tree_map(lambda x: jnp.asarray(np.asarray(x, np.float64)), tree)


def dense_lr(params, S, A, alpha, sigma, delta) -> dict:
    """grad_theta of the dense log-density (7) on the Delta-subsequence, in float64."""
    l = S.shape[0]
    idx = np.arange(0, (l - 1) // delta * delta + 1, delta)  # 0, Delta, ..., L-1
    S_hat = np.asarray(S, np.float64)[idx]
    A_hat = np.asarray(A, np.float64)[idx]
    sig = np.broadcast_to(np.asarray(sigma, np.float64), (A.shape[1],))
    C = np.kron(dense_lambda(len(idx), alpha**delta), np.diag(sig**2))
    with jax.enable_x64(True):
        p64 = to64(params)

        g = _dense_grad(p64, jnp.asarray(S_hat), jnp.asarray(A_hat.reshape(-1)), jnp.asarray(C))
        return jax.tree_util.tree_map(np.asarray, g)


@jax.jit
@jax.grad
def _dense_grad(params, S_hat, a_flat, C):
    """d/dtheta of ln N(a_flat; m(theta), C), eq. (7), with C = kron(Lambda_hat, Sigma) dense."""
    return multivariate_normal.logpdf(a_flat, mlp_apply(params, S_hat).reshape(-1), C)


def assert_tree_close(got, want, rtol: float) -> None:
    for k in want:
        g = np.asarray(got[k], np.float64)
        w = np.asarray(want[k], np.float64)
        scale = np.abs(w).max() + 1e-12
        np.testing.assert_allclose(g / scale, w / scale, atol=rtol, rtol=0, err_msg=k)


@partial(jax.jit, static_argnums=(1,))
def make_period(key, l: int, alpha: float, sigma, params):
    """States and actions of one nm-period: a = a~(s) + piecewise AR noise (eq. (6))."""
    k_s, k_xi = jax.random.split(key)
    S = jax.random.normal(k_s, (l, OBS))
    xi = N.piecewise_ar(k_xi, l, ACT, alpha, l, sigma)
    return S, mlp_apply(params, S) + xi


# --------------------------------------------------------------------------- eq. (4)/(5)


def test_piecewise_ar_moments_match_eq5() -> None:
    n_seq, T, dim, l, alpha = 20_000, 12, 3, 5, 0.8
    sigma = jnp.array([0.5, 1.0, 2.0])
    keys = jax.random.split(jax.random.key(0), n_seq)
    x = jax.jit(jax.vmap(lambda k: N.piecewise_ar(k, T, dim, alpha, l, sigma)))(keys)
    x = np.asarray(x, np.float64)  # (n_seq, T, dim)
    assert x.shape == (n_seq, T, dim)
    sig = np.asarray(sigma, np.float64)
    z = x / sig  # standardized, should be N(0, 1) marginally
    se = 1.0 / math.sqrt(n_seq)
    # marginal mean 0 and variance sigma^2 (SE of a normal sample variance: sigma^2 sqrt(2/n))
    assert np.all(np.abs(x.mean(0)) < 5 * se * sig)
    var = x.var(0, ddof=1)
    assert np.all(np.abs(var - sig**2) < 5 * sig**2 * math.sqrt(2.0 / n_seq))
    # covariance alpha^|t-t'| Sigma inside a period, 0 across periods (periods 0-4, 5-9, 10-11)
    period = np.arange(T) // l
    for t in range(T):
        for t2 in range(t + 1, T):
            prod = z[:, t, :] * z[:, t2, :]
            rho = alpha ** (t2 - t) if period[t] == period[t2] else 0.0
            tol = 5 * math.sqrt(1 + rho**2) / math.sqrt(n_seq)
            assert np.all(np.abs(prod.mean(0) - rho) < tol), (t, t2, prod.mean(0), rho)
    # Sigma diagonal: different dimensions are uncorrelated
    cross = (z[:, :, 0] * z[:, :, 1]).mean(0)
    assert np.all(np.abs(cross) < 5 * se)


def test_ar_step_reset_and_index() -> None:
    st = N.ar_init(2)
    eps = jnp.array([[1.0, -1.0], [0.5, 0.5], [2.0, 0.0], [3.0, 1.0]])
    alpha, l = 0.6, 3
    outs, idx = [], []
    for t in range(4):
        st, x = N.ar_step(st, eps[t], alpha, l, sigma=2.0, reset=(t == 2))
        outs.append(np.asarray(x))
        idx.append(int(st.i))
    r = math.sqrt(1 - alpha**2)
    xi0 = np.array([1.0, -1.0])
    xi1 = alpha * xi0 + r * np.array([0.5, 0.5])
    xi2 = np.array([2.0, 0.0])  # reset starts a new period
    xi3 = alpha * xi2 + r * np.array([3.0, 1.0])
    np.testing.assert_allclose(np.stack(outs), 2.0 * np.stack([xi0, xi1, xi2, xi3]), rtol=1e-6)
    assert idx == [1, 2, 1, 2]


def test_ar_step_traced_l_one_program_and_vmap() -> None:
    traces = []

    @jax.jit
    def run(key, l):
        traces.append(1)
        return N.piecewise_ar(key, 9, 1, 0.5, l)

    key = jax.random.key(3)
    eps = np.asarray(jax.random.normal(key, (9, 1)))
    for l in (1, 2, 4, 9):
        x = np.asarray(run(key, jnp.int32(l)))[:, 0]
        # reference: independent loop over eq. (4)
        ref, prev = [], 0.0
        for t in range(9):
            prev = eps[t, 0] if t % l == 0 else 0.5 * prev + math.sqrt(0.75) * eps[t, 0]
            ref.append(prev)
        np.testing.assert_allclose(x, ref, rtol=1e-5, atol=1e-6)
    assert len(traces) == 1

    # vmap over batched states and batched l
    ls = jnp.array([1, 2, 3], jnp.int32)
    states = jax.vmap(lambda _: N.ar_init(2))(ls)
    e = jnp.ones((3, 2))
    step = jax.vmap(lambda s, ee, ll: N.ar_step(s, ee, 0.5, ll))
    s1, _ = step(states, e, ls)
    s2, x2 = step(s1, e, ls)
    assert np.asarray(s1.i).tolist() == [0, 1, 1]
    assert np.asarray(s2.i).tolist() == [0, 0, 2]
    c = 0.5 + math.sqrt(0.75)
    np.testing.assert_allclose(np.asarray(x2)[:, 0], [1.0, c, c], rtol=1e-6)


# --------------------------------------------------------------------------- Lambda^-1


@pytest.mark.parametrize("l", [1, 2, 3, 50])
@pytest.mark.parametrize("alpha", [0.1, 0.8, 0.99])
@pytest.mark.parametrize("n", [1, 6])
def test_lambda_inv_matvec_matches_dense_solve(l: int, alpha: float, n: int) -> None:
    u = np.random.default_rng(l * 100 + n).standard_normal((l, n))
    want = np.linalg.solve(dense_lambda(l, alpha), u)
    with jax.enable_x64(True):
        got64 = np.asarray(LR.lambda_inv_matvec(jnp.asarray(u), alpha))
    np.testing.assert_allclose(got64, want, rtol=1e-9, atol=1e-9)
    got32 = np.asarray(LR.lambda_inv_matvec(jnp.asarray(u, jnp.float32), alpha))
    assert got32.dtype == np.float32
    np.testing.assert_allclose(got32, want, atol=2e-5 * max(1.0, np.abs(want).max()))


def test_lambda_inv_matvec_masked_equals_unmasked() -> None:
    l_max, n, alpha = 12, 6, 0.8
    u = jnp.asarray(np.random.default_rng(0).standard_normal((l_max, n)), jnp.float32)
    f = jax.jit(LR.lambda_inv_matvec_masked)
    for length in (1, 2, 5, 11, 12):
        got = np.asarray(f(u, alpha, jnp.int32(length)))
        want = np.linalg.solve(dense_lambda(length, alpha), np.asarray(u, np.float64)[:length])
        np.testing.assert_allclose(got[:length], want, atol=1e-5)
        np.testing.assert_allclose(got[:length], np.asarray(LR.lambda_inv_matvec(u[:length], alpha)), atol=1e-6)
        assert np.all(got[length:] == 0.0)
    assert f._cache_size() == 1


# --------------------------------------------------------------------------- likelihood ratio


def test_sampled_indices() -> None:
    assert LR.sampled_indices(10, 4).tolist() == [0, 4, 8]
    assert LR.sampled_indices(9, 4).tolist() == [0, 4, 8]
    assert LR.sampled_indices(8, 4).tolist() == [0, 4]
    assert LR.sampled_indices(1, 3).tolist() == [0]
    assert LR.sampled_indices(10, 1).tolist() == list(range(10))
    for l in range(1, 20):
        for d in range(1, 6):
            idx = LR.sampled_indices(l, d)
            assert idx[-1] + 1 == 1 + (l - 1) // d * d  # L of the paper (1-based last instant)


@pytest.mark.parametrize("delta", [1, 4])
@pytest.mark.parametrize("alpha", [0.5, 0.95])
@pytest.mark.parametrize("sigma", [1.0, "vec"])
def test_likelihood_ratio_matches_dense_grad(delta: int, alpha: float, sigma) -> None:
    params = mlp_init(jax.random.key(1))
    sig = jnp.linspace(0.5, 2.0, ACT) if sigma == "vec" else sigma
    S, A = make_period(jax.random.key(2), 10, alpha, sig, params)
    want = dense_lr(params, S, A, alpha, sig, delta)
    got = lr_jit(mlp_apply, params, S, A, alpha, sig, delta)
    assert_tree_close(got, want, rtol=1e-4)
    with jax.enable_x64(True):
        got64 = LR.likelihood_ratio(mlp_apply, to64(params), to64(S), to64(A), alpha, to64(sig), delta)
    assert_tree_close(got64, want, rtol=1e-10)


def test_likelihood_ratio_l1_is_stationary_score() -> None:
    params = mlp_init(jax.random.key(5))
    S, A = make_period(jax.random.key(6), 1, 0.8, 1.5, params)
    want = dense_lr(params, S, A, 0.8, 1.5, 1)
    assert_tree_close(LR.likelihood_ratio(mlp_apply, params, S, A, 0.8, 1.5), want, rtol=1e-5)


@pytest.mark.parametrize("delta", [1, 4])
def test_likelihood_ratio_masked_equals_unpadded(delta: int) -> None:
    params = mlp_init(jax.random.key(3))
    l_max, alpha, sig = 12, 0.8, jnp.linspace(0.5, 2.0, ACT)
    S, A = make_period(jax.random.key(4), l_max, alpha, sig, params)
    f = jax.jit(lambda S, A, n: LR.likelihood_ratio(mlp_apply, params, S, A, alpha, sig, delta, length=n))
    for length in (1, 3, 5, 9, 12):
        got = f(S, A, jnp.int32(length))
        want = dense_lr(params, S[:length], A[:length], alpha, sig, delta)
        assert_tree_close(got, want, rtol=1e-4)
        unpadded = lr_jit(mlp_apply, params, S[:length], A[:length], alpha, sig, delta)
        assert_tree_close(got, unpadded, rtol=1e-5)
    assert f._cache_size() == 1


def test_likelihood_ratio_vmap_over_batch() -> None:
    params = mlp_init(jax.random.key(7))
    alpha, l, B = 0.8, 8, 4
    keys = jax.random.split(jax.random.key(8), B)
    S, A = jax.vmap(lambda k: make_period(k, l, alpha, 1.0, params))(keys)
    got = jax.jit(jax.vmap(lambda s, a: LR.likelihood_ratio(mlp_apply, params, s, a, alpha, 1.0, 4)))(S, A)
    for b in range(B):
        want = dense_lr(params, S[b], A[b], alpha, 1.0, 4)
        assert_tree_close({k: v[b] for k, v in got.items()}, want, rtol=1e-4)


@pytest.mark.parametrize("delta", [1, 4])
def test_online_accumulation_equals_batch(delta: int) -> None:
    params = mlp_init(jax.random.key(9))
    alpha, l, sig = 0.9, 11, jnp.linspace(0.5, 2.0, ACT)
    S, A = make_period(jax.random.key(10), l, alpha, sig, params)
    alpha_hat = alpha**delta

    # Python loop, step by step, with the skipped steps passed as active=False
    add = jax.jit(LR.online_lr_add, static_argnums=(1,))
    olr = LR.online_lr_init(params, OBS, ACT)
    for i in range(l):
        u = A[i] - mlp_apply(params, S[i : i + 1])[0]
        olr = add(olr, mlp_apply, params, S[i], u, alpha_hat, sig, i % delta == 0)
    want = dense_lr(params, S, A, alpha, sig, delta)
    assert_tree_close(olr.grad, want, rtol=1e-4)
    assert int(olr.count) == len(LR.sampled_indices(l, delta))
    assert_tree_close(olr.grad, LR.likelihood_ratio(mlp_apply, params, S, A, alpha, sig, delta), rtol=1e-5)

    # the same under jit + lax.scan, two periods with a reset in between
    def body(o, x):
        i, s, a = x
        o = jax.lax.cond(i == 0, LR.online_lr_reset, lambda o: o, o)
        u = a - mlp_apply(params, s[None])[0]
        o = LR.online_lr_add(o, mlp_apply, params, s, u, alpha_hat, sig, active=(i % delta == 0))
        return o, o.grad

    S2, A2 = make_period(jax.random.key(11), l, alpha, sig, params)
    xs = (jnp.tile(jnp.arange(l), 2), jnp.concatenate([S, S2]), jnp.concatenate([A, A2]))
    _, grads = jax.jit(lambda o: jax.lax.scan(body, o, xs))(LR.online_lr_init(params, OBS, ACT))
    assert_tree_close({k: v[l - 1] for k, v in grads.items()}, want, rtol=1e-4)
    assert_tree_close({k: v[2 * l - 1] for k, v in grads.items()}, dense_lr(params, S2, A2, alpha, sig, delta), 1e-4)


def test_online_cotangents_first_and_inactive() -> None:
    u_prev, u = jnp.array([1.0, 2.0]), jnp.array([0.5, -1.0])
    c_prev, c_cur = LR.online_lr_cotangents(u_prev, u, 0.6, jnp.array([1.0, 2.0]), True)
    np.testing.assert_allclose(c_prev, 0.0)
    np.testing.assert_allclose(c_cur, [0.5, -0.25])
    # not first: gradient of -1/2 e^T Sigma^-1 e w.r.t. the means (u = a - mean), by hand
    c_prev, c_cur = LR.online_lr_cotangents(u_prev, u, 0.6, jnp.array([1.0, 2.0]), False)
    e = (np.array([0.5, -1.0]) - 0.6 * np.array([1.0, 2.0])) / 0.8
    np.testing.assert_allclose(c_cur, e / np.array([1.0, 4.0]) / 0.8, rtol=1e-6)
    np.testing.assert_allclose(c_prev, -0.6 * e / np.array([1.0, 4.0]) / 0.8, rtol=1e-6)
    params = mlp_init(jax.random.key(0))
    olr = LR.online_lr_init(params, OBS, ACT)
    same = LR.online_lr_add(olr, mlp_apply, params, jnp.ones(OBS), jnp.ones(ACT), 0.5, active=jnp.bool_(False))
    assert int(same.count) == 0 and all(np.all(np.asarray(v) == 0) for v in same.grad.values())


# --------------------------------------------------------------------------- errors


@pytest.mark.parametrize("alpha", [0, 1, -0.5, 1.5, 0.0, 1.0, float("nan"), True])
def test_bad_alpha(alpha) -> None:
    with pytest.raises(ValueError, match="alpha"):
        N.validate(alpha=alpha)
    with pytest.raises(ValueError, match="alpha"):
        N.piecewise_ar(jax.random.key(0), 5, 1, alpha, 2)


@pytest.mark.parametrize("l", [0, -1, 2.5, True])
def test_bad_l(l) -> None:
    with pytest.raises(ValueError, match="l "):
        N.validate(l=l)
    with pytest.raises(ValueError, match="l "):
        LR.sampled_indices(l, 1)


@pytest.mark.parametrize("delta", [0, -2, 1.5])
def test_bad_delta(delta) -> None:
    with pytest.raises(ValueError, match="delta"):
        N.validate(delta=delta)
    params = mlp_init(jax.random.key(0))
    with pytest.raises(ValueError, match="delta"):
        LR.likelihood_ratio(mlp_apply, params, jnp.zeros((4, OBS)), jnp.zeros((4, ACT)), 0.5, delta=delta)


def test_good_values_pass() -> None:
    N.validate(alpha=0.8, l=10, delta=4)
    N.validate(alpha=np.float32(0.5), l=np.int32(3), delta=jnp.int32(1))
    N.validate()


def test_likelihood_ratio_shape_mismatch() -> None:
    params = mlp_init(jax.random.key(0))
    with pytest.raises(ValueError, match="same number of rows"):
        LR.likelihood_ratio(mlp_apply, params, jnp.zeros((10, OBS)), jnp.zeros((9, ACT)), 0.5)
    with pytest.raises(ValueError, match="2-D"):
        LR.likelihood_ratio(mlp_apply, params, jnp.zeros((OBS,)), jnp.zeros((ACT,)), 0.5)
    with pytest.raises(ValueError, match="length"):
        LR.likelihood_ratio(mlp_apply, params, jnp.zeros((4, OBS)), jnp.zeros((4, ACT)), 0.5, length=5)


# --------------------------------------------------------------------------- Sec. II toy


@pytest.mark.parametrize("delta_t", [0.1, 0.01])
def test_toy_formula1_matches_monte_carlo(delta_t: float) -> None:
    theta, c, sa, sy, n = 1.0, 0.0, 1.0, 0.5, 8000
    g = toy.sample_stationary(jax.random.key(int(1 / delta_t)), delta_t, n, theta, c, sa, sy)
    mean, se_mean, var, se_var = toy.variance_with_se(np.asarray(g))
    assert abs(mean - 1.0) < 5 * se_mean  # unbiased: grad J = 1
    assert abs(var - toy.stationary_variance(delta_t, theta, c, sa, sy)) < 5 * se_var


@pytest.mark.parametrize("delta_t", [0.1, 0.01])
def test_toy_nm_variance_matches_monte_carlo(delta_t: float) -> None:
    theta, c, sa, sy, n = 1.0, 0.3, 1.0, 0.5, 8000
    l, alpha = toy.nm_period_length(delta_t, 0.1), toy.alpha_per_step(delta_t)
    g = toy.sample_nm(jax.random.key(7 + int(1 / delta_t)), delta_t, n, l, alpha, theta, c, sa, sy)
    mean, se_mean, var, se_var = toy.variance_with_se(np.asarray(g))
    assert abs(mean - 1.0) < 5 * se_mean
    assert abs(var - toy.nm_variance(delta_t, l, alpha, theta, c, sa, sy)) < 5 * se_var


def test_toy_nm_formula_reduces_to_1_and_is_bounded() -> None:
    for dt in (0.1, 0.01):
        assert toy.nm_variance(dt, 1, 0.5, 1.0, 0.2, 1.3, 0.4) == pytest.approx(
            toy.stationary_variance(dt, 1.0, 0.2, 1.3, 0.4)
        )
    v = [toy.nm_variance(dt, toy.nm_period_length(dt, 0.1), toy.alpha_per_step(dt), 1, 0, 1, 0.5) for dt in (0.01, 0.001)]
    assert v[1] < 1.1 * v[0]


def test_online_lr_add_vmap_over_envs() -> None:
    """A batch of environments, each with its own accumulator and active flag."""
    params = mlp_init(jax.random.key(12))
    B, alpha = 3, 0.7
    S = jax.random.normal(jax.random.key(13), (2, B, OBS))
    U = jax.random.normal(jax.random.key(14), (2, B, ACT))
    olr = jax.vmap(lambda _: LR.online_lr_init(params, OBS, ACT))(jnp.arange(B))
    add = jax.jit(jax.vmap(lambda o, s, u, act: LR.online_lr_add(o, mlp_apply, params, s, u, alpha, 1.0, act)))
    olr = add(olr, S[0], U[0], jnp.array([True, True, False]))
    olr = add(olr, S[1], U[1], jnp.array([True, False, True]))
    assert np.asarray(olr.count).tolist() == [2, 1, 1]
    for b, rows in enumerate(([0, 1], [0], [1])):
        # batch form on the samples this environment actually added (A = u + a~(s))
        Sb = S[jnp.array(rows), b]
        Ab = U[jnp.array(rows), b] + mlp_apply(params, Sb)
        want = dense_lr(params, Sb, Ab, alpha, 1.0, 1)
        assert_tree_close({k: v[b] for k, v in olr.grad.items()}, want, rtol=1e-4)
