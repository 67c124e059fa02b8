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


def period_gae(rewards: jax.Array, values: jax.Array, bootstrap: jax.Array, termination: jax.Array,
               truncation: jax.Array, start: jax.Array, gamma: jax.Array, lam: jax.Array
               ) -> tuple[jax.Array, jax.Array]:
    """GAE over periods as wholes (the paper's learning on nm-periods, Sec. IV): time-major ``(T, ...)``
    arrays and ``start`` (1 where a period begins; the unroll's first step always starts a segment).

    Each segment, from a start to the step before the next one, is one transition from the state at
    its start with reward ``R = sum_k gamma^k r_{t+k}`` and discount ``gamma^len``; the critic is read
    at segment starts only (there fresh noise makes the state Markov), the last segment bootstraps on
    ``V(s_T)``. With ``c`` = 1 - termination and ``m`` = 1 - truncation of the segment's last step:

        delta_p = m (R_p + gamma^len c V_{p+1} - V_p),   A'_p = delta_p + (gamma lam)^len c m A'_{p+1},
        vs_p = A'_p + V_p,                               A_p = m (R_p + gamma^len c vs_{p+1} - V_p),

    with vs after the last segment V(s_T): :func:`gae`'s (Brax's) form with a period as the step, so
    that periods of one control step give :func:`gae` exactly, and a truncated segment gives no
    learning signal (as :func:`gae` treats a truncated step).
    Returns ``(vs, advantages)`` at segment starts and 0 elsewhere, without gradient."""
    T = rewards.shape[0]
    start = jnp.asarray(start, rewards.dtype).at[0].set(1.0)
    last = jnp.concatenate([start[1:], jnp.ones_like(start[:1])], axis=0)  # the step before a start
    zero = jnp.zeros_like(bootstrap)

    def back(carry, inp):
        G, gam, lamk, c_end, m_end, v_end, a_end, v_next, a_next = carry
        r, v, st, ls, term, trunc = inp
        G = jnp.where(ls > 0, r, r + gamma * G)
        gam = jnp.where(ls > 0, gamma, gamma * gam)
        lamk = jnp.where(ls > 0, lam, lam * lamk)
        c_end = jnp.where(ls > 0, 1.0 - term, c_end)
        m_end = jnp.where(ls > 0, 1.0 - trunc, m_end)
        v_end = jnp.where(ls > 0, v_next, v_end)
        a_end = jnp.where(ls > 0, a_next, a_end)
        delta = m_end * (G + gam * c_end * v_end - v)
        a = delta + gam * lamk * c_end * m_end * a_end  # A'_p, the trace
        adv = m_end * (G + gam * c_end * (a_end + v_end) - v)  # A_p, with the next start's vs
        is_start = st > 0
        v_next = jnp.where(is_start, v, v_next)
        a_next = jnp.where(is_start, a, a_next)
        out = (jnp.where(is_start, a + v, 0.0), jnp.where(is_start, adv, 0.0))
        return (G, gam, lamk, c_end, m_end, v_end, a_end, v_next, a_next), out

    one = jnp.ones_like(bootstrap)
    carry0 = (zero, one, one, one, one, bootstrap, zero, bootstrap, zero)
    _, (vs, adv) = jax.lax.scan(back, carry0, (rewards, values, start, last, termination, truncation),
                                reverse=True, length=T)
    return jax.lax.stop_gradient(vs), jax.lax.stop_gradient(adv)


def segment_sums(x: jax.Array, start: jax.Array) -> jax.Array:
    """Time-major ``(T, ...)``: at each segment start the sum of ``x`` over its segment (to the step
    before the next start), 0 elsewhere; the first step always starts a segment. With ``x`` the
    per-step log-ratios of the conditional densities, this is the log-ratio of the period's density
    (eq. (7), by the chain rule)."""
    start = jnp.asarray(start, x.dtype).at[0].set(1.0)
    nxt = jnp.concatenate([start[1:], jnp.ones_like(start[:1])], axis=0)

    def back(acc, inp):
        xi, st, n = inp
        acc = xi + jnp.where(n > 0, 0.0, acc)
        return acc, jnp.where(st > 0, acc, 0.0)

    _, out = jax.lax.scan(back, jnp.zeros_like(x[0]), (x, start, nxt), reverse=True)
    return out
