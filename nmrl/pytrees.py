"""Small pytree helpers every learner uses, written once (the actor-critic's training program and
PPO in nmrl/learners/ both import them).

* :func:`tree_where`: ``c ? a : b`` leaf by leaf, how a learner keeps the old parameters when an
  update is rejected (non-finite or too large) without leaving the jitted program;
* :func:`global_norm`: the Euclidean norm of all leaves together, the size of parameters and
  gradients the learners log and bound;
* :func:`check_shards`: the environment axis splits evenly over the shards of a ``jax.shard_map``
  (every learner's ``make`` takes ``axis_name`` and ``num_shards``).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp


def tree_where(c: jax.Array, a: Any, b: Any) -> Any:
    """``jnp.where(c, a, b)`` on every pair of leaves of two pytrees of the same structure."""
    return jax.tree.map(lambda x, y: jnp.where(c, x, y), a, b)


def global_norm(tree: Any) -> jax.Array:
    """sqrt of the sum of squares of every leaf of ``tree``."""
    return jnp.sqrt(sum(jnp.sum(jnp.square(x)) for x in jax.tree.leaves(tree)))


def check_shards(num_envs: int, num_shards: int, axis_name: str | None) -> None:
    """ValueError unless ``num_envs`` splits evenly over ``num_shards`` shards of a ``jax.shard_map``
    named ``axis_name`` (one shard needs no name)."""
    if num_shards < 1 or num_envs % num_shards:
        raise ValueError(f"num_envs={num_envs} must be divisible by num_shards={num_shards}")
    if num_shards > 1 and axis_name is None:
        raise ValueError("num_shards > 1 needs an axis_name")
