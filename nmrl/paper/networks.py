"""Actor a~(s; theta) and critic V~(s; v) of Sec. V-C (flax).

Both are two-layer perceptrons: M arctan ("sigmoidal") hidden units, a bias on every neuron and a
linear output layer. Hidden weights and biases are drawn from N(0, 1); output weights and biases
are zero, so the initial policy is a~ = 0 (the robot stands still under its PD torque) and the
initial value estimate is V~ = 0.
"""

from __future__ import annotations

from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

Params = Any


class Perceptron(nn.Module):
    """s -> W2 arctan(W1 s + b1) + b2 (Sec. V-C)."""

    hidden: int
    out: int

    @nn.compact
    def __call__(self, s: jax.Array) -> jax.Array:
        h = nn.Dense(self.hidden, kernel_init=nn.initializers.normal(1.0),
                     bias_init=nn.initializers.normal(1.0), name="hidden")(s)
        return nn.Dense(self.out, kernel_init=nn.initializers.zeros,
                        bias_init=nn.initializers.zeros, name="output")(jnp.arctan(h))


def make_actor(hidden: int = 100, act_dim: int = 6) -> Perceptron:
    """The actor: M^A = 100 hidden units, output a~(s; theta) in R^6 (eq. (6))."""
    return Perceptron(hidden=hidden, out=act_dim)


def make_critic(hidden: int = 200) -> Perceptron:
    """The critic: M^C = 200 hidden units, output V~(s; v) in R^1."""
    return Perceptron(hidden=hidden, out=1)


def value(critic: Perceptron, v: Params, s: jax.Array) -> jax.Array:
    """V~(s; v) as a scalar (or a batch of scalars)."""
    return critic.apply(v, s)[..., 0]


def init_params(module: Perceptron, key: jax.Array, obs_dim: int) -> Params:
    return module.init(key, jnp.zeros((obs_dim,), jnp.float32))
