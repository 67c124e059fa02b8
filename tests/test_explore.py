"""Tests of nmrl.explore: the exploration processes and their exact likelihoods.

Every check is against an independent computation: Monte-Carlo covariances against the processes'
definition (a dense covariance with the resets), scipy's multivariate normal on that dense covariance
(float64), autodiff of the dense log-density, the paper's eq. (7) with Lambda = [alpha^|i-j|], a
Schur complement for a fragment that starts from a carried belief, an FFT of the autocovariance for
the colored spectrum.
"""

from __future__ import annotations

import math
import pathlib
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import multivariate_normal

import nmrl.explore as E
from nmrl.explore import colored

REPO = pathlib.Path(__file__).resolve().parents[1]
DT = 0.02


# --------------------------------------------------------------------------- references (NumPy, float64)


def params64(proc: E.Process) -> tuple[np.ndarray, np.ndarray, float, int]:
    return (np.asarray(proc.phi, np.float64), np.asarray(proc.w, np.float64), float(proc.sigma),
            int(proc.period))


def dense_cov(proc: E.Process, fresh: np.ndarray) -> np.ndarray:
    """(T, T) covariance of one action dimension by the definition: sigma^2 sum_k w_k^2 phi_k^|t-s|
    inside one segment between fresh draws, 0 across segments."""
    phi, w, sigma, _ = params64(proc)
    T = len(fresh)
    seg = np.cumsum(np.asarray(fresh, int))
    lag = np.abs(np.arange(T)[:, None] - np.arange(T)[None, :])
    rho = np.sum((w**2)[None, None, :] * phi[None, None, :] ** lag[:, :, None], axis=-1)
    return sigma**2 * rho * (seg[:, None] == seg[None, :])


def period_fresh(T: int, period: int, resets=()) -> np.ndarray:
    """Fresh flags of a process started at t = 0 with a period and trial resets before the given steps."""
    fresh, i = np.zeros(T, bool), 0
    for t in range(T):
        if t in resets:
            i = 0
        fresh[t] = i == 0
        i = (i + 1) % period
    return fresh


def dense_logpdf(C: np.ndarray, xi: np.ndarray) -> float:
    """Joint log-density of xi (T, n), the n dimensions independent with covariance C each."""
    return float(sum(multivariate_normal(mean=np.zeros(len(C)), cov=C).logpdf(xi[:, j]) for j in range(xi.shape[1])))


def dense_conditional_logpdf(C: np.ndarray, xi: np.ndarray, t0: int) -> float:
    """log p(xi[t0:] | xi[:t0]) by the Schur complement of the dense covariance."""
    C11, C12, C22 = C[:t0, :t0], C[:t0, t0:], C[t0:, t0:]
    G = np.linalg.solve(C11, C12)  # C11^-1 C12
    cov = C22 - C12.T @ G
    mean = G.T @ xi[:t0]
    return float(sum(multivariate_normal(mean=mean[:, j], cov=cov).logpdf(xi[t0:, j]) for j in range(xi.shape[1])))


SPECS = {
    "white": E.ExplorationSpec("white", sigma=0.7),
    "nm-periods": E.ExplorationSpec("nm-periods", sigma=1.3, period_s=0.1, corr_time_s=0.0896),
    "ou": E.ExplorationSpec("ou", sigma=0.5, corr_time_s=0.15),
    "colored3": E.ExplorationSpec("colored", sigma=2.0, beta=0.5, order=3),
    "colored": E.ExplorationSpec("colored"),
}


@jax.jit
def _rollout(proc: E.Process, key: jax.Array, reset_mask: jax.Array) -> tuple:
    """T draws for B environments; before step t the environments where reset_mask[t] are reset."""
    B = reset_mask.shape[1]
    k0, k1 = jax.random.split(key)
    st = E.init(proc, k0, B, 2)

    def body(st, inp):
        k, mask = inp
        st = E.reset(proc, st, mask)
        mean, cov, _ = E.belief(st)
        xi, logp, fresh, st = E.sample(proc, st, k)
        return st, (xi, logp, fresh, mean, cov)

    return jax.lax.scan(body, st, (jax.random.split(k1, reset_mask.shape[0]), reset_mask))[1]


