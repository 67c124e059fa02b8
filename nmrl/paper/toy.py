r"""The Sec. II toy problem: REINFORCE variance vs time discretization.

State = 1-D velocity, action = acceleration a_t ~ N(theta, sigma_a^2) held for one step of
length delta_t; an episode lasts 1 s (T = 1/delta_t steps), s_0 = 0, s_t = s_{t-1} + delta_t a_t,
and the only reward is r = s_T + y, y ~ N(0, sigma_y^2). J(theta) = theta, so grad J = 1.

* Stationary policy, episodic REINFORCE: g = (r - c) sum_t d ln pi(a_t)/d theta, whose
  variance is the paper's formula (1):  V g = 2 + ((c - theta)^2 + sigma_y^2) / (delta_t sigma_a^2).
* Piecewise non-Markov policy (Sec. III-IV): a_t = theta + sigma_a xi_t with xi the
  piecewise AR process (4), periods of ``l`` steps, and
  g = (r - c) sum_k d ln pi_A(A_k)/d theta (the nm-period likelihood ratio). Because
  (r - c, G = sum_k d ln pi_A/d theta) is jointly Gaussian (plus y),
  V g = 1 + ((c - theta)^2 + sigma_y^2 + V s_T) V G, with
  V G = sum_k 1^T Lambda_k^-1 1 / sigma_a^2 and V s_T = delta_t^2 sigma_a^2 sum_k 1^T Lambda_k 1
  (derived in docs/noise.md; for l = 1 it reduces to (1)).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from nmrl.paper.likelihood import likelihood_ratio
from nmrl.paper.noise import piecewise_ar, validate

__all__ = [
    "num_steps",
    "period_lengths",
    "stationary_variance",
    "nm_variance",
    "sample_stationary",
    "sample_nm",
    "alpha_per_step",
    "nm_period_length",
    "variance_with_se",
]


def num_steps(delta_t: float) -> int:
    """T = 1/delta_t steps in the 1-s episode (delta_t must divide 1 up to rounding)."""
    T = int(round(1.0 / delta_t))
    if T < 1 or abs(T * delta_t - 1.0) > 1e-6:
        raise ValueError(f"delta_t must be 1/T for an integer T >= 1, got {delta_t!r}")
    return T


def period_lengths(T: int, l: int) -> list[int]:
    """Lengths l_k of the nm-periods covering T steps (the last one may be shorter)."""
    validate(l=l)
    return [l] * (T // l) + ([T % l] if T % l else [])


def stationary_variance(delta_t: float, theta: float, c: float, sigma_a: float, sigma_y: float) -> float:
    """Formula (1): V g = 2 + ((c - theta)^2 + sigma_y^2) / (delta_t sigma_a^2)."""
    return 2.0 + ((c - theta) ** 2 + sigma_y**2) / (delta_t * sigma_a**2)


def _sum_lambda(m: int, alpha: float) -> float:
    """1^T Lambda 1 for Lambda = [alpha^|i-j|] of size m."""
    return m * (1 + alpha) / (1 - alpha) - 2 * alpha * (1 - alpha**m) / (1 - alpha) ** 2


def _sum_lambda_inv(m: int, alpha: float) -> float:
    """1^T Lambda^-1 1 (tridiagonal closed form summed): (m (1 - alpha) + 2 alpha) / (1 + alpha)."""
    return (m * (1 - alpha) + 2 * alpha) / (1 + alpha)


def nm_variance(
    delta_t: float, l: int, alpha: float, theta: float, c: float, sigma_a: float, sigma_y: float
) -> float:
    """Closed-form variance of the nm-period REINFORCE estimator (see module docstring)."""
    validate(alpha=alpha, l=l)
    T = num_steps(delta_t)
    lengths = period_lengths(T, l)
    v_G = sum(_sum_lambda_inv(m, alpha) for m in lengths) / sigma_a**2
    v_X = delta_t**2 * sigma_a**2 * sum(_sum_lambda(m, alpha) for m in lengths)
    return 1.0 + ((c - theta) ** 2 + sigma_y**2 + v_X) * v_G


def sample_stationary(
    key: jax.Array, delta_t: float, n: int, theta: float, c: float, sigma_a: float, sigma_y: float
) -> jax.Array:
    """n Monte Carlo draws of the stationary REINFORCE estimator g (Sec. II)."""
    T = num_steps(delta_t)
    k_a, k_y = jax.random.split(key)
    a = theta + sigma_a * jax.random.normal(k_a, (n, T))
    y = sigma_y * jax.random.normal(k_y, (n,))
    r = delta_t * a.sum(axis=1) + y
    score = ((a - theta) / sigma_a**2).sum(axis=1)  # sum_t d ln N(a_t; theta, sigma_a^2)/d theta
    return (r - c) * score


def _mean_fn(theta: jax.Array, S: jax.Array) -> jax.Array:
    """a~(s; theta) = theta for every state: the toy's 'policy network'."""
    return jnp.broadcast_to(theta, (S.shape[0], 1))


def sample_nm(
    key: jax.Array,
    delta_t: float,
    n: int,
    l: int,
    alpha: float,
    theta: float,
    c: float,
    sigma_a: float,
    sigma_y: float,
) -> jax.Array:
    """n Monte Carlo draws of the nm-period REINFORCE estimator g = (r - c) sum_k grad ln pi_A.

    The noise is the piecewise AR process (4) with periods of ``l`` steps; the per-period
    likelihood ratio is ``nmrl.paper.likelihood.likelihood_ratio`` (vmapped over samples and periods).
    """
    T = num_steps(delta_t)
    k_xi, k_y = jax.random.split(key)
    xi = piecewise_ar(k_xi, T, n, alpha, l).T  # (n, T): column j of the scan is sequence j
    a = theta + sigma_a * xi
    y = sigma_y * jax.random.normal(k_y, (n,))
    r = delta_t * a.sum(axis=1) + y
    theta_arr = jnp.asarray(theta, jnp.float32)

    def period_lr(A_k: jax.Array) -> jax.Array:  # A_k: (m,) actions of one period
        S_k = jnp.zeros((A_k.shape[0], 1))
        return likelihood_ratio(_mean_fn, theta_arr, S_k, A_k[:, None], alpha, sigma_a)

    score = jnp.zeros((n,))
    start = 0
    for m in sorted(set(period_lengths(T, l)), reverse=True):
        count = sum(1 for x in period_lengths(T, l) if x == m)
        block = a[:, start : start + count * m].reshape(n * count, m)
        lr = jax.vmap(period_lr)(block).reshape(n, count).sum(axis=1)
        score = score + lr
        start += count * m
    return (r - c) * score


def alpha_per_step(delta_t: float, rho: float = 0.8, tau: float = 0.02) -> float:
    """Per-step AR coefficient giving correlation ``rho`` over ``tau`` seconds: rho**(delta_t/tau)."""
    return float(rho ** (delta_t / tau))


def nm_period_length(delta_t: float, duration: float) -> int:
    """Steps per nm-period of fixed ``duration`` seconds (at least 1)."""
    return max(1, int(math.floor(duration / delta_t + 1e-9)))


def variance_with_se(g: np.ndarray) -> tuple[float, float, float, float]:
    """Sample mean, its SE, sample variance and the SE of the variance (from the 4th moment)."""
    g = np.asarray(g, np.float64)
    n = g.size
    mean = g.mean()
    dev = g - mean
    var = float(np.mean(dev**2) * n / (n - 1))
    m4 = float(np.mean(dev**4))
    se_var = math.sqrt(max(m4 - var**2, 0.0) / n)
    return float(mean), math.sqrt(var / n), var, se_var
