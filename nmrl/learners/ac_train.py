"""The classic actor-critic with TD(lambda) over non-Markov periods (Table II), batched.

``trainer = make_train(config)`` gives pure functions ``trainer.init(key)`` and ``trainer.chunk(ts)``
(``chunk_steps`` control steps of every environment, a ``lax.scan``; nmrl/runs/driver.py runs the
chunks of a budget). All hyperparameters that a sweep may
vary (l, Delta, alpha, sigma, gamma, lambda, beta) live in the traced :class:`Hyper` pytree inside the
training state, so ``jax.vmap`` over (l, seed) points compiles one program.

Per environment e, per nm-period k (Table II):

1. perform l_k actions a_t = a~(s_t; theta) + xi_t (eq. (6)) with xi the piecewise AR process (4);
   accumulate r_bar_k = sum_i gamma^i r_{t_k+i}; accumulate the Delta-sampled likelihood ratio
   grad ln pi_Ahat(Ahat_k; S_k, theta) online (nmrl.paper.likelihood.online_lr_add, the innovation
   form of (7));
2. if the trial was stopped within the period, discard it: no update, traces z, y := 0 (a new trial
   begins), and a new period starts at the reset state; an environment that ends trials by a rule
   of its own (a Gymnasium task's ``terminated``: a fall) ends the period there instead, and it is
   learned from with the value after the end 0 (V~(s_{t_{k+1}}) := 0 in 3.), then the traces are 0;
3. d_k = r_bar_k + gamma_k V~(s_{t_{k+1}}; v) - V~(s_{t_k}; v), gamma_k = gamma^{l_k};
4. z := lambda gamma_k z + grad ln pi_Ahat,   theta += beta^theta d_k z;
5. y := lambda gamma_k y + dV~(s_{t_k}; v)/dv,  v += beta^v d_k y.

Batching. N environments run in lock-step, each with its own period phase, traces and noise. At
every control step the updates of all environments whose period ended at that step are *summed*
with the paper's step sizes: theta += beta^theta sum_e d_e z_e (same for v). Each period thus moves
the parameters by exactly the step the sequential algorithm would take for it, and N = 1 is the
paper's sequential algorithm. (Averaging instead of summing would divide the step per sample by N.)
With N > 1 the parameters change within a period of one environment (other environments update).
The likelihood ratio is accumulated online (docs/noise.md, "Online form"): each sample's noise
u = xi is the one that generated its action, but every term is one vjp at the parameters current
when it is added, and it covers the previous sample too, so the previous sample's Jacobian is
evaluated at the current theta, which may differ from the theta that generated it. With N = 1
theta is fixed within a period and the online sum equals the batch likelihood ratio of (7) exactly.

The update goes through optax. The parameter steps of Table II (4., 5.) are plain gradient
*ascent* along the pseudo-gradients sum_e d_e z_e and sum_e d_e y_e; optax minimises, so each
control step hands it the negated pseudo-gradients

    g^theta = -sum_e d_e z_e,    g^v = -sum_e d_e y_e        (summed over the environments, psum-ed
                                                              over shards, before the optimizer)

and applies its updates: with ``optax.sgd(beta)`` that is u = -beta g = beta sum_e d_e z_e and
theta := theta + u, the paper's rule. The step sizes are not baked into the program:
each optimizer is wrapped in ``optax.inject_hyperparams`` and its ``learning_rate`` is overwritten
at every control step from the traced :class:`Hyper` (``beta_theta`` for the actor, ``beta_v`` for
the critic), so a sweep over beta (or l, ...) is still one compiled program and ``Hyper`` stays the
one source of the step sizes (the copy inside the optimizer state only records the last one used).
The optimizer states ``opt_theta`` and ``opt_v`` are part of :class:`TrainState` (and so of the
checkpoints). The optimizer takes a step only at a control step at which at least one
environment's period ended (the update instants of Table II; with N = 1 one step per learned
period); at other steps the parameters and the optimizer states stay as they are. For sgd this
changes nothing (the summed update is zero there); a stateful optimizer does not see zero
gradients in between.

The update rules (``actor_opt``, ``critic_opt``: sgd, adam, clipping by global norm, as chains) are
nmrl/learners/optimizers.py; the config, its traced :class:`Hyper` and the presets are
nmrl/learners/ac_config.py; nmrl/learners/ac.py registers the program as the learner ``ac``.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.flatten_util
import jax.numpy as jnp
import optax
from flax import struct

from nmrl import tasks
from nmrl.learners import ac_config
from nmrl.learners.ac_config import Hyper, TrainConfig
from nmrl.learners.optimizers import injected, opt_rule, parse_opt, with_learning_rate
from nmrl.paper import likelihood, networks, noise
from nmrl.paper.env import HalfCheetah, State
from nmrl.pytrees import check_shards, global_norm, tree_where

Params = Any
OptState = Any

#: The TrainState fields that hold the optimizer states (a checkpoint of the layout without an
#: optimizer lacks them; nmrl/runs/checkpoint.py restores it with fresh ones, see :func:`make_train`'s ``init_opt``).
OPT_FIELDS = ac_config.OPT_FIELDS


@struct.dataclass
class EnvSlot:
    """Per-environment learner state (leading axis N)."""

    env: State
    ar: noise.ARState  #: xi_{t-1} and the in-period index of the next step
    olr: likelihood.OnlineLR  #: likelihood ratio of the current period, accumulated online
    z: Params  #: actor eligibility trace
    y: Params  #: critic eligibility trace
    s_start: jax.Array  #: s_{t_k}
    rbar: jax.Array  #: r_bar_k so far
    gpow: jax.Array  #: gamma^(steps so far in the period)


@struct.dataclass
class TrainState:
    theta: Params
    v: Params
    slots: EnvSlot
    key: jax.Array
    hyper: Hyper
    step: jax.Array  #: control steps per environment so far
    trials: jax.Array  #: trials finished, summed over environments
    periods: jax.Array  #: periods that took part in learning, summed over environments
    diverged: jax.Array  #: True once an update made the parameters non-finite or too large
    #: optax state of the actor's optimizer (``optax.inject_hyperparams`` state: count,
    #: hyperparams {"learning_rate"}, inner state; see the module docstring)
    opt_theta: OptState
    opt_v: OptState  #: optax state of the critic's optimizer


class ACTrainer(NamedTuple):
    """The actor-critic's training functions, as :func:`make_train` builds them: the learner
    contract's ``Trainer`` (nmrl/learners/contract.py: ``config``, ``env``, ``init``, ``chunk``) and
    ``init_opt``, which the contract does not ask for."""

    config: TrainConfig
    env: HalfCheetah
    init: Callable[..., TrainState]
    chunk: Callable[[TrainState], tuple[TrainState, dict]]
    #: ``init_opt(theta, v, hyper) -> (opt_theta, opt_v)``: fresh optimizer states (as ``init`` makes)
    init_opt: Callable[[Params, Params, Hyper], tuple[OptState, OptState]]


def make_train(config: TrainConfig, env: Any = None, *, axis_name: str | None = None,
               num_shards: int = 1, action_map: Callable[[jax.Array], jax.Array] | None = None) -> ACTrainer:
    """Build the pure functions of a training run (see the module docstring).

    ``env`` defaults to ``HalfCheetah(config.environment.env_config())`` (a config naming another ``env`` must
    bring it); any environment with the same interface (``obs_dim``, ``act_dim``, ``reward_terms``,
    ``reset(key)``, ``step(state, action)`` with auto-reset, ``State`` with ``obs``, ``reward``,
    ``done``, ``metrics`` incl. ``forward_speed`` and ``nonfinite``) works. ``action_map`` turns the
    action a_t of (6) into the environment's action (None: a_t itself, the paper's robot;
    nmrl/learners/ac.py maps it onto a Gymnasium task's action space).

    With ``axis_name`` and ``num_shards`` > 1, ``chunk`` is written for ``jax.shard_map`` over the
    environment axis of ``TrainState.slots`` (nmrl/runs/layout.py does that): each shard steps its
    ``num_envs / num_shards`` environments, and the summed update and the statistics are ``psum``-ed
    over ``axis_name``. The noise of all N environments is drawn from the shared key and each shard
    takes its slice, so the draws equal the unsharded program's.
    """
    check_shards(config.budget.num_envs, num_shards, axis_name)
    cfg = config.resolved()
    if env is None and cfg.environment.env != tasks.PAPER:
        raise ValueError(f"env={cfg.environment.env!r}: make_train builds the paper's robot only; pass the environment")
    env = env or HalfCheetah(cfg.environment.env_config())
    OBS_DIM, ACT_DIM = env.obs_dim, env.act_dim
    REWARD_TERMS = tuple(env.reward_terms)
    #: whether the environment ends trials by a rule of its own (a Gymnasium task's ``terminated``)
    TERMINATES = "terminated" in jax.eval_shape(env.reset, jax.random.PRNGKey(0)).info
    actor = networks.make_actor(cfg.hidden_actor, ACT_DIM, cfg.arctan)
    critic = networks.make_critic(cfg.hidden_critic, cfg.arctan)
    N = cfg.budget.num_envs
    N_local = N // num_shards
    # The update rules of actor and critic (the paper's: sgd; cfg.actor_opt / cfg.critic_opt). Only
    # the structure of these transformations is used; the step size comes from the state (Hyper).
    rule_theta = opt_rule(parse_opt(cfg.actor_opt, "actor_opt"))
    rule_v = opt_rule(parse_opt(cfg.critic_opt, "critic_opt"))
    tx_theta, tx_v = injected(rule_theta, 0.0), injected(rule_v, 0.0)

    def init_opt(theta: Params, v: Params, hyper: Hyper) -> tuple[OptState, OptState]:
        return (injected(rule_theta, hyper.beta_theta).init(theta),
                injected(rule_v, hyper.beta_v).init(v))

    def psum(x):
        return jax.lax.psum(x, axis_name) if num_shards > 1 else x

    def pmax(x):
        return jax.lax.pmax(x, axis_name) if num_shards > 1 else x

    def init(key: jax.Array, hyper: Hyper | None = None) -> TrainState:
        hyper = Hyper.from_config(cfg) if hyper is None else hyper
        k_a, k_c, k_env, key = jax.random.split(key, 4)
        theta = networks.init_params(actor, k_a, OBS_DIM)
        v = networks.init_params(critic, k_c, OBS_DIM)
        env_states = jax.vmap(env.reset)(jax.random.split(k_env, N))
        zeros_like = lambda t: jax.tree.map(lambda x: jnp.zeros((N,) + x.shape, x.dtype), t)  # noqa: E731
        olr = likelihood.online_lr_init(theta, OBS_DIM, ACT_DIM)
        slots = EnvSlot(
            env=env_states,
            ar=jax.vmap(lambda _: noise.ar_init(ACT_DIM))(jnp.arange(N)),
            olr=jax.tree.map(lambda x: jnp.broadcast_to(x, (N,) + x.shape), olr),
            z=zeros_like(theta),
            y=zeros_like(v),
            s_start=env_states.obs,
            rbar=jnp.zeros((N,), jnp.float32),
            gpow=jnp.ones((N,), jnp.float32),
        )
        z32 = jnp.zeros((), jnp.int32)
        opt_theta, opt_v = init_opt(theta, v, hyper)
        return TrainState(theta=theta, v=v, slots=slots, key=key, hyper=hyper, step=z32, trials=z32,
                          periods=z32, diverged=jnp.zeros((), bool), opt_theta=opt_theta, opt_v=opt_v)

    def slot_step(theta, v, slot: EnvSlot, eps, h: Hyper):
        """One control step of one environment; returns the slot and its (d, completed) and stats."""
        obs = slot.env.obs
        start = slot.ar.i == 0
        s_start = jnp.where(start, obs, slot.s_start)
        rbar = jnp.where(start, 0.0, slot.rbar)
        gpow = jnp.where(start, 1.0, slot.gpow)
        olr = tree_where(start, likelihood.online_lr_reset(slot.olr), slot.olr)
        i_used = slot.ar.i
        mean = actor.apply(theta, obs)
        ar, xi = noise.ar_step(slot.ar, eps, h.alpha, h.l, h.sigma)
        sampled = jnp.remainder(i_used, h.delta) == 0
        olr = likelihood.online_lr_add(olr, actor.apply, theta, obs, xi, h.alpha ** h.delta, h.sigma,
                                  active=sampled)
        env_state = env.step(slot.env, mean + xi if action_map is None else action_map(mean + xi))
        r = env_state.reward * cfg.reward_scale
        rbar = rbar + gpow * r
        gpow = gpow * h.gamma
        stopped = env_state.done > 0
        completed = (ar.i == 0) & ~stopped
        v_start, g_v = jax.value_and_grad(lambda p: networks.value(critic, p, s_start))(v)
        v_next = networks.value(critic, v, env_state.obs)
        if TERMINATES:  # a task's own end (a fall): the period is learned from, the value after it is 0
            terminal = stopped & (env_state.info["terminated"] > 0)
            completed = completed | terminal
            v_next = jnp.where(terminal, 0.0, v_next)
        d = rbar + gpow * v_next - v_start
        decay = h.lam * gpow
        z_new = jax.tree.map(lambda z, g: decay * z + g, slot.z, olr.grad)
        y_new = jax.tree.map(lambda y, g: decay * y + g, slot.y, g_v)
        keep = lambda new, old: jax.tree.map(  # noqa: E731
            lambda n, o: jnp.where(completed, n, jnp.where(stopped, jnp.zeros_like(o), o)), new, old)
        slot = EnvSlot(env=env_state, ar=ar._replace(i=jnp.where(stopped, 0, ar.i)), olr=olr,
                       z=keep(z_new, slot.z), y=keep(y_new, slot.y), s_start=s_start, rbar=rbar,
                       gpow=gpow)
        d_used = jnp.where(completed, d, 0.0)
        return slot, d_used, completed, stopped, env_state

    def step(ts: TrainState, _):
        h = ts.hyper
        key, k_eps = jax.random.split(ts.key)
        eps = jax.random.normal(k_eps, (N, ACT_DIM), jnp.float32)
        if num_shards > 1:
            eps = jax.lax.dynamic_slice_in_dim(eps, jax.lax.axis_index(axis_name) * N_local, N_local)
        slots, d, completed, stopped, es = jax.vmap(slot_step, in_axes=(None, None, 0, 0, None))(
            ts.theta, ts.v, ts.slots, eps, h)
        n_done = psum(jnp.sum(stopped.astype(jnp.int32)))
        n_learn = psum(jnp.sum(completed.astype(jnp.int32)))
        # Table II steps 4, 5 summed over the environments: optax gets the negated pseudo-gradients
        # -sum_e d_e z_e and -sum_e d_e y_e (d_e = 0 where no period ended) and the traced step sizes.
        g_theta = jax.tree.map(lambda z: -psum(jnp.tensordot(d, z, axes=1)), slots.z)
        g_v = jax.tree.map(lambda y: -psum(jnp.tensordot(d, y, axes=1)), slots.y)
        u_theta, opt_theta = tx_theta.update(g_theta, with_learning_rate(ts.opt_theta, h.beta_theta), ts.theta)
        u_v, opt_v = tx_v.update(g_v, with_learning_rate(ts.opt_v, h.beta_v), ts.v)
        theta = optax.apply_updates(ts.theta, u_theta)
        v = optax.apply_updates(ts.v, u_v)
        learn = n_learn > 0  # an update instant: some environment's period ended at this step
        ok = (global_norm(theta) < cfg.budget.max_param_norm) & (global_norm(v) < cfg.budget.max_param_norm)
        ok = (ok | ~learn) & ~ts.diverged  # a diverged point stays frozen at its last good parameters
        take = ok & learn
        theta = tree_where(take, theta, ts.theta)
        v = tree_where(take, v, ts.v)
        opt_theta = tree_where(take, opt_theta, ts.opt_theta)
        opt_v = tree_where(take, opt_v, ts.opt_v)
        if TERMINATES:  # a new trial after a fall: its traces start at 0 (after they took part above)
            ended = slots.env.done > 0
            zero = lambda t: jax.tree.map(  # noqa: E731
                lambda x: jnp.where(ended.reshape((-1,) + (1,) * (x.ndim - 1)), 0.0, x), t)
            slots = slots.replace(z=zero(slots.z), y=zero(slots.y))
        new = ts.replace(theta=theta, v=v, slots=slots, key=key, step=ts.step + 1,
                         trials=ts.trials + n_done, periods=ts.periods + n_learn,
                         diverged=ts.diverged | ~ok, opt_theta=opt_theta, opt_v=opt_v)
        stats = {
            "reward": psum(jnp.sum(es.reward)) / N,
            **{k: psum(jnp.sum(es.metrics[k])) / N for k in REWARD_TERMS},
            "forward_speed": psum(jnp.sum(es.metrics["forward_speed"])) / N,
            "nonfinite": psum(jnp.sum(es.metrics["nonfinite"])),
            "trials": n_done,
            "periods": n_learn,
            "td_sum": psum(jnp.sum(d)),
            "td_sq": psum(jnp.sum(d * d)),
            "td_absmax": pmax(jnp.max(jnp.abs(d))),
            # global norms of the summed pseudo-gradients sum_e d_e z_e, sum_e d_e y_e (0 where no
            # period ended) and of the updates the optimizers made of them
            "gnorm_theta": global_norm(g_theta),
            "gnorm_v": global_norm(g_v),
            "unorm_theta": jnp.where(take, global_norm(u_theta), 0.0),
            "unorm_v": jnp.where(take, global_norm(u_v), 0.0),
            "learn": take,
        }
        if cfg.grad_stats:
            # g_e = d_e grad ln pi_e for every period that ended here (d_e = 0 otherwise), unflattened
            g = jax.vmap(lambda t: jax.flatten_util.ravel_pytree(t)[0])(slots.olr.grad)
            g = d[:, None] * g
            stats["g_sum"] = psum(jnp.sum(g, axis=0))
            stats["g_sqnorm"] = psum(jnp.sum(g * g))
        return new, stats

    def chunk(ts: TrainState) -> tuple[TrainState, dict]:
        ts, stats = jax.lax.scan(step, ts, None, length=cfg.budget.chunk_steps)
        n = jnp.maximum(jnp.sum(stats["periods"]), 1)
        td_mean = jnp.sum(stats["td_sum"]) / n
        out = {
            "avg_reward": jnp.mean(stats["reward"]),
            "forward_speed": jnp.mean(stats["forward_speed"]),
            **{k: jnp.mean(stats[k]) for k in REWARD_TERMS},
            "trials_in_chunk": jnp.sum(stats["trials"]),
            "periods_in_chunk": jnp.sum(stats["periods"]),
            "nonfinite": jnp.sum(stats["nonfinite"]),
            "td_mean": td_mean,
            "td_std": jnp.sqrt(jnp.maximum(jnp.sum(stats["td_sq"]) / n - td_mean**2, 0.0)),
            "td_absmax": jnp.max(stats["td_absmax"]),
            # the summed pseudo-gradients' and the updates' global norms over the chunk's update
            # instants: mean and max (what clipping by global norm would act on)
            **{f"{k}_{f}": fn(stats[k], jnp.sum(stats["learn"]))
               for k in ("gnorm_theta", "gnorm_v", "unorm_theta", "unorm_v")
               for f, fn in (("mean", lambda x, n: jnp.sum(x) / jnp.maximum(n, 1)),
                             ("max", lambda x, n: jnp.max(x)))},
            "theta_norm": global_norm(ts.theta),
            "v_norm": global_norm(ts.v),
            "diverged": ts.diverged,
            "step": ts.step,
            "trials": ts.trials,
            "periods": ts.periods,
        }
        if cfg.grad_stats:
            out["g_sum"] = jnp.sum(stats["g_sum"], axis=0)
            out["g_sqnorm"] = jnp.sum(stats["g_sqnorm"])
        return ts, out

    return ACTrainer(config=cfg, env=env, init=init, chunk=chunk, init_opt=init_opt)