#: log_prob of B environments' fragments, time-major (T, B, ...) as _rollout returns them
_lp_batch = jax.jit(jax.vmap(E.log_prob, in_axes=(None, 0, 0, 1, 1)))


@jax.jit
def _fragment64(proc: E.Process, xi: jax.Array, fresh: jax.Array, split: jax.Array) -> jax.Array:
    """Summed log_prob of xi[t0:] from the belief that filtering xi[:t0] gives (split[t] = t < t0;
    one environment, float64 under enable_x64): the earlier steps enter only through the belief."""
    K, n = proc.phi.shape[0], xi.shape[1]
    lp, m, P = E.filter_sequence(proc, jnp.zeros((K, n), xi.dtype), jnp.eye(K, dtype=xi.dtype), xi, fresh)
    return jnp.sum(jnp.where(split, 0.0, lp))


# --------------------------------------------------------------------------- sampling


@pytest.mark.parametrize("name", ["white", "nm-periods", "ou", "colored"])
def test_monte_carlo_covariance_matches_the_definition(name):
    """The empirical T x T covariance of 16,000 sampled sequences (8,000 environments x 2 dimensions)
    equals the dense covariance of the definition, period resets and a trial reset included."""
    proc = SPECS[name].process(DT)
    T, B, reset_at = 14, 8000, 8
    mask = np.zeros((T, B), bool)
    mask[reset_at] = True
    xi, _, fresh, _, _ = _rollout(proc, jax.random.key(1), jnp.asarray(mask))
    want_fresh = period_fresh(T, int(proc.period), resets=(reset_at,))
    np.testing.assert_array_equal(np.asarray(fresh), np.broadcast_to(want_fresh[:, None], (T, B)))
    x = np.asarray(xi, np.float64).transpose(1, 2, 0).reshape(-1, T)  # (B * n, T)
    emp = x.T @ x / len(x)
    C = dense_cov(proc, want_fresh)
    s2 = float(proc.sigma) ** 2
    # standard error of a covariance entry <= sigma^2 sqrt(2 / N); 5 of them
    np.testing.assert_allclose(emp / s2, C / s2, atol=5 * math.sqrt(2 / len(x)))


def test_long_trial_stays_stationary_in_float32():
    """3,000 steps at 5 ms (6 times the slowest colored component's time constant, phi = 0.998)
    without a reset: the float32 sampler's variance and its covariances at 1, 10 and 100 steps over
    the trial's last 101 steps are the definition's (Monte Carlo over 2 x 500 environments)."""
    proc = E.ExplorationSpec("colored", sigma=0.5).process(0.005)
    T, B = 3000, 500

    @jax.jit
    def tail(key):  # the last 101 draws of T, and how many draws were fresh
        st = E.init(proc, key, B, 2)

        def step(carry, k):
            st, n_fresh = carry
            xi, _, fresh, st = E.sample(proc, st, k)
            return (st, n_fresh + jnp.sum(fresh)), xi

        keys = jax.random.split(key, T)
        (st, n_fresh), _ = jax.lax.scan(step, (st, 0), keys[:-101])
        (_, n_fresh), xi = jax.lax.scan(step, (st, n_fresh), keys[-101:])
        return xi, n_fresh

    xi, n_fresh = tail(jax.random.key(9))
    assert int(n_fresh) == B  # only the first draw of each trial is fresh
    x = np.asarray(xi, np.float64).transpose(1, 2, 0).reshape(-1, 101) / float(proc.sigma)  # (B * n, 101)
    phi, w, _, _ = params64(proc)
    N = len(x)
    for h in (0, 1, 10, 100):
        emp = float(np.mean(x[:, :101 - h] * x[:, h:]))  # over every pair h apart in the window
        assert abs(emp - np.sum(w**2 * phi**h)) < 5 * math.sqrt(2 / N), (h, emp, np.sum(w**2 * phi**h))


