r"""Non-Markov-period exploration in your own MJX code: a worked example on another robot.

A planar two-link arm (its MJCF is below; any MJX model works the same way) learns to bring its
fingertip to a target by a plain policy gradient over nm-periods, using only the public functions
of `nmrl.paper.noise` and `nmrl.paper.likelihood` (Sec. IV of the paper):

* acting, eq. (6): a_t = a~(s_t; theta) + sigma xi_t, where xi is the piecewise independent
  autoregressive noise (4), one `noise.ar_step` per control step inside the rollout's `lax.scan`
  (vmapped over the environments; `reset` starts a new period at every episode start);
* learning, eq. (7): the rollout is cut into its nm-periods, and each period's
  grad_theta ln pi(A | S; theta) comes from `likelihood.likelihood_ratio` (the tridiagonal Lambda^-1
  in O(l n), with Delta-sampling), weighted by the period's return-to-go minus a baseline (the
  mean over the environments at the same period): REINFORCE with nm-periods as the "actions".

The paper's learner (Table II: actor-critic, TD(lambda) over periods, the online form
`likelihood.online_lr_add`) is in `nmrl/learners/ac_train.py`; this example is the smallest honest use of
the exploration scheme on its own. It runs in about a minute on one CPU core, most of it compiling
MJX's step (measured: 68-79 s in all, ~45 s of compiles, then ~0.08 s per iteration of 32 x 60
control steps, on a core shared with a niced run):

    .venv/bin/python examples/nm_exploration_example.py --l 10

It prints the deterministic policy's average reward per step (its fingertip's mean distance to the
target, negated) before and after learning. Tested in tests/test_example.py (it learns; bad
arguments are refused with the value named).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import optax

from nmrl.paper import _mjx as mjx
from nmrl.paper import likelihood, noise
from nmrl.paper.networks import Perceptron

# A planar arm in the horizontal plane (no gravity along its joints): two 0.1 m links, two hinge
# motors, 5 ms physics steps; the fingertip is a site.
ARM_XML = """
<mujoco model="planar_arm">
  <option timestep="0.01" gravity="0 0 0"/>
  <worldbody>
    <body name="upper">
      <joint name="shoulder" type="hinge" axis="0 0 1" damping="0.02"/>
      <geom type="capsule" fromto="0 0 0 0.1 0 0" size="0.01" mass="0.1"/>
      <body name="fore" pos="0.1 0 0">
        <joint name="elbow" type="hinge" axis="0 0 1" damping="0.02" range="-2.8 2.8" limited="true"/>
        <geom type="capsule" fromto="0 0 0 0.1 0 0" size="0.01" mass="0.1"/>
        <site name="tip" pos="0.1 0 0"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor joint="shoulder" gear="0.05" ctrlrange="-1 1" ctrllimited="true"/>
    <motor joint="elbow" gear="0.05" ctrlrange="-1 1" ctrllimited="true"/>
  </actuator>
