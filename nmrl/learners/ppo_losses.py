"""PPO's loss pieces as pure functions: GAE with truncation and termination, the clipped surrogate.

:func:`gae` is Brax PPO's ``compute_gae`` (time-major ``(T, ...)``): with ``d_t = 1 - termination_t``,
``m_t = 1 - truncation_t``,

    delta_t = m_t (r_t + gamma d_t V_{t+1} - V_t),      V_T = V(s_T) (bootstrap),
    A'_t    = delta_t + gamma lambda d_t m_t A'_{t+1},   vs_t = A'_t + V_t,
    A_t     = m_t (r_t + gamma d_t vs_{t+1} - V_t),      vs_T = V(s_T),

so a terminated step bootstraps with 0, and a truncated step (the paper's artificial stop, Sec. V-D:
the next observation is already the next trial's) gives no learning signal at all (A_t = 0 and
vs_t = V_t) and cuts the trace. :func:`clipped_surrogate` is PPO's objective (Schulman et al. 2017,
eq. (7)) with the ratio of the exact conditional densities; :func:`value_loss` Brax's
``0.5 * vf_coef * mean((vs - V)^2)``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def gae(rewards: jax.Array, values: jax.Array, bootstrap: jax.Array, termination: jax.Array,
        truncation: jax.Array, gamma: jax.Array, lam: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(vs, advantages)`` of time-major ``(T, ...)`` arrays (``bootstrap``: V(s_T), shape ``(...)``);
    both without gradient (module docstring)."""
    mask = 1.0 - truncation
    cont = 1.0 - termination
    v_next = jnp.concatenate([values[1:], bootstrap[None]], axis=0)
    deltas = (rewards + gamma * cont * v_next - values) * mask

    def back(acc, inp):
        m, d, c = inp
        acc = d + gamma * c * m * lam * acc
        return acc, acc

    _, vs_minus_v = jax.lax.scan(back, jnp.zeros_like(bootstrap), (mask, deltas, cont), reverse=True)
    vs = vs_minus_v + values
    vs_next = jnp.concatenate([vs[1:], bootstrap[None]], axis=0)
    adv = (rewards + gamma * cont * vs_next - values) * mask
    return jax.lax.stop_gradient(vs), jax.lax.stop_gradient(adv)


def normalize_advantages(adv: jax.Array, total: jax.Array, count: jax.Array, total_sq: jax.Array) -> jax.Array:
    """``(adv - mean) / (std + 1e-8)`` over a minibatch given its sum, count and sum of squares
    (summed over shards by the caller; Brax normalises over the minibatch, truncated zeros included)."""
    mean = total / count
    std = jnp.sqrt(jnp.maximum(total_sq / count - mean * mean, 0.0))
    return (adv - mean) / (std + 1e-8)


def clipped_surrogate(logp: jax.Array, logp_old: jax.Array, adv: jax.Array, clip_eps: jax.Array
                      ) -> tuple[jax.Array, dict]:
    """Per-sample PPO objective to *minimise*, ``-min(rho A, clip(rho, 1-eps, 1+eps) A)`` with
    ``rho = exp(logp - logp_old)``, and per-sample diagnostics (clipped or not, the k3 estimate
    ``(rho - 1) - log rho`` of KL(old || new))."""
    log_rho = logp - logp_old
    rho = jnp.exp(log_rho)
    s1 = rho * adv
    s2 = jnp.clip(rho, 1.0 - clip_eps, 1.0 + clip_eps) * adv
    diag = {"clipped": (jnp.abs(rho - 1.0) > clip_eps).astype(jnp.float32),
            "approx_kl": (rho - 1.0) - log_rho, "ratio": rho}
    return -jnp.minimum(s1, s2), diag


def value_loss(values: jax.Array, vs: jax.Array, vf_coef: jax.Array) -> jax.Array:
    """Per-sample ``0.5 * vf_coef * (vs - V)^2`` (Brax: vf_coefficient 0.5 by default)."""
    err = vs - values
    return 0.5 * vf_coef * err * err