def test_autocorrelation_at_100_ms_is_the_same_at_20_10_and_5_ms():
    """The correlation of xi_t and xi_{t + 0.1 s}, averaged over the position in a period, from the
    process parameters at each control step: one physical process at every step."""
    specs = [E.ExplorationSpec("nm-periods", period_s=0.2), E.ExplorationSpec("ou"),
             E.ExplorationSpec("colored"), E.ExplorationSpec("colored", beta=0.5, f_min_hz=0.5, order=8)]
    for spec in specs:
        rho = []
        for dt in (0.02, 0.01, 0.005):
            phi, w, _, period = params64(spec.process(dt))
            h = round(0.1 / dt)
            inside = 1.0 if period == E.NO_RESET else max(period - h, 0) / period  # pairs in one period
            rho.append(inside * float(np.sum(w**2 * phi**h)))
        assert rho[0] > 0.05, (spec, rho)
        np.testing.assert_allclose(rho, rho[0], rtol=2e-5, err_msg=str(spec))


# --------------------------------------------------------------------------- likelihood vs dense


CASES = [  # (spec, T, trial resets)
    ("white", 5, ()),
    ("nm-periods", 12, ()),
    ("nm-periods", 9, (3,)),
    ("ou", 1, ()),
    ("ou", 11, (6,)),
    ("colored3", 7, ()),
    ("colored", 13, (4, 10)),
]


