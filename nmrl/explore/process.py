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

:func:`sample` draws from the same factorisation: xi_t from its conditional law given the earlier xi
(the filter's prediction), then the filter update. The sequence then has exactly the joint law above
(chain rule), the step costs n normal draws whatever K, and its ``logp`` is the density it was
drawn from.

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
        z: (B, K, n) E[z_t | xi since the last reset], the latent components as far as the xi
            determine them (for K = 1, z itself; the sampler needs no other state than the belief).
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


def _predict(proc: Process, mean: jax.Array, cov: jax.Array, fresh: jax.Array
             ) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """Belief about z_{t-1} -> predicted belief about z_t for one environment.

    Returns ``(m_pred (K, n), P_pred (K, K), P_pred w (K,), s)`` with ``s = w^T P_pred w``, the
    variance of ``u_t = w^T z_t`` given the past (units of sigma^2); at a reset the prior N(0, I).
    """
    dtype = mean.dtype
    phi, w = proc.phi.astype(dtype), proc.w.astype(dtype)
    eye = jnp.eye(phi.shape[0], dtype=dtype)
    # elementwise products and sums only: K is small, and batched K x K matmuls are slow on CPU
    m_pred = jnp.where(fresh, 0.0, phi[:, None] * mean)
    P_pred = jnp.where(fresh, eye, phi[:, None] * cov * phi[None, :] + eye * _q(phi)[None, :])
    Pw = jnp.sum(P_pred * w[None, :], axis=-1)
    s = jnp.sum(w * Pw)  # >= min_k (1 - phi_k^2) sum_k w_k^2: the process noise keeps it away from 0
    return m_pred, P_pred, Pw, s


def _update(m_pred: jax.Array, P_pred: jax.Array, Pw: jax.Array, s: jax.Array, e: jax.Array
            ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Condition the predicted belief on the innovation ``e = u_t - w^T m_pred`` (n,).

    Returns ``(log p(u_t | past) summed over the n dimensions, mean (K, n), cov (K, K))``.
    """
    k = Pw / s
    new_mean = m_pred + k[:, None] * e[None, :]
    # Joseph form (I - k w^T) P (I - k w^T)^T expanded (no observation noise): first-order errors in
    # k cancel, and for K = 1 it is exactly 0
    kP = k[:, None] * Pw[None, :]
    new_cov = P_pred - kP - kP.T + s * (k[:, None] * k[None, :])
    new_cov = 0.5 * (new_cov + new_cov.T)
    n = e.shape[-1]
    logp = -0.5 * (n * (_LOG_2PI + jnp.log(s)) + jnp.sum(e * e) / s)
    return logp, new_mean, new_cov


def _filter_step(proc: Process, mean: jax.Array, cov: jax.Array, u: jax.Array, fresh: jax.Array
                 ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """One Kalman step for one environment: belief about z_{t-1} -> about z_t given ``u_t = w^T z_t``.

    Returns (log p(u_t | past) summed over the n dimensions, mean (K, n), cov (K, K)).
    """
    m_pred, P_pred, Pw, s = _predict(proc, mean.astype(u.dtype), cov.astype(u.dtype), fresh)
    e = u - jnp.sum(proc.w.astype(u.dtype)[:, None] * m_pred, axis=0)
    return _update(m_pred, P_pred, Pw, s, e)


def _sum_log_sigma(sigma: jax.Array, n: int, dtype) -> jax.Array:
    return jnp.sum(jnp.broadcast_to(jnp.log(jnp.asarray(sigma, dtype)), (n,)))


def init(proc: Process, key: jax.Array, batch: int, act_dim: int) -> NoiseState:
    """State of ``batch`` environments before their first draw: i = 0 (the first draw starts a
    period), belief = the prior N(0, I). (``key`` is not needed: the first draw is fresh.)"""
    del key
    K = proc.phi.shape[0]
    return NoiseState(
        z=jnp.zeros((batch, K, act_dim), jnp.float32),
        i=jnp.zeros((batch,), jnp.int32),
        mean=jnp.zeros((batch, K, act_dim), jnp.float32),
        cov=jnp.broadcast_to(jnp.eye(K, dtype=jnp.float32), (batch, K, K)),
    )


def sample(proc: Process, state: NoiseState, key: jax.Array
           ) -> tuple[jax.Array, jax.Array, jax.Array, NoiseState]:
    """Draw xi_t for every environment.

    xi_t is drawn from its conditional law given the xi since the last reset, N(sigma w^T m_pred,
    sigma^2 s), the filter's prediction, and the belief is then updated with it: by the chain rule
    the sequence has exactly the process's joint law, with n normal draws per step whatever K.

    Returns:
        ``(xi (B, n), logp (B,), fresh (B,) bool, new_state)``: ``logp`` is log p(xi_t | xi since the
        last reset) summed over the n dimensions (what :func:`log_prob` gives for the same sequence);
        ``fresh`` is True where this draw started a period or a trial.
    """
    dtype = state.mean.dtype
    B, _, n = state.mean.shape
    fresh = state.i == 0
    m_pred, P_pred, Pw, s = jax.vmap(_predict, in_axes=(None, 0, 0, 0))(proc, state.mean, state.cov, fresh)
    e = jnp.sqrt(s)[:, None] * jax.random.normal(key, (B, n), dtype)
    u = jnp.einsum("k,bkn->bn", proc.w.astype(dtype), m_pred) + e
    logp, mean, cov = jax.vmap(_update)(m_pred, P_pred, Pw, s, e)
    xi = jnp.asarray(proc.sigma, dtype) * u
    logp = logp - _sum_log_sigma(proc.sigma, n, dtype)
    i = jnp.remainder(state.i + 1, proc.period).astype(jnp.int32)
    return xi, logp, fresh, NoiseState(z=mean, i=i, mean=mean, cov=cov)


def reset(proc: Process, state: NoiseState, mask: jax.Array) -> NoiseState:
    """Where ``mask`` (B,): the next draw starts afresh (i = 0, belief = the prior N(0, I))."""
    K = proc.phi.shape[0]
    eye = jnp.eye(K, dtype=state.cov.dtype)
    return NoiseState(
        z=jnp.where(mask[:, None, None], 0.0, state.z),
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
