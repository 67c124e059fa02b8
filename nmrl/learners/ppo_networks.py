"""PPO's networks, observation normaliser and action distribution (Brax PPO's, in nmrl's terms).

* :class:`MLP`: Brax's ``networks.MLP`` (Dense layers with ``lecun_uniform`` kernels and zero biases,
  swish between layers, a linear output). The policy outputs ``(mu, raw_std)`` per action dimension
  (``2 n`` outputs, a state-dependent std) or ``mu`` alone (a fixed std); the value net outputs V.
* :class:`ObsStats`: running mean and standard deviation of the observations (Brax's
  ``running_statistics``, Welford form): ``update`` adds a batch, ``normalize`` maps
  ``s -> (s - mean) / std``; the std is ``sqrt(summed_var / count)`` clipped to [1e-6, 1e6], and it
  starts at mean 0, std 1 (the first rollout sees the raw observation, as in Brax).
* The distribution of the pre-squash action ``x`` (docs/ppo.md, "Distribution"):
  ``x_t = mu_theta(s_t) + std_theta(s_t) * xi_t``, ``xi`` the exploration process (nmrl.explore:
  white noise is Brax's i.i.d. normal), ``std_theta = softplus(raw) + min_std`` (Brax's
  ``NormalTanhDistribution``) or 1. The action sent to the environment is ``ACTION_SCALE * tanh(x)``
  (or ``ACTION_SCALE * clip(x, -1, 1)``); ``tanh_log_det`` is the log-Jacobian of tanh, which enters
  the entropy bonus and cancels in the likelihood ratio of a fixed ``x``.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple, Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

#: the paper's action a = ACTION_SCALE * u for a squashed u in [-1, 1]: a^0 = 0.1 a = 2u spans the
#: full torque range min{max{-1, tau^0 + a^0}, 1} for every tau^0 in (-1, 1) (Sec. V-A), and
#: nothing beyond it (the value of nmrl.adapters.brax_env.ACTION_SCALE, the Brax baseline's)
ACTION_SCALE = 20.0
#: Brax's running_statistics bounds of the observation std
STD_MIN, STD_MAX = 1e-6, 1e6
_HALF_LOG_2PI_E = 0.5 + 0.5 * math.log(2.0 * math.pi)


class MLP(nn.Module):
    """Brax's MLP: Dense(lecun_uniform, zero bias) with swish after every layer but the last."""

    sizes: Sequence[int]

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for i, size in enumerate(self.sizes):
            x = nn.Dense(size, kernel_init=nn.initializers.lecun_uniform(), name=f"hidden_{i}")(x)
            if i < len(self.sizes) - 1:
                x = nn.swish(x)
        return x


class Networks(NamedTuple):
    policy: MLP
    value: MLP
    learn_std: bool
    act_dim: int


def make_networks(policy_layers: int, policy_width: int, value_layers: int, value_width: int, act_dim: int,
                  learn_std: bool) -> Networks:
    out = 2 * act_dim if learn_std else act_dim
    return Networks(policy=MLP((policy_width,) * policy_layers + (out,)),
                    value=MLP((value_width,) * value_layers + (1,)), learn_std=learn_std, act_dim=act_dim)


def init_params(nets: Networks, key: jax.Array, obs_dim: int) -> tuple[Any, Any]:
    """(policy params, value params) as Brax initialises them (one key each)."""
    k_p, k_v = jax.random.split(key)
    x = jnp.zeros((1, obs_dim), jnp.float32)
    return nets.policy.init(k_p, x), nets.value.init(k_v, x)


def mean_std(nets: Networks, policy_params: Any, obs_n: jax.Array, min_std: float) -> tuple[jax.Array, jax.Array]:
    """``(mu, std_theta)`` of the pre-squash action for normalised observations ``obs_n (..., obs)``."""
    out = nets.policy.apply(policy_params, obs_n)
    if not nets.learn_std:
        return out, jnp.ones_like(out)
    mu, raw = jnp.split(out, 2, axis=-1)
    return mu, jax.nn.softplus(raw) + min_std


def value(nets: Networks, value_params: Any, obs_n: jax.Array) -> jax.Array:
    return nets.value.apply(value_params, obs_n)[..., 0]


def tanh_log_det(x: jax.Array) -> jax.Array:
    """log |d tanh(x) / dx| = 2 (log 2 - x - softplus(-2x)) (Brax's TanhBijector), elementwise."""
    return 2.0 * (math.log(2.0) - x - jax.nn.softplus(-2.0 * x))


def squash(x: jax.Array, kind: str, scale: Any = ACTION_SCALE, offset: Any = None) -> jax.Array:
    """The environment's action for a pre-squash action ``x``: ``offset + scale * u`` with u = tanh(x)
    or clip(x, -1, 1); ``scale``/``offset`` map [-1, 1] onto the environment's action range
    (:func:`action_range`; the paper's robot: 20 u)."""
    u = jnp.tanh(x) if kind == "tanh" else jnp.clip(x, -1.0, 1.0)
    return scale * u if offset is None else offset + scale * u


def action_range(env: Any) -> tuple[Any, Any]:
    """``(scale, offset)`` of :func:`squash` for ``env``: its ``action_scale`` and ``action_offset``
    (a Gymnasium task: the half-width and centre of its actuators' ctrlrange), the paper's
    ``ACTION_SCALE`` and no offset for an environment that declares neither."""
    return getattr(env, "action_scale", ACTION_SCALE), getattr(env, "action_offset", None)


def entropy(std: jax.Array, x_sample: jax.Array, squash_kind: str) -> jax.Array:
    """Brax's entropy estimate of the squashed action, summed over the action dimensions: the normal
    entropy with marginal std ``std`` plus, for tanh, the log-Jacobian at a sample ``x_sample``."""
    h = _HALF_LOG_2PI_E + jnp.log(std)
    if squash_kind == "tanh":
        h = h + tanh_log_det(x_sample)
    return jnp.sum(h, axis=-1)


class ObsStats(NamedTuple):
    """Running observation statistics (Brax's RunningStatisticsState, Welford form)."""

    count: jax.Array  #: () float32, observations seen
    mean: jax.Array  #: (obs_dim,)
    summed_var: jax.Array  #: (obs_dim,) sum of squared deviations
    std: jax.Array  #: (obs_dim,) clip(sqrt(summed_var / count), STD_MIN, STD_MAX); 1 before any data


def obs_init(obs_dim: int) -> ObsStats:
    z = jnp.zeros((obs_dim,), jnp.float32)
    return ObsStats(count=jnp.zeros((), jnp.float32), mean=z, summed_var=z, std=jnp.ones((obs_dim,), jnp.float32))


def obs_update(stats: ObsStats, batch: jax.Array, psum=lambda x: x) -> ObsStats:
    """Add a batch ``(..., obs_dim)`` (Brax's ``running_statistics.update``; ``psum`` sums over shards)."""
    batch = batch.reshape(-1, batch.shape[-1])
    count = stats.count + psum(jnp.float32(batch.shape[0]))
    diff_old = batch - stats.mean
    mean = stats.mean + psum(jnp.sum(diff_old, axis=0) / count)
    summed_var = stats.summed_var + psum(jnp.sum(diff_old * (batch - mean), axis=0))
    std = jnp.clip(jnp.sqrt(jnp.maximum(summed_var, 0.0) / count), STD_MIN, STD_MAX)
    return ObsStats(count=count, mean=mean, summed_var=summed_var, std=std)


def normalize(stats: ObsStats, obs: jax.Array, enabled: bool = True) -> jax.Array:
    return (obs - stats.mean) / stats.std if enabled else obs
