r"""The likelihood ratio of nm-period actions, eq. (7), in O(l n), batch and online.

Implements the second half of Sec. IV of P. Wawrzynski, "Learning to Control a 6-Degree-of-Freedom
Walking Robot" (the paper's equation numbers are used throughout); the noise process (4) itself
is nmrl/paper/noise.py.

* Eq. (6): a_t = a~(s_t; theta) + xi_t, so within one nm-period of length l the
  action sequence A is Gaussian, eq. (7), with mean m(theta) = [a~(s_1) ... a~(s_l)]
  and covariance C = Lambda (x) Sigma, Lambda = [alpha^|i-j|]_{i,j} (eq. (5)).
* The likelihood ratio is
  grad_theta ln pi_A = [grad a~(s_1) ... grad a~(s_l)] (Lambda^-1 (x) Sigma^-1) (A - m),
  where, for l > 1, Lambda^-1 is the tridiagonal matrix

      Lambda^-1 = 1/(1 - alpha^2) * tridiag(-alpha; [1, 1+alpha^2, ..., 1+alpha^2, 1]; -alpha)

  (and the identity for l = 1). ``lambda_inv_matvec`` applies it in O(l n) with shifts,
  and ``likelihood_ratio`` contracts the result with the Jacobian through a single
  ``jax.vjp`` (no Jacobian, no solve, no inverse is ever formed).
* Delta-sampling (end of Sec. IV): only the actions at in-period indices 0, Delta, 2 Delta,
  ..., L - 1 with L = 1 + floor((l - 1)/Delta) Delta enter the likelihood; the sampled
  subsequence is again AR(1) with coefficient alpha_hat = alpha**Delta, so its
  covariance is Lambda_hat (x) Sigma with Lambda_hat = [alpha^(Delta |i-j|)].
* Online (innovation) form: with e_0 = u_0 and e_j = (u_j - alpha_hat u_{j-1}) /
  sqrt(1 - alpha_hat^2) the innovations are i.i.d. N(0, Sigma) and
  ln pi = -1/2 sum_j e_j^T Sigma^-1 e_j + const, so Lambda^-1 = D^T D for the bidiagonal
  innovation map D. ``online_lr_add`` accumulates the same likelihood ratio one sample at
  a time (see docs/noise.md for the derivation).

Everything is a pure function of arrays, jit/vmap friendly and float32 safe.
"""

from __future__ import annotations

import numbers
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from nmrl.paper.noise import concrete_scalar, is_tracer, validate

__all__ = [
    "lambda_inv_matvec",
    "lambda_inv_matvec_masked",
    "sampled_indices",
    "likelihood_ratio",
    "OnlineLR",
    "online_lr_init",
    "online_lr_cotangents",
    "online_lr_add",
    "online_lr_reset",
]

ApplyFn = Callable[[Any, jax.Array], jax.Array]


# --------------------------------------------------------------------------- Lambda^-1


def _lambda_inv_core(u: jax.Array, alpha: Any, has_next: jax.Array | None) -> jax.Array:
    """Lambda^-1 u = D^T D u, D the innovation (bidiagonal) map, using shifts only.

    Row i of the result is ``[i == 0] d_0 + [i > 0] d_i / (1 - alpha^2)
    - [i + 1 < l] alpha d_{i+1} / (1 - alpha^2)`` with d_0 = u_0 and
    d_i = u_i - alpha u_{i-1}; this reproduces the tridiagonal closed form of Sec. IV
    for l > 1 and the identity for l = 1.
    """
    alpha = jnp.asarray(alpha, u.dtype)
    q = 1.0 / (1.0 - alpha * alpha)
    zero_row = jnp.zeros_like(u[:1])
    prev = jnp.concatenate([zero_row, u[:-1]], axis=0)
    d = u - alpha * prev  # d_0 = u_0 because prev_0 = 0
    nxt = jnp.concatenate([d[1:], zero_row], axis=0)  # d_{i+1}, 0 past the end
    if has_next is not None:
        nxt = jnp.where(has_next, nxt, 0.0)
    row = jnp.arange(u.shape[0])[:, None]
    own = jnp.where(row == 0, d, q * d)
    return own - (alpha * q) * nxt


def lambda_inv_matvec(u: jax.Array, alpha: Any) -> jax.Array:
    """Return Lambda^-1 u for Lambda = [alpha^|i-j|] (Sec. IV closed form), in O(l n).

    Args:
        u: (l, n) array, l a static (Python) length, n = action dimension.
        alpha: AR coefficient in (0, 1) (may be traced).
    """
    if u.ndim != 2:
        raise ValueError(f"u must have shape (l, n), got {u.shape}")
    return _lambda_inv_core(u, alpha, None)


