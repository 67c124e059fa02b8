r"""Piecewise autoregressive exploration noise, eq. (4), and the checks of its hyper-parameters.

Implements the first half of Sec. IV of P. Wawrzynski, "Learning to Control a 6-Degree-of-Freedom
Walking Robot" (the paper's equation numbers are used throughout); the likelihood ratio of the
actions this noise makes, eq. (7), is nmrl/paper/likelihood.py.

* Eq. (4), the *piecewise independent autoregressive process*::

      xi_t = eps_t                                       if t = t_k (a period starts)
      xi_t = alpha * xi_{t-1} + sqrt(1 - alpha^2) eps_t   otherwise,

  with eps_t ~ N(0, Sigma) i.i.d. and alpha in (0, 1). Here the standardized process
  is generated (eps_t ~ N(0, I)) and then scaled by ``sigma``, Sigma = diag(sigma**2).
* Eq. (5): every xi_t ~ N(0, Sigma); cov(xi_t, xi_t') = alpha^|t - t'| Sigma inside one
  nm-period and 0 across periods.
* :func:`validate` checks alpha (eq. (4)), the period length l and the sampling step Delta
  wherever they are concrete (traced values pass: one program serves every value).

Everything is a pure function of arrays, jit/vmap friendly and float32 safe.
"""

from __future__ import annotations

import numbers
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np


__all__ = [
    "validate",
    "piecewise_ar",
    "ARState",
    "ar_init",
    "ar_step",
]


# --------------------------------------------------------------------------- validation


def is_tracer(x: Any) -> bool:
    """Whether ``x`` is a traced value (inside jit/vmap: its number cannot be checked)."""
    return isinstance(x, jax.core.Tracer)


def concrete_scalar(x: Any, name: str) -> Any:
    """Return ``x`` as a Python scalar, or None when it is traced (cannot be checked)."""
    if is_tracer(x):
        return None
    if isinstance(x, bool | np.bool_):
        raise ValueError(f"{name} must be a number, got the bool {x!r}")
    if isinstance(x, numbers.Number):
        return x
    arr = np.asarray(x)
    if arr.ndim != 0:
        raise ValueError(f"{name} must be a scalar, got an array of shape {arr.shape}")
    if arr.dtype == np.bool_:
        raise ValueError(f"{name} must be a number, got the bool {x!r}")
    return arr.item()


def validate(alpha: Any = None, l: Any = None, delta: Any = None) -> None:
    """Check the hyper-parameters of eq. (4) and of Delta-sampling.

    ``alpha`` must be a real number in the open interval (0, 1) (eq. (4)); ``l`` (the
    nm-period length) and ``delta`` (the sampling step Delta) must be integers >= 1.
    ``None`` arguments are skipped, and so are traced values (they cannot be inspected).

    Raises:
        ValueError: naming the bad value and the allowed range.
    """
    if alpha is not None:
        a = concrete_scalar(alpha, "alpha")
        if a is not None:
            if not isinstance(a, numbers.Real) or not (0.0 < float(a) < 1.0):
                raise ValueError(
                    f"alpha must be a float in the open interval (0, 1) (eq. (4)), got {alpha!r}"
                )
    for name, value, what in (("l", l, "nm-period length"), ("delta", delta, "sampling step Delta")):
        if value is None:
            continue
        v = concrete_scalar(value, name)
        if v is None:
            continue
        if not isinstance(v, numbers.Integral) or int(v) < 1:
            raise ValueError(f"{name} ({what}) must be an int >= 1, got {value!r}")


# --------------------------------------------------------------------------- eq. (4)


class ARState(NamedTuple):
    """Carry of the piecewise AR process (4).

    Attributes:
        xi: (dim,) last standardized noise value xi_{t-1} (in units of sigma).
        i: int32 scalar, in-period index of the NEXT step (0 => the next step starts
            a new nm-period).
    """

    xi: jax.Array
    i: jax.Array


def ar_init(dim: int) -> ARState:
    """Initial carry: xi = 0 and i = 0 (the first step starts a period)."""
    return ARState(xi=jnp.zeros((dim,)), i=jnp.zeros((), jnp.int32))


def ar_step(
    state: ARState,
    eps: jax.Array,
    alpha: Any,
    l: Any,
    sigma: Any = 1.0,
    reset: Any = False,
) -> tuple[ARState, jax.Array]:
    """One step of eq. (4).

    Args:
        state: the carry (batched under vmap if desired).
        eps: (dim,) standard normal draw.
        alpha: AR coefficient in (0, 1) (may be traced).
        l: nm-period length (Python int or traced int32 scalar; one program serves all l).
        sigma: scalar or (dim,) standard deviations, Sigma = diag(sigma**2).
        reset: (traced) bool, force this step to start a new period.

    Returns:
        (new_state, sigma * xi_t). ``new_state.i = (i_used + 1) % l`` with
        ``i_used = 0 if reset else state.i``.
    """
    i_used = jnp.where(reset, jnp.zeros_like(state.i), state.i)
    start = i_used == 0
    alpha = jnp.asarray(alpha, state.xi.dtype)
    eps = jnp.asarray(eps, state.xi.dtype)
    continued = alpha * state.xi + jnp.sqrt(1.0 - alpha * alpha) * eps
    xi = jnp.where(start, eps, continued)
    new_i = jnp.remainder(i_used + 1, jnp.asarray(l, jnp.int32)).astype(jnp.int32)
    sigma = jnp.asarray(sigma, xi.dtype)
    return ARState(xi=xi, i=new_i), sigma * xi


def piecewise_ar(
    key: jax.Array, num_steps: int, dim: int, alpha: Any, l: Any, sigma: Any = 1.0
) -> jax.Array:
    """Sample ``num_steps`` values of the process (4); periods start at t = 0, l, 2l, ...

    Returns:
        (num_steps, dim) array; row t is sigma * xi_t. The last period is shorter when
        l does not divide num_steps.
    """
    validate(alpha=alpha, l=l)
    eps = jax.random.normal(key, (num_steps, dim), jnp.float32)

    def body(state: ARState, e: jax.Array) -> tuple[ARState, jax.Array]:
        return ar_step(state, e, alpha, l, sigma)

    _, xs = jax.lax.scan(body, ar_init(dim), eps)
    return xs
