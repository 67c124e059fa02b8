"""The paper's actor-critic (Table II) as the learner ``ac``.

Its training program is nmrl/learners/ac_train.py, its config nmrl/learners/ac_config.py and its
update rules nmrl/learners/optimizers.py; the equations it is built of (the networks of (6), the
noise (4) and its likelihood ratio (7), the robot) are nmrl/paper/. This module says how the driver
takes it (nmrl/learners/contract.py): its config is
:class:`~nmrl.learners.ac_config.TrainConfig`, its traced hyperparameters :class:`~nmrl.learners.ac_config.Hyper`
(l, Delta, alpha, sigma, gamma, lambda and the step sizes: a sweep over any of them is one program),
the per-environment part of its state the ``slots`` (environment, noise (4), likelihood ratio (7),
traces), the compact continuation state the parameters theta, v and the count of learned periods,
and the deterministic policy a = a~(s; theta) (eq. (6) with xi = 0); the exploring one adds the
piecewise AR noise (4) with the run's l, alpha and sigma.

Exploration processes in seconds (``white``, ``nm-periods``; :func:`exploration_fields`): white
noise is l = 1, the paper's nm-periods are l = round(period_s / control_dt) and
alpha = exp(-control_dt / corr_time_s) (alpha = 0.8 at 0.02 s <-> corr_time_s = 0.0896 s). A
stationary correlated process (``ou``, ``colored``) has no periods, so its likelihood ratio has no
period to be accumulated over (Table II, step 1): the actor-critic refuses it.

Environments (``env``, nmrl/tasks/): the paper's robot or a Gymnasium task. The actor's action
a = a~(s; theta) + xi is in the paper's units, where a = 20 u with u in [-1, 1] spans the robot's
whole torque range (a^0 = 0.1 a, Sec. V-A; ``ppo_networks.ACTION_SCALE``) and the noise's sigma = 1
is a twentieth of it. On a task the same u is mapped onto the task's action space the way PPO maps
its squashed action (``ppo_networks.action_range``, ``Task.action_scale``/``action_offset``):
offset + scale * clip(a / 20, -1, 1), so the task sees an action inside Gymnasium's
``action_space`` and the noise keeps its share of the range. On the paper's robot a goes to the
robot unchanged (its torque saturates by itself). A task's termination (a fall) ends the period,
which is learned from with the value after it 0 (nmrl/learners/ac_train.py, Table II step 2); its
truncation (the time limit) discards the period, as the paper's random stop does.
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp

from nmrl import explore, options, tasks
from nmrl.learners import ppo_networks
from nmrl.learners.ac_config import EXPLORATIONS, TrainConfig
from nmrl.learners.ac_train import make_train
from nmrl.learners.contract import Policy
from nmrl.paper import networks, noise

#: TrainConfig fields checked for finiteness before anything is built (NaN/inf pass some range checks)
FINITE = ("alpha", "sigma", "gamma", "lam", "control_dt", "stop_prob", "reward_scale")


def check(cfg: TrainConfig) -> None:
    for name in FINITE:
        v = options.value(cfg, name)
        if isinstance(v, float) and not math.isfinite(v):
            raise ValueError(f"{name}={v!r} is invalid: must be a finite number")


def action_map(env):
    """The environment's action for the actor's a (module docstring): None (a itself) for an
    environment without an action space of its own (the paper's robot), else
    ``a -> offset + scale * clip(a / 20, -1, 1)`` onto its ``action_scale``/``action_offset``."""
    if not hasattr(env, "action_scale"):
        return None
    scale, offset = ppo_networks.action_range(env)
    return lambda a: ppo_networks.squash(a / ppo_networks.ACTION_SCALE, "clip", scale, offset)


def make(config: TrainConfig, env=None, **kw):
    """``make_train`` with the run's environment (``tasks.make_env(config.environment.env, ...)`` unless given)
    and its :func:`action_map`."""
    cfg = config.resolved()
    env = env or tasks.make_env(cfg.environment.env, cfg.environment.env_config())
    return make_train(config, env, action_map=action_map(env), **kw)


def exploration_fields(kind: str, control_dt: float, period_s: float | None = None,
                       corr_time_s: float | None = None) -> dict:
    """The TrainConfig fields (l, alpha) of an exploration process given in seconds (only those whose
    parameter is given: l = round(period_s / control_dt), alpha = exp(-control_dt / corr_time_s);
    ``white``: l = 1), validated by nmrl.explore's ExplorationSpec; ValueError for a process the
    actor-critic cannot use or a bad time (e.g. a period shorter than the control step)."""
    if kind not in EXPLORATIONS:
        raise ValueError(f"exploration={kind!r} is a process the learner 'ac' cannot use: its likelihood ratio "
                         f"is accumulated over nm-periods (Table II); allowed: {', '.join(EXPLORATIONS)}")
    if kind == "white":
        if period_s is not None or corr_time_s is not None:
            raise ValueError("exploration='white' takes no --period-s or --corr-time-s")
        return {"l": 1}
    explore.ExplorationSpec(kind=kind, period_s=period_s, corr_time_s=corr_time_s).validate(control_dt)
    out: dict = {}
    if period_s is not None:
        out["l"] = explore.period_steps(period_s, control_dt)
    if corr_time_s is not None:
        out["alpha"] = explore.alpha_from_corr_time(corr_time_s, control_dt)
    return out


def exploration(cfg: TrainConfig, kind: str | None, params: dict, given: frozenset = frozenset()) -> TrainConfig:
    """``cfg`` with the process ``kind`` (None: nm-periods, the paper's) and its parameters in seconds
    (:func:`exploration_fields`) set as l and alpha; ValueError for a process the actor-critic cannot
    use, a parameter it does not have, or one given twice (``--l`` and ``--period-s``, ``--alpha`` and
    ``--corr-time-s``; ``--exploration white`` and an ``--l`` other than 1)."""
    kind = kind or "nm-periods"
    if kind not in EXPLORATIONS:
        exploration_fields(kind, cfg.environment.control_dt)  # raises: a process the learner cannot use
    extra = sorted(k for k in params if k not in ("period_s", "corr_time_s"))
    if extra:
        raise ValueError(f"--{extra[0].replace('_', '-')}={params[extra[0]]!r} is not a parameter of "
                         f"--exploration {kind} for the learner 'ac' (it takes --period-s and --corr-time-s)")
    for field, param in (("l", "period_s"), ("alpha", "corr_time_s")):
        if field in given and param in params:
            raise ValueError(f"give either --{field} or --{param.replace('_', '-')}, not both (--{field} "
                             f"{getattr(cfg, field)!r}, --{param.replace('_', '-')} {params[param]!r})")
    if kind == "white" and "l" in given and cfg.l != 1:
        raise ValueError(f"--exploration white is l = 1, but --l {cfg.l!r} is given")
    return dataclasses.replace(cfg, **exploration_fields(kind, cfg.environment.control_dt, **params))


def policy(cfg: TrainConfig, env) -> Policy:
    """a = a~(s; theta) + xi (eq. (6)) through the environment's :func:`action_map`; xi the piecewise AR
    process (4) with the run's l, alpha, sigma."""
    actor = networks.make_actor(cfg.hidden_actor, env.act_dim, cfg.arctan)
    to_env = action_map(env) or (lambda a: a)
    return Policy(
        act=lambda params, obs, xi: to_env(actor.apply(params["theta"], obs) + xi),
        noise_init=noise.ar_init,
        noise_step=lambda a, state, eps: noise.ar_step(state, eps, a["alpha"], a["l"], a["sigma"]),
        noise_args={"alpha": jnp.float32(cfg.alpha), "l": jnp.int32(cfg.l), "sigma": jnp.float32(cfg.sigma)},
    )


def fill(trainer, ts):
    """Fresh optimizer states for a checkpoint written before they were saved (exact for the paper's
    sgd rule, the only one those runs could name: its state holds no statistics)."""
    opt_theta, opt_v = trainer.init_opt(ts.theta, ts.v, ts.hyper)
    return ts.replace(opt_theta=opt_theta, opt_v=opt_v)