</mujoco>
"""
TARGET = (0.05, 0.15)  # [m], reachable (|target| = 0.158 < 0.2)
FRAME_SKIP = 2  # control step 0.02 s, as the paper's
OBS_DIM, ACT_DIM = 8, 2


@dataclasses.dataclass(frozen=True)
class ExampleConfig:
    """The example's settings; `l`, `alpha`, `sigma`, `delta` are the paper's symbols."""

    l: int = 10  #: nm-period length (eq. (4)); l = 1 is white noise, i.e. the classic scheme
    alpha: float = 0.8  #: AR coefficient of (4), the paper's value
    sigma: float = 0.3  #: noise standard deviation, Sigma = sigma^2 I
    delta: int = 1  #: Delta-sampling step of the likelihood (end of Sec. IV)
    num_envs: int = 32
    steps: int = 60  #: control steps per episode (1.2 s), a multiple of l: T / l periods
    iterations: int = 100
    learning_rate: float = 0.03
    hidden: int = 32
    seed: int = 0

    def validate(self) -> None:
        for name in ("l", "delta", "num_envs", "steps", "iterations", "hidden"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise ValueError(f"{name}={v!r} is invalid: must be an integer >= 1")
        noise.validate(alpha=self.alpha, l=self.l, delta=self.delta)
        if self.steps % self.l:
            raise ValueError(f"steps={self.steps} is invalid with l={self.l}: an episode must be whole "
                             f"nm-periods (a multiple of l)")
        if not self.sigma > 0:
            raise ValueError(f"sigma={self.sigma!r} is invalid: must be > 0")
        if not self.learning_rate > 0:
            raise ValueError(f"learning_rate={self.learning_rate!r} is invalid: must be > 0")

    @property
    def periods(self) -> int:
        return self.steps // self.l


class Trajectory(NamedTuple):
    obs: jax.Array  # (T, N, OBS_DIM)
    act: jax.Array  # (T, N, ACT_DIM): a_t = a~(s_t) + sigma xi_t, before the actuators clip it
    reward: jax.Array  # (T, N)


def _observe(d: mjx.Data) -> jax.Array:
    """cos and sin of both joint angles, their velocities, the fingertip's offset from the target."""
    tip = d.site_xpos[0, :2]
    return jnp.concatenate([jnp.cos(d.qpos), jnp.sin(d.qpos), d.qvel * 0.1, (tip - jnp.asarray(TARGET)) * 10])


def _reward(d: mjx.Data) -> jax.Array:
    return -jnp.linalg.norm(d.site_xpos[0, :2] - jnp.asarray(TARGET))


class Example(NamedTuple):
    """What :func:`make_example` builds (the rollout is compiled once; ``explore`` scales the noise)."""

    init: Callable  #: key -> (params, opt_state)
    rollout: Callable  #: (params, key, explore) -> Trajectory; explore 1.0 acts by (6), 0.0 by a~ alone
    policy_gradient: Callable  #: (params, Trajectory) -> the estimate of grad J, shaped like params
    update: Callable  #: (params, opt_state, key) -> (params, opt_state, exploring reward per step)
    evaluate: Callable  #: (params, key) -> the deterministic policy's reward per step


