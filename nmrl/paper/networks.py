"""Actor a~(s; theta) and critic V~(s; v) of Sec. V-C (flax).

Both are two-layer perceptrons: M arctan ("sigmoidal") hidden units, a bias on every neuron and a
linear output layer. Hidden weights and biases are drawn from N(0, 1); output weights and biases
are zero, so the initial policy is a~ = 0 (the robot stands still under its PD torque) and the
initial value estimate is V~ = 0.

The arctan. XLA's (``jnp.arctan``, lowered to a general atan2) costs ~7 ns per element on a CPU
and was most of the batched actor-critic's work per control step (~700 hidden units evaluated per
environment step: the actor at s and at the previous sample, the critic at the period's start and
at the next state; docs/performance.md). :func:`arctan_fast` is Cephes' single-precision atanf
(range reduction at tan(pi/8) and tan(3pi/8), a degree-9 odd polynomial): ~0.5 ns per element,
within 3 float32 ulp of the exact arctan where XLA's is within 5 (tests/test_networks.py), with
the exact derivative 1 / (1 + x^2) as its JVP, as ``jnp.arctan`` has. ``ARCTANS`` names both: the
config field ``arctan`` picks one; runs made before it existed used ``"xla"`` and keep it, so they
continue bit for bit.
"""

from __future__ import annotations

from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

Params = Any

_TAN_3PI_8 = 2.414213562373095
_TAN_PI_8 = 0.4142135623730950


@jax.custom_jvp
def arctan_fast(x: jax.Array) -> jax.Array:
    """arctan(x) in float32 by Cephes' atanf: |x| is reduced to [-tan(pi/8), tan(pi/8)] (x > tan(3pi/8):
    pi/2 + arctan(-1/x); x > tan(pi/8): pi/4 + arctan((x-1)/(x+1))) and a polynomial in x^2 does the
    rest; elementwise selects, no branches, so XLA vectorises it."""
    t = jnp.abs(x)
    big, mid = t > _TAN_3PI_8, t > _TAN_PI_8
    r = jnp.where(big, -1.0 / jnp.where(big, t, 1.0), jnp.where(mid, (t - 1.0) / (t + 1.0), t))
    base = jnp.where(big, jnp.float32(jnp.pi / 2), jnp.where(mid, jnp.float32(jnp.pi / 4), jnp.float32(0.0)))
    z = r * r
    p = (((8.05374449538e-2 * z - 1.38776856032e-1) * z + 1.99777106478e-1) * z - 3.33329491539e-1) * z
    y = (p * r + r) + base
    return jnp.where(x < 0, -y, y)


@arctan_fast.defjvp
def _arctan_fast_jvp(primals, tangents):
    (x,), (dx,) = primals, tangents
    return arctan_fast(x), dx / (1.0 + x * x)


#: the hidden units' arctan by name (the config field ``arctan``)
ARCTANS = {"fast": arctan_fast, "xla": jnp.arctan}


class Perceptron(nn.Module):
    """s -> W2 arctan(W1 s + b1) + b2 (Sec. V-C); ``arctan`` names the implementation (:data:`ARCTANS`)."""

    hidden: int
    out: int
    arctan: str = "fast"

    @nn.compact
    def __call__(self, s: jax.Array) -> jax.Array:
        h = nn.Dense(self.hidden, kernel_init=nn.initializers.normal(1.0),
                     bias_init=nn.initializers.normal(1.0), name="hidden")(s)
        return nn.Dense(self.out, kernel_init=nn.initializers.zeros,
                        bias_init=nn.initializers.zeros, name="output")(ARCTANS[self.arctan](h))


def make_actor(hidden: int = 100, act_dim: int = 6, arctan: str = "fast") -> Perceptron:
    """The actor: M^A = 100 hidden units, output a~(s; theta) in R^6 (eq. (6))."""
    return Perceptron(hidden=hidden, out=act_dim, arctan=arctan)


def make_critic(hidden: int = 200, arctan: str = "fast") -> Perceptron:
    """The critic: M^C = 200 hidden units, output V~(s; v) in R^1."""
    return Perceptron(hidden=hidden, out=1, arctan=arctan)


def value(critic: Perceptron, v: Params, s: jax.Array) -> jax.Array:
    """V~(s; v) as a scalar (or a batch of scalars)."""
    return critic.apply(v, s)[..., 0]


def init_params(module: Perceptron, key: jax.Array, obs_dim: int) -> Params:
    return module.init(key, jnp.zeros((obs_dim,), jnp.float32))
