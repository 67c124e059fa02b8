"""The C path's float64 numbers read inside JAX (no ``jax_enable_x64``) as float32 pairs.

The C physics carries MuJoCo's integration state as float64 bits (two uint32 words per number,
nmrl/physics/mujoco_c.py) and hands back qpos/qvel rounded to float32. Gymnasium's v5 tasks compute
the forward velocity as ``(x_after - x_before) / dt`` and the healthy rule as comparisons of
float64 positions with thresholds; in float32 the difference loses the bits of ``x`` (at x = 100 m
one float32 ulp is 7.6e-6 m, 1.5e-4 m/s at dt = 0.05 s) and a comparison flips within an ulp of its
threshold. Read as a pair ``hi + lo`` of float32 numbers (|lo| <= ulp(hi) / 2, together 48 bits of
the 53), the difference and the comparisons are Gymnasium's up to a relative 2^-47 of ``x``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def split(bits: jax.Array) -> tuple[jax.Array, jax.Array]:
    """float64 numbers given as their uint32 words (..., 2 n) (little-endian: the low word first,
    as :func:`nmrl.physics.mujoco_c.to_bits` writes them) -> (hi, lo) float32 (..., n) with
    hi + lo equal to the number up to 2^-47 relative. Zeros and subnormals read as 0; inf and NaN
    read as non-finite."""
    w = bits.reshape(*bits.shape[:-1], -1, 2)
    low, high = w[..., 0], w[..., 1]
    biased = ((high >> 20) & 0x7FF).astype(jnp.int32)
    e = biased - 1023
    # The 53-bit significand as three exact float32 pieces: 21 + 16 + 16 bits.
    top = ((high & 0xFFFFF) | 0x100000).astype(jnp.float32)
    mid = (low >> 16).astype(jnp.float32)
    bot = (low & 0xFFFF).astype(jnp.float32)
    a = jnp.ldexp(top, e - 20)
    b = jnp.ldexp(mid, e - 36)
    c = jnp.ldexp(bot, e - 52)
    hi = a + b
    lo = (b - (hi - a)) + c  # Fast2Sum (|a| >= |b|): the rounding error of hi, exact, plus c
    sign = jnp.where((high >> 31) == 1, -1.0, 1.0).astype(jnp.float32)
    special = biased == 0x7FF
    hi = jnp.where(biased == 0, 0.0, jnp.where(special, jnp.where((high & 0xFFFFF) | low, jnp.nan, jnp.inf), hi))
    lo = jnp.where((biased == 0) | special, 0.0, lo)
    return sign * hi, sign * lo


def constant(t: float) -> tuple[np.float32, np.float32]:
    """A float64 constant as a (hi, lo) float32 pair (inf: (inf, 0))."""
    hi = np.float32(t)
    lo = np.float32(float(t) - float(hi)) if np.isfinite(hi) else np.float32(0.0)
    return hi, lo


def diff(a: tuple[jax.Array, jax.Array], b: tuple[jax.Array, jax.Array]) -> jax.Array:
    """a - b of two pairs, rounded to float32 (the leading parts' difference first: near equal
    numbers cancel exactly there, so the small parts keep their bits)."""
    return (a[0] - b[0]) + (a[1] - b[1])


def greater(a: tuple[jax.Array, jax.Array], t: float) -> jax.Array:
    """a > t for a pair ``a`` and a float64 constant ``t`` (float64's answer unless a is within 2^-47
    relative of t)."""
    th, tl = constant(t)
    return diff(a, (th, tl)) > 0


def less(a: tuple[jax.Array, jax.Array], t: float) -> jax.Array:
    """a < t, as :func:`greater`."""
    th, tl = constant(t)
    return diff(a, (th, tl)) < 0
