r"""One linear-Gaussian family for every exploration process: sampling and exact likelihood.

Per action dimension (the same process, independent across the n dimensions), K latent AR(1)
components, each stationary N(0, 1):

    z_{k,t} = phi_k z_{k,t-1} + sqrt(1 - phi_k^2) eps_{k,t},   eps ~ N(0, 1)
    xi_t    = sigma * sum_k w_k z_{k,t},                         sum_k w_k^2 = 1,

so every xi_t ~ N(0, sigma^2) and ``cov(xi_t, xi_s) = sigma^2 sum_k w_k^2 phi_k^|t-s|`` inside one
period. At a period start (every ``period`` steps, and after :func:`reset`: a trial ended) z is drawn
afresh from N(0, I) and xi is independent of everything before: with K = 1 this is the paper's
piecewise AR process, eq. (4), with covariance (5) (alpha = phi_1, l = period).

The density of a sequence is the product of the per-step conditionals p(xi_t | xi since the last
reset), computed by a Kalman filter over z with a noiseless observation ``u_t = xi_t / sigma =
w^T z_t``: predicted belief ``N(Phi m, Phi P Phi + Q)`` (or ``N(0, I)`` at a reset), innovation
variance ``s = w^T P^- w >= min_k (1 - phi_k^2)`` (bounded away from 0 by the process noise), the
update in Joseph form ``P = A P^- A^T``, ``A = I - k w^T``, symmetrised, which keeps P symmetric
positive semi-definite in float32 when phi is close to 1.
The covariance recursion does not depend on sigma or on the data, only on the reset pattern, so
the n action dimensions share one K x K covariance. For K = 1 the filter is the AR(1) innovation
form of eq. (4): ``e_t = (u_t - phi u_{t-1}) / sqrt(1 - phi^2)``; the joint density of one period is
eq. (7) with Lambda = [phi^|i-j|]. Cost: O(T K^2 n), linear in the length, differentiable in xi.

Every function is pure and jit/vmap friendly; every leaf of :class:`Process` is an array, so points
with different processes (the same K) vmap in one program. ``sigma`` may be 1: the filter then gives
the density of a unit-variance correlation structure ``u``, and a learner that scales it by its own
``sigma_theta(s)`` adds ``-sum log sigma_theta`` (change of variables) itself.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

__all__ = [
    "NO_RESET",
    "Process",
    "NoiseState",
    "init",
    "sample",
    "reset",
    "belief",
    "log_prob",
    "filter_sequence",
    "stack",
]

#: ``period`` of a process without period resets (only trial starts, by :func:`reset`)
NO_RESET = 2**30
_LOG_2PI = math.log(2.0 * math.pi)


class Process(NamedTuple):
    """Traced parameters of one process at one control step.

    Attributes:
        phi: (K,) AR coefficients in [0, 1).
        w: (K,) component weights, ``sum w^2 = 1`` (padding components have w = 0).
        sigma: () marginal standard deviation of xi (a (n,) array also works: one per dimension).
        period: () int32 period length in steps (:data:`NO_RESET`: no period resets).
    """

    phi: jax.Array
    w: jax.Array
    sigma: jax.Array
    period: jax.Array


class NoiseState(NamedTuple):
    """Per-environment state (leading batch axis B).

    Attributes:
        z: (B, K, n) latent components (the sampler's exact state).
        i: (B,) int32 steps since the last reset (0: the next draw starts a period).
        mean: (B, K, n) filter belief about z given the xi observed since the last reset (units of sigma).
        cov: (B, K, K) its covariance (shared by the n action dimensions).
    """

    z: jax.Array
    i: jax.Array
    mean: jax.Array
    cov: jax.Array


def _q(phi: jax.Array) -> jax.Array:
    """1 - phi^2 as (1 - phi)(1 + phi): 1 - phi is exact in float32 for phi in [0.5, 1]."""
    return (1.0 - phi) * (1.0 + phi)


def _filter_step(proc: Process, mean: jax.Array, cov: jax.Array, u: jax.Array, fresh: jax.Array
                 ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """One Kalman step for one environment: belief about z_{t-1} -> about z_t given ``u_t = w^T z_t``.

    Returns (log p(u_t | past) summed over the n dimensions, mean (K, n), cov (K, K)).
    """
    phi, w = proc.phi.astype(u.dtype), proc.w.astype(u.dtype)
    eye = jnp.eye(phi.shape[0], dtype=u.dtype)
    # elementwise products and sums only: K is small, and batched K x K matmuls are slow on CPU
    m_pred = jnp.where(fresh, 0.0, phi[:, None] * mean)
    P_pred = jnp.where(fresh, eye, phi[:, None] * cov * phi[None, :] + eye * _q(phi)[None, :])
    Pw = jnp.sum(P_pred * w[None, :], axis=-1)
    s = jnp.sum(w * Pw)  # innovation variance (units of sigma^2), >= min_k (1 - phi_k^2) * sum_k w_k^2
    e = u - jnp.sum(w[:, None] * m_pred, axis=0)  # (n,)
    k = Pw / s
    new_mean = m_pred + k[:, None] * e[None, :]
    # Joseph form (I - k w^T) P (I - k w^T)^T expanded (no observation noise): first-order errors in
    # k cancel, and for K = 1 it is exactly 0
    kP = k[:, None] * Pw[None, :]
    new_cov = P_pred - kP - kP.T + s * (k[:, None] * k[None, :])
    new_cov = 0.5 * (new_cov + new_cov.T)
    n = u.shape[-1]
    logp = -0.5 * (n * (_LOG_2PI + jnp.log(s)) + jnp.sum(e * e) / s)
    return logp, new_mean, new_cov


def _sum_log_sigma(sigma: jax.Array, n: int, dtype) -> jax.Array:
    return jnp.sum(jnp.broadcast_to(jnp.log(jnp.asarray(sigma, dtype)), (n,)))


def init(proc: Process, key: jax.Array, batch: int, act_dim: int) -> NoiseState:
    """State of ``batch`` environments before their first draw (i = 0: the first draw starts a
    period; belief = the prior N(0, I)); z is a stationary draw."""
    K = proc.phi.shape[0]
    return NoiseState(
        z=jax.random.normal(key, (batch, K, act_dim), jnp.float32),
        i=jnp.zeros((batch,), jnp.int32),
        mean=jnp.zeros((batch, K, act_dim), jnp.float32),
        cov=jnp.broadcast_to(jnp.eye(K, dtype=jnp.float32), (batch, K, K)),
    )


def sample(proc: Process, state: NoiseState, key: jax.Array
           ) -> tuple[jax.Array, jax.Array, jax.Array, NoiseState]:
    """Draw xi_t for every environment.

    Returns:
        ``(xi (B, n), logp (B,), fresh (B,) bool, new_state)``: ``logp`` is log p(xi_t | xi since the
        last reset) summed over the n dimensions (what :func:`log_prob` gives for the same sequence);
        ``fresh`` is True where this draw started a period or a trial.
    """
    z = state.z
    eps = jax.random.normal(key, z.shape, z.dtype)
    fresh = state.i == 0
    phi = proc.phi.astype(z.dtype)[None, :, None]
    z_new = jnp.where(fresh[:, None, None], eps, phi * z + jnp.sqrt(_q(phi)) * eps)
    u = jnp.einsum("k,bkn->bn", proc.w.astype(z.dtype), z_new)
    logp, mean, cov = jax.vmap(_filter_step, in_axes=(None, 0, 0, 0, 0))(proc, state.mean, state.cov, u, fresh)
    n = u.shape[-1]
    xi = jnp.asarray(proc.sigma, z.dtype) * u
    logp = logp - _sum_log_sigma(proc.sigma, n, z.dtype)
    i = jnp.remainder(state.i + 1, proc.period).astype(jnp.int32)
    return xi, logp, fresh, NoiseState(z=z_new, i=i, mean=mean, cov=cov)


def reset(proc: Process, state: NoiseState, mask: jax.Array) -> NoiseState:
    """Where ``mask`` (B,): the next draw starts afresh (i = 0, belief = the prior N(0, I))."""
    K = proc.phi.shape[0]
    eye = jnp.eye(K, dtype=state.cov.dtype)
    return state._replace(
        i=jnp.where(mask, 0, state.i).astype(jnp.int32),
        mean=jnp.where(mask[:, None, None], 0.0, state.mean),
        cov=jnp.where(mask[:, None, None], eye, state.cov),
    )


def belief(state: NoiseState) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``(mean (B, K, n), cov (B, K, K), i (B,))``: what a learner stores at a rollout fragment's start
    to evaluate :func:`log_prob` of the fragment later."""
    return state.mean, state.cov, state.i


def filter_sequence(proc: Process, mean0: jax.Array, cov0: jax.Array, xi: jax.Array, fresh: jax.Array
                    ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """:func:`log_prob` of one environment's sequence plus the belief after its last step.

    Returns ``(logp (T,), mean (K, n), cov (K, K))``.
    """
    xi = jnp.asarray(xi)
    dtype = xi.dtype
    sigma = jnp.asarray(proc.sigma, dtype)
    u = xi / sigma
    n = xi.shape[-1]

    def step(carry, inp):
        m, P = carry
        u_t, f_t = inp
        lp, m, P = _filter_step(proc, m, P, u_t, f_t)
        return (m, P), lp

    (m, P), logp = jax.lax.scan(step, (jnp.asarray(mean0, dtype), jnp.asarray(cov0, dtype)),
                                (u, jnp.asarray(fresh, bool)))
    return logp - _sum_log_sigma(sigma, n, dtype), m, P


def log_prob(proc: Process, mean0: jax.Array, cov0: jax.Array, xi: jax.Array, fresh: jax.Array) -> jax.Array:
    """Per-step exact conditional log-density of one environment's sequence ``xi (T, n)``.

    The Kalman filter starts from the belief ``(mean0 (K, n), cov0 (K, K))`` about z before the first
    step (stored by :func:`belief` at the fragment's start, computed at rollout time under the
    behaviour policy); where ``fresh[t]`` the belief is reset to the prior before step t. Returns
    (T,), each entry log p(xi_t | xi since the last reset) summed over the n dimensions; linear in T,
    differentiable in xi (vmap over environments).
    """
    return filter_sequence(proc, mean0, cov0, xi, fresh)[0]


def stack(procs: list[Process]) -> Process:
    """Processes with the same K stacked on a leading axis (for one vmapped program)."""
    return jax.tree.map(lambda *x: jnp.stack(x), *procs)