def lambda_inv_matvec_masked(u: jax.Array, alpha: Any, length: Any) -> jax.Array:
    """Lambda^-1 u restricted to the first ``length`` rows of a padded (l_max, n) ``u``.

    Rows ``< length`` equal ``lambda_inv_matvec(u[:length], alpha)``; rows ``>= length``
    are 0 (whatever the padding holds). ``length`` may be a traced int32 with
    1 <= length <= l_max, so one compiled program serves every period length.
    """
    if u.ndim != 2:
        raise ValueError(f"u must have shape (l_max, n), got {u.shape}")
    length = jnp.asarray(length, jnp.int32)
    row = jnp.arange(u.shape[0])[:, None]
    inside = row < length
    u = jnp.where(inside, u, 0.0)
    out = _lambda_inv_core(u, alpha, row + 1 < length)
    return jnp.where(inside, out, 0.0)


# --------------------------------------------------------------------------- likelihood ratio


def sampled_indices(l: int, delta: int) -> np.ndarray:
    """0-based in-period indices of Delta-sampling: 0, Delta, ..., L - 1.

    L = 1 + floor((l - 1)/Delta) Delta is the paper's (1-based) last sampling instant,
    so there are 1 + floor((l - 1)/Delta) samples.
    """
    validate(l=l, delta=delta)
    l, delta = int(l), int(delta)
    last = (l - 1) // delta * delta
    return np.arange(0, last + 1, delta)


def _inv_sigma2(sigma: Any, dtype: Any) -> jax.Array:
    sigma = jnp.asarray(sigma, dtype)
    return 1.0 / (sigma * sigma)


def _check_period(S: Any, A: Any) -> None:
    s_shape, a_shape = np.shape(S), np.shape(A)
    if len(s_shape) != 2 or len(a_shape) != 2:
        raise ValueError(
            f"S and A must be 2-D, (l, obs_dim) and (l, act_dim); got S{s_shape} and A{a_shape}"
        )
    if s_shape[0] != a_shape[0]:
        raise ValueError(
            f"S and A must have the same number of rows (steps of the nm-period); "
            f"got S{s_shape} and A{a_shape}"
        )
    if s_shape[0] < 1:
        raise ValueError("an nm-period must contain at least one step")


def likelihood_ratio(
    apply_fn: ApplyFn,
    params: Any,
    S: jax.Array,
    A: jax.Array,
    alpha: Any,
    sigma: Any = 1.0,
    delta: int = 1,
    length: Any = None,
) -> Any:
    """grad_theta ln pi_A_hat(A_hat; S, theta) of Sec. IV, Delta-sampling included.

    Computes [grad a~(s_1) ... grad a~(s_L)] (Lambda_hat^-1 (x) Sigma^-1) (A_hat - m) as
    one ``jax.vjp`` through ``apply_fn`` on the sampled states; Lambda_hat has
    coefficient alpha**delta.

    Args:
        apply_fn: (params, (k, obs_dim)) -> (k, act_dim), the deterministic part a~ of (6).
        params: pytree theta.
        S: (l, obs_dim) states of the nm-period; A: (l, act_dim) actions (3).
        alpha: per-step AR coefficient of (4).
        sigma: scalar or (act_dim,) standard deviations.
        delta: static sampling step Delta >= 1.
        length: optional traced int32; then S/A are padded to l_max rows and the period
            is their first ``length`` rows (rows with index % delta == 0 and index <
            length are sampled, the rest masked; padded rows must hold finite states).

    Returns:
        A pytree shaped like ``params``.
    """
    _check_period(S, A)
    validate(alpha=alpha, delta=delta)
    delta = int(delta)
    S = jnp.asarray(S)
    A = jnp.asarray(A)
    l = S.shape[0]
    alpha_hat = jnp.asarray(alpha, A.dtype) ** delta
    if length is None:
        idx = sampled_indices(l, delta)
    else:
        if not is_tracer(length):
            n = concrete_scalar(length, "length")
            if not isinstance(n, numbers.Integral) or not 1 <= int(n) <= l:
                raise ValueError(f"length must be an int in [1, {l}] (the padded size), got {length!r}")
        idx = np.arange(0, l, delta)
    S_hat, A_hat = S[idx], A[idx]
    m, vjp = jax.vjp(lambda p: apply_fn(p, S_hat), params)
    u = A_hat - m
    if length is None:
        v = lambda_inv_matvec(u, alpha_hat)
    else:
        count = (jnp.asarray(length, jnp.int32) - 1) // delta + 1
        v = lambda_inv_matvec_masked(u, alpha_hat, count)
    cot = (v * _inv_sigma2(sigma, v.dtype)).astype(m.dtype)
    (grad,) = vjp(cot)
    return grad