def make_example(cfg: ExampleConfig) -> Example:
    """The arm, the actor and the nm-period policy gradient of ``cfg`` (see the module docstring)."""
    cfg.validate()
    mj_model = mujoco.MjModel.from_xml_string(ARM_XML)
    m = mjx.put_model(mj_model)
    actor = Perceptron(hidden=cfg.hidden, out=ACT_DIM)  # the paper's arctan perceptron, a~ = 0 at first

    def apply(params, s):  # (k, OBS_DIM) -> (k, ACT_DIM): the deterministic part a~ of (6)
        return actor.apply(params, s)

    def env_step(d, a):
        d = d.replace(ctrl=jnp.clip(a, -1.0, 1.0))
        for _ in range(FRAME_SKIP):
            d = mjx.step(m, d)
        return d

    def reset(key):
        d = mjx.make_data(m)
        d = d.replace(qpos=jax.random.uniform(key, (2,), minval=-0.3, maxval=0.3))
        return mjx.forward(m, d)

    @jax.jit
    def rollout(params, key, explore) -> Trajectory:
        k_reset, k_eps = jax.random.split(key)
        d0 = jax.vmap(reset)(jax.random.split(k_reset, cfg.num_envs))
        ar0 = jax.vmap(lambda _: noise.ar_init(ACT_DIM))(jnp.arange(cfg.num_envs))
        eps = jax.random.normal(k_eps, (cfg.steps, cfg.num_envs, ACT_DIM))

        def body(carry, xs):
            d, ar = carry
            e, t = xs
            s = jax.vmap(_observe)(d)
            # eq. (4): every environment's noise; a period starts at t = 0 and every l steps after
            ar, u = jax.vmap(lambda st, ee: noise.ar_step(st, ee, cfg.alpha, cfg.l, cfg.sigma, t == 0))(ar, e)
            a = apply(params, s) + explore * u  # eq. (6)
            d = jax.vmap(env_step)(d, a)
            return (d, ar), (s, a, jax.vmap(_reward)(d))

        _, (s, a, r) = jax.lax.scan(body, (d0, ar0), (eps, jnp.arange(cfg.steps)))
        return Trajectory(s, a, r)

    optimizer = optax.adam(cfg.learning_rate)

    def policy_gradient(params, traj: Trajectory):
        """Mean over environments and periods of (G_k - b_k) grad ln pi(A_k | S_k) (eq. (7))."""
        N = traj.reward.shape[1]
        K, l = cfg.periods, cfg.l
        reward_k = traj.reward.reshape(K, l, N).sum(axis=1)  # (K, N) reward of each period
        G = jnp.flip(jnp.cumsum(jnp.flip(reward_k, 0), 0), 0)  # return-to-go from period k
        adv = G - G.mean(axis=1, keepdims=True)  # baseline: the same period's mean over environments
        S = traj.obs.reshape(K, l, N, OBS_DIM).transpose(0, 2, 1, 3)  # (K, N, l, OBS_DIM)
        A = traj.act.reshape(K, l, N, ACT_DIM).transpose(0, 2, 1, 3)
        lr_one = lambda s, a: likelihood.likelihood_ratio(apply, params, s, a, cfg.alpha, cfg.sigma, cfg.delta)
        g = jax.vmap(jax.vmap(lr_one))(S, A)  # (K, N, ...) grad ln pi of every period
        return jax.tree.map(lambda x: jnp.einsum("kn,kn...->...", adv, x) / (K * N), g)

    @jax.jit
    def learn(params, opt_state, traj):
        grad = policy_gradient(params, traj)
        step, opt_state = optimizer.update(jax.tree.map(jnp.negative, grad), opt_state, params)  # ascent
        return optax.apply_updates(params, step), opt_state

    def update(params, opt_state, key):
        traj = rollout(params, key, 1.0)
        params, opt_state = learn(params, opt_state, traj)
        return params, opt_state, traj.reward.mean()

    def init(key):
        params = actor.init(key, jnp.zeros((OBS_DIM,)))
        return params, optimizer.init(params)

    def evaluate(params, key):
        return rollout(params, key, 0.0).reward.mean()
    return Example(init, rollout, policy_gradient, update, evaluate)


def train(cfg: ExampleConfig) -> dict:
    """Runs the example; returns the deterministic policy's reward per step before and after."""
    init, _, _, update, evaluate = make_example(cfg)
    key = jax.random.PRNGKey(cfg.seed)
    key, k_init, k_eval = jax.random.split(key, 3)
    params, opt_state = init(k_init)
    before = float(evaluate(params, k_eval))
    exploring = []
    for _ in range(cfg.iterations):
        key, k = jax.random.split(key)
        params, opt_state, r = update(params, opt_state, k)
        exploring.append(float(r))
    after = float(evaluate(params, k_eval))
    return {"l": cfg.l, "reward_per_step_before": before, "reward_per_step_after": after,
            "exploring_first": exploring[0], "exploring_last": exploring[-1]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    defaults = ExampleConfig()
    for f in dataclasses.fields(ExampleConfig):
        ap.add_argument(f"--{f.name.replace('_', '-')}", type=type(getattr(defaults, f.name)),
                        default=getattr(defaults, f.name))
    cfg = ExampleConfig(**vars(ap.parse_args(argv)))
    try:
        cfg.validate()
    except ValueError as e:
        print(f"nm_exploration_example: error: {e}", file=sys.stderr)
        return 2
    out = train(cfg)
    print(f"l = {cfg.l}: the deterministic policy's reward per step {out['reward_per_step_before']:+.4f} -> "
          f"{out['reward_per_step_after']:+.4f} (mean fingertip distance to the target, negated) after "
          f"{cfg.iterations} iterations of {cfg.num_envs} x {cfg.steps} control steps")
    return 0


if __name__ == "__main__":
    sys.exit(main())