@pytest.mark.parametrize("name, T, resets", CASES)
def test_log_prob_equals_the_dense_gaussian(name, T, resets):
    """Cumulative sums of the per-step log_prob equal scipy's joint log-density of the first t steps
    (so every term is the conditional density given the earlier steps since the last reset)."""
    proc = SPECS[name].process(DT)
    K, n = proc.phi.shape[0], 3
    fresh = period_fresh(T, int(proc.period), resets)
    xi = np.random.default_rng(T).standard_normal((T, n)) * float(proc.sigma)
    with jax.enable_x64(True):
        lp = np.asarray(E.log_prob(proc, jnp.zeros((K, n)), jnp.eye(K), jnp.asarray(xi), jnp.asarray(fresh)))
    assert lp.shape == (T,)
    C = dense_cov(proc, fresh)
    for t in sorted({1, T // 2 + 1, T}):
        np.testing.assert_allclose(lp[:t].sum(), dense_logpdf(C[:t, :t], xi[:t]), rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("name", ["nm-periods", "ou", "colored3", "colored"])
def test_log_prob_from_a_carried_belief_is_the_dense_conditional(name):
    """A fragment that starts mid-trial: log_prob from the belief that sample() carried to its start
    (float32, as a rollout stores it) equals log p(fragment | the trial's earlier xi) by the Schur
    complement of the dense covariance."""
    proc = SPECS[name].process(DT)
    T, t0, B = 20, 10, 4
    mask = np.zeros((T, B), bool)
    mask[13, 1] = True  # a trial ends inside the fragment of environment 1
    xi, logp, fresh, mean, cov = _rollout(proc, jax.random.key(2), jnp.asarray(mask))
    lp = _lp_batch(proc, mean[t0], cov[t0], xi[t0:], fresh[t0:])
    xi, fresh = np.asarray(xi), np.asarray(fresh)
    for b in range(B):
        want = dense_conditional_logpdf(dense_cov(proc, fresh[:, b]), xi[:, b].astype(np.float64), t0)
        np.testing.assert_allclose(float(jnp.sum(lp[b])), want, rtol=2e-5, atol=2e-4)
        # the same in float64 from the belief that filtering the trial's earlier steps gives
        with jax.enable_x64(True):
            lp64 = _fragment64(proc, jnp.asarray(xi[:, b], jnp.float64), jnp.asarray(fresh[:, b]),
                               jnp.arange(T) < t0)
            np.testing.assert_allclose(float(lp64), want, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("name", ["nm-periods", "ou", "colored", "white"])
def test_sample_logp_equals_log_prob(name):
    """The logp that sample() returns while acting equals log_prob of the same sequence rebuilt
    later from the belief stored at the fragment's start (two fragments, a trial reset inside)."""
    proc = SPECS[name].process(DT)
    T, B = 20, 4
    mask = np.zeros((T, B), bool)
    mask[5, 0] = mask[13, 2] = True
    xi, logp, fresh, mean, cov = _rollout(proc, jax.random.key(3), jnp.asarray(mask))
    for a, b in ((0, 10), (10, T)):
        got = _lp_batch(proc, mean[a], cov[a], xi[a:b], fresh[a:b])
        np.testing.assert_allclose(np.asarray(got), np.asarray(logp[a:b]).T, rtol=1e-5, atol=1e-5)


def test_theta_gradient_equals_autodiff_of_the_dense_density():
    """xi = a - mu_theta(s) for a linear policy: the theta- and xi-gradients of the summed log_prob
    (from the prior and from a carried belief) equal autodiff of the dense (conditional) density."""
    proc = SPECS["colored3"].process(DT)
    T, t0, n, d = 10, 4, 2, 3
    rng = np.random.default_rng(4)
    fresh = period_fresh(T, 10**6, resets=(7,))
    fresh[0] = True
    C = dense_cov(proc, fresh)
    with jax.enable_x64(True):
        S = jnp.asarray(rng.standard_normal((T, d)))
        A = jnp.asarray(rng.standard_normal((T, n)))
        W = jnp.asarray(rng.standard_normal((d, n)))
        K = proc.phi.shape[0]
        Cj = jnp.asarray(C)

        def kalman(W, a):  # fragment [a, T) from the belief after [0, a)
            xi = A - S @ W
            _, m, P = E.filter_sequence(proc, jnp.zeros((K, n)), jnp.eye(K), jax.lax.stop_gradient(xi[:a]),
                                        jnp.asarray(fresh[:a]))
            return jnp.sum(E.log_prob(proc, m, P, xi[a:], jnp.asarray(fresh[a:])))

        def dense(W, a):
            xi = A - S @ W
            x1, x2 = jax.lax.stop_gradient(xi[:a]), xi[a:]
            if a == 0:
                mean, cov = jnp.zeros_like(x2), Cj
            else:
                G = jnp.linalg.solve(Cj[:a, :a], Cj[:a, a:])
                mean, cov = G.T @ x1, Cj[a:, a:] - Cj[:a, a:].T @ G
            return sum(jax.scipy.stats.multivariate_normal.logpdf(x2[:, j], mean[:, j], cov) for j in range(n))

        for a in (0, t0):
            vk, gk = jax.jit(jax.value_and_grad(kalman), static_argnums=1)(W, a)
            vd, gd = jax.jit(jax.value_and_grad(dense), static_argnums=1)(W, a)
            np.testing.assert_allclose(vk, vd, rtol=1e-10)
            np.testing.assert_allclose(gk, gd, rtol=1e-8, atol=1e-10)
        gx = jax.jit(jax.grad(lambda x: jnp.sum(E.log_prob(proc, jnp.zeros((K, n)), jnp.eye(K), x,
                                                           jnp.asarray(fresh)))))(A)
        gd = jax.jit(jax.grad(lambda x: sum(jax.scipy.stats.multivariate_normal.logpdf(x[:, j], jnp.zeros(T), Cj)
                                            for j in range(n))))(A)
        np.testing.assert_allclose(gx, gd, rtol=1e-8, atol=1e-10)


def test_nm_periods_is_the_papers_eq_7():
    """K = 1 nm-periods with l = 10, phi = alpha = 0.8 (the paper's setting, from seconds): each
    period's summed log_prob equals eq. (7), N(m, Lambda (x) Sigma) with Lambda = [alpha^|i-j|]."""
    alpha, l, n, sigma = 0.8, 10, 3, 0.6
    spec = E.ExplorationSpec("nm-periods", sigma=sigma, period_s=0.2, corr_time_s=-0.02 / math.log(alpha))
    assert spec == E.ExplorationSpec.from_paper(alpha, l, 0.02, sigma=sigma)
    proc = spec.process(0.02)
    assert int(proc.period) == l and abs(float(proc.phi[0]) - alpha) < 1e-7
    T = 3 * l
    rng = np.random.default_rng(5)
    xi = rng.standard_normal((T, n)) * sigma
    fresh = np.arange(T) % l == 0
    with jax.enable_x64(True):
        lp = np.asarray(E.log_prob(proc, jnp.zeros((1, n)), jnp.eye(1), jnp.asarray(xi), jnp.asarray(fresh)))
    a, s = float(proc.phi[0]), float(proc.sigma)  # the process's alpha and sigma as stored (float32)
    Lam = a ** np.abs(np.arange(l)[:, None] - np.arange(l)[None, :])
    Cmat = np.kron(Lam, np.diag(np.full(n, s**2)))  # C_k = Lambda (x) Sigma, blocks alpha^|i-j| Sigma
    for k in range(3):
        v = xi[k * l:(k + 1) * l].reshape(-1)  # [a_1; ...; a_l] - m
        _, logdet = np.linalg.slogdet(Cmat)
        eq7 = -0.5 * (l * n * math.log(2 * math.pi) + logdet + v @ np.linalg.solve(Cmat, v))
        np.testing.assert_allclose(lp[k * l:(k + 1) * l].sum(), eq7, rtol=1e-10)


def test_unit_process_scaled_by_a_state_dependent_sigma():
    """A learner that samples u from the sigma = 1 process and acts xi_t = sigma_t u_t with its own
    sigma_t gets log p(xi) = log_prob(u) - n sum_t log sigma_t: equal to the dense density with
    covariance diag(sigma_t) C diag(sigma_t); and log_prob scales with the Process's sigma alike."""
    unit = E.ExplorationSpec("colored", order=4).process(DT)
    T, n = 9, 2
    rng = np.random.default_rng(6)
    u = rng.standard_normal((T, n))
    s_t = np.exp(rng.standard_normal(T) * 0.3)
    fresh = np.zeros(T, bool)
    fresh[0] = True
    with jax.enable_x64(True):
        lp_u = float(jnp.sum(E.log_prob(unit, jnp.zeros((4, n)), jnp.eye(4), jnp.asarray(u), jnp.asarray(fresh))))
        scaled = unit._replace(sigma=jnp.float32(2.5))
        lp_s = float(jnp.sum(E.log_prob(scaled, jnp.zeros((4, n)), jnp.eye(4), jnp.asarray(2.5 * u),
                                        jnp.asarray(fresh))))
    C = dense_cov(unit, fresh)
    want = dense_logpdf(np.diag(s_t) @ C @ np.diag(s_t), s_t[:, None] * u)
    np.testing.assert_allclose(lp_u - n * np.log(s_t).sum(), want, rtol=1e-10)
    np.testing.assert_allclose(lp_s, lp_u - T * n * math.log(2.5), rtol=1e-10)


def test_padded_and_stacked_processes_give_the_same_density():
    """Every kind padded to K = 6 w = 0 components, stacked and vmapped in one program, gives each
    process's own log_prob."""
    names = ["white", "nm-periods", "ou", "colored"]
    T, n = 12, 2
    xi = jnp.asarray(np.random.default_rng(7).standard_normal((T, n)), jnp.float32)
    procs = [SPECS[k].process(DT, order=6) for k in names]
    fresh = jnp.asarray(np.stack([period_fresh(T, int(p.period)) for p in procs]))
    stacked = E.stack(procs)
    got = jax.jit(jax.vmap(E.log_prob, in_axes=(0, None, None, None, 0)))(
        stacked, jnp.zeros((6, n)), jnp.eye(6), xi, fresh)
    for j, k in enumerate(names):
        own = SPECS[k].process(DT)
        K = own.phi.shape[0]
        want = E.log_prob(own, jnp.zeros((K, n)), jnp.eye(K), xi, fresh[j])
        np.testing.assert_allclose(got[j], want, rtol=1e-5, atol=1e-5)
    with pytest.raises(ValueError, match=r"order \(components to pad to\) must be an int >= 6 for colored, got 3"):
        SPECS["colored"].process(DT, order=3)


@pytest.mark.parametrize("steps", [200, int(E.spec.MAX_TAU_STEPS)])
def test_float32_filter_with_phi_close_to_1(steps):
    """tau / dt = 200 and the largest allowed 10^4: the float32 filter (K = 1 and a colored fit whose
    slowest component has that time constant) matches float64 over 600 steps; its covariance stays
    symmetric positive semi-definite."""
    T, n = 600, 2
    f_min = colored.LOW_MARGIN / (2 * math.pi * steps * DT)  # slowest time constant = steps * DT
    specs = [E.ExplorationSpec("ou", corr_time_s=steps * DT),
             E.ExplorationSpec("colored", beta=1.5, f_min_hz=f_min, order=8)]
    for spec in specs:
        proc = spec.process(DT)
        K = proc.phi.shape[0]
        xs, _, fresh, _, _ = _rollout(proc, jax.random.key(8), jnp.zeros((T, 1), bool))
        x32, fr = xs[:, 0], fresh[:, 0]
        lp32, _, P32 = E.filter_sequence(proc, jnp.zeros((K, n)), jnp.eye(K), x32, fr)
        with jax.enable_x64(True):
            lp64 = np.asarray(E.log_prob(proc, jnp.zeros((K, n)), jnp.eye(K), jnp.asarray(x32, jnp.float64), fr))
        err = np.abs(np.asarray(lp32, np.float64) - lp64)
        assert err.max() < 1e-4 * (1 + np.abs(lp64).max()), (spec, err.max())
        assert abs(np.sum(np.asarray(lp32, np.float64)) - np.sum(lp64)) < 1e-5 * np.sum(np.abs(lp64)), spec
        P = np.asarray(P32, np.float64)
        np.testing.assert_allclose(P, P.T, atol=0)
        assert np.linalg.eigvalsh(P).min() > -1e-6


# --------------------------------------------------------------------------- colored spectrum


def _fft_psd(acov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Spectrum (up to a constant) of a sequence with autocovariance acov[h], h >= 0, by FFT of the
    symmetric sequence; frequencies in cycles per step."""
    full = np.concatenate([acov, acov[-2:0:-1]])
    return np.fft.rfftfreq(len(full)), np.fft.rfft(full).real


def _db_error(f: np.ndarray, S: np.ndarray, beta: float, lo: float, hi: float) -> float:
    band = (f >= lo) & (f <= hi)
    db = 10 * np.log10(S[band] * f[band] ** beta)
    return (db.max() - db.min()) / 2


#: max dB error over [0.25, 25] Hz of the default order-6 fit, continuous time and sampled at dt
#: (the stated numbers of docs/exploration.md), per beta
STATED_DB = {0.5: (0.06, 2.4, 1.2, 0.4), 1.0: (0.03, 2.6, 1.1, 0.4), 2.0: (0.14, 2.1, 1.0, 0.3)}


@pytest.mark.parametrize("beta", sorted(STATED_DB))
def test_colored_spectrum_error_against_1_over_f_beta(beta):
    """The default colored fit's spectrum, computed independently (FFT of its autocovariance
    sum_k w_k^2 exp(-|t|/tau_k); at 0.25 ms for the continuous-time spectrum), is within the stated
    dB of 1/f^beta over the band, continuous and sampled at 20, 10 and 5 ms."""
    spec = E.ExplorationSpec("colored", beta=beta)
    tau, w = colored.colored_components(beta, spec.f_min_hz, spec.f_max_hz, spec.order)
    stated = STATED_DB[beta]
    for dt, bound in zip((0.00025, 0.02, 0.01, 0.005), stated):
        n_lag = int(40 * tau.max() / dt)
        acov = (w**2) @ np.exp(-np.arange(n_lag)[None, :] * dt / tau[:, None])
        f, S = _fft_psd(acov)
        err = _db_error(f / dt, S, beta, spec.f_min_hz, spec.f_max_hz)
        assert err <= bound, (beta, dt, err)
        if dt == 0.00025:
            assert abs(err - colored.spectrum_error_db(beta, spec.f_min_hz, spec.f_max_hz, tau, w)) < 0.01
        else:
            assert abs(err - colored.spectrum_error_db(beta, spec.f_min_hz, spec.f_max_hz, tau, w, dt)) < 0.02
    phi, w32, _, _ = params64(spec.process(0.02))
    np.testing.assert_allclose(np.sum(w32**2), 1.0, rtol=1e-6)  # marginal std = sigma


def test_colored_fit_of_the_sampled_spectrum():
    """The alternative fit (weights for the spectrum sampled at 20 ms, not used by the spec): the
    sampled spectrum, by FFT of its autocovariance, is within 0.6 dB of 1/f over the band."""
    tau = colored.time_constants(0.25, 25.0, 6)
    w = colored.fit_weights(1.0, 0.25, 25.0, tau, control_dt=0.02)
    acov = (w**2) @ np.exp(-np.arange(int(40 * tau.max() / 0.02))[None, :] * 0.02 / tau[:, None])
    f, S = _fft_psd(acov)
    assert _db_error(f / 0.02, S, 1.0, 0.25, 25.0) <= 0.6


# --------------------------------------------------------------------------- spec, conversion, bad input


def test_seconds_to_steps_conversion_table():
    """The paper's alpha = 0.8, l = 10 at 20 ms is corr_time 0.0896 s, period 0.2 s; the same
    seconds give alpha = exp(-dt / 0.0896) and l = 0.2 / dt at 10 and 5 ms (docs/exploration.md)."""
    assert abs(E.corr_time_from_alpha(0.8, 0.02) - 0.089628) < 1e-6
    spec = E.ExplorationSpec("nm-periods")  # the defaults are the paper's
    for dt, alpha, l in ((0.02, 0.8, 10), (0.01, 0.894427, 20), (0.005, 0.945742, 40), (0.0025, 0.972492, 80)):
        proc = spec.process(dt)
        assert int(proc.period) == l
        np.testing.assert_allclose(float(proc.phi[0]), alpha, atol=1e-6)
        np.testing.assert_allclose(float(proc.phi[0]), 0.8 ** (dt / 0.02), rtol=1e-6)
    assert E.period_steps(0.25, 0.02) == 13 and E.period_steps(0.2, 0.02) == 10  # halves round up
    colored_phi = {0.02: [0.9922, 0.9705, 0.8924, 0.6483, 0.1920, 0.0019],
                   0.01: [0.9961, 0.9852, 0.9447, 0.8051, 0.4382, 0.0432],
                   0.005: [0.9980, 0.9926, 0.9719, 0.8973, 0.6619, 0.2079],
                   0.0025: [0.9990, 0.9963, 0.9859, 0.9473, 0.8136, 0.4559]}
    tau = np.array([2.546, 0.6688, 0.1757, 0.04614, 0.01212, 0.003183])  # 1 / (2 pi f), f from 0.0625 to 50 Hz
    for dt, phi in colored_phi.items():
        got = np.asarray(E.ExplorationSpec("colored").process(dt).phi, np.float64)
        np.testing.assert_allclose(got, phi, atol=6e-5)
        np.testing.assert_allclose(got, np.exp(-dt / tau), atol=1e-4)


def test_spec_round_trip():
    for spec in SPECS.values():
        assert E.ExplorationSpec.from_dict(spec.to_dict()) == spec
    with pytest.raises(ValueError, match="period_s is a parameter of nm-periods, not of colored exploration"):
        E.ExplorationSpec.from_dict({"kind": "colored", "period_s": 0.2})


BAD = [  # (spec kwargs, control_dt, substrings of the message)
    (dict(kind="ou", corr_time_s=0.0), DT, ["corr_time_s", "> 0", "0.0"]),
    (dict(kind="ou", corr_time_s=-0.1), DT, ["corr_time_s", "> 0", "-0.1"]),
    (dict(kind="nm-periods", corr_time_s=float("nan")), DT, ["corr_time_s", "finite", "nan"]),
    (dict(kind="ou", corr_time_s=201.0), DT, ["corr_time_s", "(0, 200] s", "201.0"]),
    (dict(kind="colored", beta=2.5), DT, ["beta", "[0, 2]", "2.5"]),
    (dict(kind="colored", beta=-0.1), DT, ["beta", "[0, 2]", "-0.1"]),
    (dict(kind="colored", beta=float("inf")), DT, ["beta", "finite", "inf"]),
    (dict(kind="nm-periods", period_s=0.01), DT, ["period_s", ">= the control step 0.02 s", "0.01"]),
    (dict(kind="nm-periods", period_s=0.0), DT, ["period_s", "> 0", "0.0"]),
    (dict(kind="white", sigma=0.0), DT, ["sigma", "> 0", "0.0"]),
    (dict(kind="white", sigma=-1.0), DT, ["sigma", "> 0", "-1.0"]),
    (dict(kind="ou", sigma=float("inf")), DT, ["sigma", "finite number in float32", "inf"]),
    (dict(kind="ou", sigma=1e39), DT, ["sigma", "finite number in float32", "1e+39"]),
    (dict(kind="ou", sigma=True), DT, ["sigma", "must be a finite number > 0", "True"]),
    (dict(kind="colored", f_max_hz=30.0), DT, ["f_max_hz", "Nyquist frequency 25 Hz", "30.0"]),
    (dict(kind="colored", f_min_hz=30.0), 0.005, ["f_min_hz must be < f_max_hz", "30.0", "25.0"]),
    (dict(kind="colored", f_min_hz=0.0), DT, ["f_min_hz", "> 0", "0.0"]),
    (dict(kind="colored", f_min_hz=1e-5), DT, ["f_min_hz must be >=", "1e-05"]),
    (dict(kind="colored", order=0), DT, ["order", "[1, 32]", "0"]),
    (dict(kind="colored", order=2.5), DT, ["order", "[1, 32]", "2.5"]),
    (dict(kind="pink"), DT, ["kind", "white, nm-periods, ou, colored", "'pink'"]),
    (dict(kind="white", beta=1.0), DT, ["beta", "colored", "white", "1.0"]),
    (dict(kind="ou", period_s=0.2), DT, ["period_s", "nm-periods", "ou", "0.2"]),
    (dict(kind="ou"), 0.0, ["control_dt", "> 0", "0.0"]),
]


@pytest.mark.parametrize("kwargs, dt, words", BAD)
def test_bad_parameters_name_the_value_and_the_range(kwargs, dt, words):
    with pytest.raises(ValueError) as e:
        E.ExplorationSpec(**kwargs).process(dt)
    msg = str(e.value)
    assert "\n" not in msg
    for w in words:
        assert w in msg, (w, msg)


# --------------------------------------------------------------------------- the documentation's example


def test_the_documented_example_runs():
    """The fenced python block under "Use it in your own PPO" in docs/exploration.md, run as is."""
    text = (REPO / "docs" / "exploration.md").read_text()
    section = text.split("## Use it in your own PPO", 1)[1]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert blocks, "no python example in docs/exploration.md"
    scope: dict = {"__name__": "docs_example"}
    exec(compile(blocks[0], "docs/exploration.md", "exec"), scope)  # noqa: S102
    assert "check" in scope, "the example ends with a check() of its own results"
    scope["check"]()