# --------------------------------------------------------------------------- online form


class OnlineLR(NamedTuple):
    """Running likelihood ratio of the current nm-period (innovation form).

    Attributes:
        grad: params-shaped accumulated grad_theta ln pi over the samples added so far.
        prev_s: (obs_dim,) state at the previous sample.
        prev_u: (act_dim,) noise a - a~ at the previous sample.
        count: int32 number of samples added in this period.
    """

    grad: Any
    prev_s: jax.Array
    prev_u: jax.Array
    count: jax.Array


def online_lr_init(params: Any, obs_dim: int, act_dim: int) -> OnlineLR:
    """All-zero accumulator (count = 0: the next sample starts a period)."""
    return OnlineLR(
        grad=jax.tree_util.tree_map(jnp.zeros_like, params),
        prev_s=jnp.zeros((obs_dim,)),
        prev_u=jnp.zeros((act_dim,)),
        count=jnp.zeros((), jnp.int32),
    )


def online_lr_reset(olr: OnlineLR) -> OnlineLR:
    """Start a new nm-period: zero ``grad`` and ``count``."""
    return olr._replace(
        grad=jax.tree_util.tree_map(jnp.zeros_like, olr.grad),
        count=jnp.zeros_like(olr.count),
    )


def online_lr_cotangents(
    prev_u: jax.Array, u: jax.Array, alpha_hat: Any, sigma: Any, first: Any
) -> tuple[jax.Array, jax.Array]:
    """Cotangents on (a~(s_prev), a~(s_cur)) of sample j's term of ln pi.

    With innovations e_0 = u_0, e_j = (u_j - alpha_hat u_{j-1}) / sqrt(1 - alpha_hat^2),
    ln pi = -1/2 sum_j e_j^T Sigma^-1 e_j + const, and since u = a - a~:

    * first sample: c_prev = 0, c_cur = Sigma^-1 u;
    * otherwise:    c_cur = Sigma^-1 e / r, c_prev = -alpha_hat Sigma^-1 e / r,
      r = sqrt(1 - alpha_hat^2).

    Summed over the period these give (Lambda_hat^-1 (x) Sigma^-1)(A_hat - m).
    """
    u = jnp.asarray(u)
    prev_u = jnp.asarray(prev_u, u.dtype)
    alpha_hat = jnp.asarray(alpha_hat, u.dtype)
    inv_s2 = _inv_sigma2(sigma, u.dtype)
    r = jnp.sqrt(1.0 - alpha_hat * alpha_hat)
    scaled_e = inv_s2 * (u - alpha_hat * prev_u) / (r * r)  # Sigma^-1 e / r
    c_cur = jnp.where(first, inv_s2 * u, scaled_e)
    c_prev = jnp.where(first, jnp.zeros_like(u), -alpha_hat * scaled_e)
    return c_prev, c_cur


def online_lr_add(
    olr: OnlineLR,
    apply_fn: ApplyFn,
    params: Any,
    s: jax.Array,
    u: jax.Array,
    alpha_hat: Any,
    sigma: Any = 1.0,
    active: Any = True,
) -> OnlineLR:
    """Add one sample (state ``s``, noise ``u = a - a~(s; theta)``) to the running ratio.

    One ``jax.vjp`` through ``apply_fn`` on the stacked pair [s_prev, s]. When ``active``
    (a possibly traced bool) is False the accumulator is returned unchanged; use it for
    the steps skipped by Delta-sampling (``alpha_hat = alpha**delta``).
    """
    s = jnp.asarray(s, olr.prev_s.dtype)
    u = jnp.asarray(u, olr.prev_u.dtype)
    first = olr.count == 0
    c_prev, c_cur = online_lr_cotangents(olr.prev_u, u, alpha_hat, sigma, first)
    pair = jnp.stack([olr.prev_s, s])
    m, vjp = jax.vjp(lambda p: apply_fn(p, pair), params)
    (g,) = vjp(jnp.stack([c_prev, c_cur]).astype(m.dtype))
    new = OnlineLR(
        grad=jax.tree_util.tree_map(lambda a, b: a + b.astype(a.dtype), olr.grad, g),
        prev_s=s,
        prev_u=u,
        count=olr.count + 1,
    )
    active = jnp.asarray(active, bool)
    return jax.tree_util.tree_map(lambda n, o: jnp.where(active, n, o), new, olr)
