"""PPO with any exploration process of nmrl.explore, as the learner ``ppo`` (pure JAX).

``trainer = make_ppo(config)`` gives pure ``trainer.init(key, hyper=None)`` and ``trainer.chunk(state)``
(nested ``lax.scan``s; nmrl/learners/contract.py). One PPO *iteration* is Brax PPO's training step:

1. every environment runs ``U = batch_size * num_minibatches / num_envs`` unrolls of
   ``T = round(unroll_s / control_dt)`` control steps with the behaviour parameters theta_old;
   the pre-squash action is ``x_t = mu_theta(s_t) + std_theta(s_t) xi_t`` (eq. (6) with a learned
   scale), ``xi`` the exploration process (white noise: Brax's i.i.d. normal), whose state is carried
   per environment across unrolls, iterations and chunks and reset where a trial ends; the
   environment gets ``ACTION_SCALE * tanh(x_t)``. Stored per step: s_t, x_t, r_t, the stop flags,
   ``fresh_t`` (a period or trial started) and ``log pi_old(x_t | past)``; per unroll: the filter
   belief about the noise at its start and the observation after its last step;
2. the running observation statistics take the iteration's observations (Brax: before the update);
3. ``epochs`` passes over the data, each a shuffle of the unrolls into ``num_minibatches``
   minibatches of ``batch_size`` whole unrolls (sequences are never cut: the likelihood of a step
   depends on the noise before it), one Adam step per minibatch on
   ``clipped surrogate + vf_coef * 0.5 (vs - V)^2 - entropy_cost * entropy`` with GAE
   (nmrl/learners/ppo_losses.py) recomputed per minibatch under the current value net, as Brax does.

**The likelihood ratio** is the process's exact conditional density, not a per-step marginal: with
``xi_t(theta) = (x_t - mu_theta(s_t)) / std_theta(s_t)`` rebuilt under the current theta for the
whole unroll, ``log pi_theta(x_t | x_<t) = log p_xi(xi_t(theta) | xi_<t(theta)) - sum_j log
std_theta,j(s_t)`` (change of variables), where ``log p_xi`` is nmrl.explore's Kalman filter started
from the belief stored at the unroll's start (computed under theta_old at rollout time). For the
nm-periods process this is eq. (7) factorised into its per-step innovations (docs/ppo.md). The
tanh of the action does not depend on theta: its log-Jacobian at the stored ``x_t`` cancels in
``pi_theta / pi_old``, so the ratio is taken on ``x``.

**Time in seconds.** The discount, the GAE lambda, the unroll and the noise's correlation times
are given in seconds; at 0.02 s every default is the Brax baseline's. The config
(:class:`~nmrl.learners.ppo_config.PPOConfig`) and its traced ``Hyper`` are
nmrl/learners/ppo_config.py; docs/ppo.md has the conversions and what differs from Brax.

Divergence: a parameter that is non-finite, or a global norm above ``max_param_norm``, after an
iteration undoes that iteration's update and freezes the point (``diverged``), as in the actor-critic.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import optax
from flax import struct

from nmrl import explore, tasks
from nmrl.learners import heartbeat
from nmrl.learners import ppo_losses as L
from nmrl.learners import ppo_networks as nn_
from nmrl.learners.ppo_config import Hyper, PPOConfig
from nmrl.learners.ppo_policy import policy  # noqa: F401 - ppo.policy, the learner's evaluation policy
from nmrl.pytrees import check_shards, global_norm, tree_where


@struct.dataclass
class PPOState:
    policy: Any  #: policy network parameters (mu and the std head)
    value: Any  #: value network parameters
    opt: Any  #: Adam's state over {"policy", "value"}
    obs_stats: nn_.ObsStats  #: running observation statistics
    env: Any  #: environment states (leading axis num_envs)
    noise: explore.NoiseState  #: exploration state per environment
    key: jax.Array
    hyper: Hyper
    step: jax.Array  #: control steps per environment so far
    trials: jax.Array  #: trials ended, summed over the environments
    diverged: jax.Array


class Batch(NamedTuple):
    """Sequences (one unroll of one environment each): leading axes (..., T) per step."""

    obs: jax.Array  #: (..., T, obs) s_t
    x: jax.Array  #: (..., T, n) pre-squash action
    logp: jax.Array  #: (..., T) log pi_old(x_t | x since the last reset)
    fresh: jax.Array  #: (..., T) bool, the noise started a period or trial at t
    reward: jax.Array  #: (..., T) r_t (unscaled)
    termination: jax.Array  #: (..., T) 1 where the trial terminated (the value after is 0): the physics
    #: failed, or a task's own rule (Gymnasium's ``terminated``: unhealthy)
    truncation: jax.Array  #: (..., T) 1 where any other end (the stop rule, a time limit) cut the trial
    #: (no learning signal)
    next_obs: jax.Array  #: (..., obs) the observation after the unroll's last step
    mean0: jax.Array  #: (..., K, n) noise filter belief at the unroll's start
    cov0: jax.Array  #: (..., K, K)


class PPOTrainer(NamedTuple):
    config: PPOConfig
    env: Any
    init: Callable[..., PPOState]
    chunk: Callable[[PPOState], tuple[PPOState, dict]]
    nets: nn_.Networks
    #: ``seq_logp(policy, obs_stats, batch, process) -> (..., T)``: log pi_theta of a batch's actions
    seq_logp: Callable[..., jax.Array]
    #: ``loss(params, obs_stats, batch, hyper, eps, count) -> (local loss, sums)`` of one minibatch
    loss: Callable[..., tuple[jax.Array, dict]]
    #: ``rollout(state, key) -> ((env, noise, sums), data)``: one iteration's unrolls, ``data`` (N, U, T, ...)
    rollout: Callable[..., Any]
    #: ``learn(state, data, key) -> (params, opt, obs_stats, loss sums)``: one iteration's update
    learn: Callable[..., Any]
    #: ``minibatches(data, key) -> Batch (M, batch_size, T, ...)``: one epoch's minibatches of whole unrolls
    minibatches: Callable[..., Batch]


def _sample_per_env(proc: explore.Process, ns: explore.NoiseState, keys: jax.Array):
    """explore.sample with one key per environment (the draws do not depend on how many
    environments a shard holds)."""
    def one(n1, k):
        xi, lp, fr, n1 = explore.sample(proc, jax.tree.map(lambda a: a[None], n1), k)
        return xi[0], lp[0], fr[0], jax.tree.map(lambda a: a[0], n1)
    return jax.vmap(one)(ns, keys)


def make_ppo(config: PPOConfig, env: Any = None, *, axis_name: str | None = None, num_shards: int = 1) -> PPOTrainer:
    """Build the pure functions of a PPO run (module docstring; ``env`` as for the actor-critic:
    ``tasks.make_env(config.environment.env, config.environment.env_config())`` by default). With
    ``num_shards`` > 1, ``chunk`` is written for ``jax.shard_map`` over the environment axis of ``env`` and ``noise``: every draw is made per
    environment from the shared key, the minibatches take the same unrolls, and the sums behind the
    losses, gradients and statistics are ``psum``-ed over ``axis_name``."""
    check_shards(config.budget.num_envs, num_shards, axis_name)
    cfg = config.resolved()
    env = env or tasks.make_env(cfg.environment.env, cfg.environment.env_config())
    OBS, ACT = env.obs_dim, env.act_dim
    SCALE = nn_.action_range(env)
    TERMS = tuple(env.reward_terms)
    N, NL = cfg.budget.num_envs, cfg.budget.num_envs // num_shards
    T, U, M, E = cfg.unroll_length, cfg.unrolls_per_env, cfg.num_minibatches, cfg.epochs
    UM = U // M  # unrolls of each environment in one minibatch
    ITERS = cfg.budget.chunk_steps // cfg.iteration_steps
    COUNT = float(cfg.batch_size * T)  # samples per minibatch (all shards)
    nets = nn_.make_networks(cfg.policy_layers, cfg.policy_width, cfg.value_layers, cfg.value_width, ACT,
                             cfg.learn_std)
    adam = optax.scale_by_adam()
    tx = adam if cfg.max_grad_norm is None else optax.chain(optax.clip_by_global_norm(cfg.max_grad_norm), adam)

    def psum(x):
        return jax.lax.psum(x, axis_name) if num_shards > 1 else x

    def local(x):
        """This shard's slice of an array over all N environments (leading axis)."""
        if num_shards == 1:
            return x
        return jax.lax.dynamic_slice_in_dim(x, jax.lax.axis_index(axis_name) * NL, NL)

    def init(key: jax.Array, hyper: Hyper | None = None) -> PPOState:
        hyper = Hyper.from_config(cfg) if hyper is None else hyper
        k_net, k_env, k_noise, key = jax.random.split(key, 4)
        policy, value = nn_.init_params(nets, k_net, OBS)
        env_states = jax.vmap(env.reset)(jax.random.split(k_env, N))
        noise = explore.init(hyper.process, k_noise, N, ACT)
        z = jnp.zeros((), jnp.int32)
        return PPOState(policy=policy, value=value, opt=tx.init({"policy": policy, "value": value}),
                        obs_stats=nn_.obs_init(OBS), env=env_states, noise=noise, key=key, hyper=hyper,
                        step=z, trials=z, diverged=jnp.zeros((), bool))

    def norm(stats, obs):
        return nn_.normalize(stats, obs, cfg.normalize_obs)

    def logp_of(mu, std, b: Batch, proc: explore.Process) -> jax.Array:
        xi = (b.x - mu) / std
        lead = xi.shape[:-2]
        flat = lambda a: a.reshape((-1,) + a.shape[len(lead):])  # noqa: E731
        lp = jax.vmap(explore.log_prob, in_axes=(None, 0, 0, 0, 0))(
            proc, flat(b.mean0), flat(b.cov0), flat(xi), flat(b.fresh))
        return lp.reshape(xi.shape[:-1]) - jnp.sum(jnp.log(std), axis=-1)  # (..., sequence length)

    def seq_logp(policy, stats, b: Batch, proc: explore.Process) -> jax.Array:
        """log pi_theta(x_t | x since the last reset) of every step of ``b`` (leading axes (..., T)):
        xi rebuilt as (x - mu_theta) / std_theta, the process's filter from the stored belief, and
        the change of variables -sum log std_theta."""
        mu, std = nn_.mean_std(nets, policy, norm(stats, b.obs), cfg.min_std)
        return logp_of(mu, std, b, proc)

    def tm(a):
        """The first two axes swapped: (B, T, ...) <-> (T, B, ...)."""
        return jnp.swapaxes(a, 0, 1)

    def targets(values, boot, b: Batch, h: Hyper):
        """Time-major ``(w, vs, adv, start)`` of a batch (leading axes (B, T)) under its values: GAE at
        every step (weights 1), or at the starts of nm-periods when period-wise (weights 1 there, 0
        elsewhere; ``start`` the period starts, else None)."""
        if cfg.period_wise:  # one sample per period (segment) of the unroll, at its start
            start = tm(b.fresh).at[0].set(True)
            vs, adv = L.period_gae(tm(b.reward * h.reward_scale), tm(values), boot, tm(b.termination),
                                   tm(b.truncation), start, h.gamma, h.lam)
            return tm(start.astype(values.dtype)), tm(vs), tm(adv), start
        vs, adv = L.gae(tm(b.reward * h.reward_scale), tm(values), boot, tm(b.termination), tm(b.truncation),
                        h.gamma, h.lam)
        return jnp.ones_like(values), tm(vs), tm(adv), None

    def moments(w, adv):
        """This shard's ``(sum w, sum w adv, sum w adv^2)`` of a batch's advantages."""
        return jnp.sum(w), jnp.sum(adv * w), jnp.sum(adv * adv * w)

    def loss(params, stats, b: Batch, h: Hyper, eps: jax.Array, count: float = COUNT, whole=None):
        """This shard's part of one minibatch's loss (its sums / the minibatch's ``count`` samples)
        and the sums behind the diagnostics; ``b`` has leading axes (B, T). ``whole``: the
        minibatch's ``(n, sum w adv, sum w adv^2)`` when ``b`` is a part of it (:func:`minibatch_grad`),
        else they are ``b``'s own."""
        obs_n = norm(stats, b.obs)
        mu, std = nn_.mean_std(nets, params["policy"], obs_n, cfg.min_std)
        logp = logp_of(mu, std, b, h.process)
        values = nn_.value(nets, params["value"], obs_n)
        boot = nn_.value(nets, params["value"], norm(stats, b.next_obs))
        std_x = h.process.sigma * std  # marginal std of x
        ent = nn_.entropy(std_x, mu + std_x * eps, cfg.squash)
        w, vs, adv, start = targets(values, boot, b, h)
        if cfg.period_wise:
            logp_new = tm(L.segment_sums(tm(logp - b.logp), start))
            logp_old = jnp.zeros_like(logp_new)
        else:
            logp_new, logp_old = logp, b.logp
        if whole is None:
            sw, sa, saa = moments(w, adv)
            whole = (psum(sw) if cfg.period_wise else count, psum(sa), psum(saa))
        n = whole[0]  # the samples of the minibatch (all shards)
        if cfg.normalize_advantage:
            adv = L.normalize_advantages(adv, whole[1], n, whole[2])
        pl, diag = L.clipped_surrogate(logp_new, logp_old, adv, h.clip_eps)
        vl = L.value_loss(values, vs, h.vf_coef)
        if cfg.period_wise:
            pl, vl = pl * w, vl * w
            total = (jnp.sum(pl) + jnp.sum(vl)) / n - h.entropy_cost * jnp.sum(ent) / count
        else:
            total = (jnp.sum(pl) + jnp.sum(vl) - h.entropy_cost * jnp.sum(ent)) / count
        per = count / n  # the sums are reported per sample: per period when period-wise
        sums = {"policy_loss": jnp.sum(pl) * per, "value_loss": jnp.sum(vl) * per, "entropy": jnp.sum(ent),
                "approx_kl": jnp.sum(diag["approx_kl"] * w) * per, "clip_frac": jnp.sum(diag["clipped"] * w) * per,
                "std": jnp.sum(jnp.mean(std_x, axis=-1))}
        return total, jax.lax.stop_gradient(sums)

    grad_fn = jax.grad(loss, has_aux=True)
    C = cfg.grad_chunks

    def whole_sums(value_params, stats, parts: Batch, h: Hyper) -> tuple:
        """The minibatch's ``(n, sum w adv, sum w adv^2)`` (all shards) from its ``parts`` (leading
        axes (C, B / C, T)), each part's advantages under the value net as :func:`loss` computes them."""
        def one(b):
            w, _, adv, _ = targets(nn_.value(nets, value_params, norm(stats, b.obs)),
                                   nn_.value(nets, value_params, norm(stats, b.next_obs)), b, h)
            return jnp.stack(moments(w, adv))
        s = psum(jnp.sum(jax.lax.map(one, parts), axis=0))
        return (s[0] if cfg.period_wise else COUNT), s[1], s[2]

    def minibatch_grad(params, stats, mb: Batch, h: Hyper, eps: jax.Array):
        """The gradient of one minibatch's loss and its sums: at once, or (``grad_chunks`` C > 1) summed
        over C parts of its unrolls taken in turn, the advantages normalised over the whole minibatch
        first -- the same gradient up to float rounding, with a C times smaller working set."""
        if C == 1:
            return grad_fn(params, stats, mb, h, eps)
        split = lambda a: a.reshape((C, a.shape[0] // C) + a.shape[1:])  # noqa: E731
        parts, eps_parts = jax.tree.map(split, mb), split(eps)
        whole = whole_sums(params["value"], stats, parts, h)

        def part_grad(b, e):
            return grad_fn(params, stats, b, h, e, COUNT, whole)

        def add(acc, part):
            return jax.tree.map(jnp.add, acc, part_grad(*part)), None
        shapes = jax.eval_shape(part_grad, jax.tree.map(lambda a: a[0], parts), eps_parts[0])
        zero = jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), shapes)
        return jax.lax.scan(add, zero, (parts, eps_parts))[0]

    # ------------------------------------------------------------------------------- rollout
    def rollout_step(carry, key):
        es, ns, policy, stats, h, acc = carry
        mu, std = nn_.mean_std(nets, policy, norm(stats, es.obs), cfg.min_std)
        xi, logp_xi, fresh, ns = _sample_per_env(h.process, ns, local(jax.random.split(key, N)))
        x = mu + std * xi
        logp = logp_xi - jnp.sum(jnp.log(std), axis=-1)
        new = jax.vmap(env.step)(es, nn_.squash(x, cfg.squash, *SCALE))
        done = new.done > 0
        failed = new.metrics["nonfinite"] > 0
        ns = explore.reset(h.process, ns, done)
        acc = {"reward": acc["reward"] + jnp.sum(new.reward),
               "forward_speed": acc["forward_speed"] + jnp.sum(new.metrics["forward_speed"]),
               "trials": acc["trials"] + jnp.sum(done.astype(jnp.int32)),
               "nonfinite": acc["nonfinite"] + jnp.sum(failed.astype(jnp.int32)),
               **{k: acc[k] + jnp.sum(new.metrics[k]) for k in TERMS}}
        # termination: the environment's own rule where it has one (a Gymnasium task: unhealthy or a
        # failed physics step), else a failed physics step; every other end of a trial truncates
        term = done & (new.info["terminated"] > 0) if "terminated" in new.info else done & failed
        tr = (es.obs, x, logp, fresh, new.reward, term.astype(jnp.float32), (done & ~term).astype(jnp.float32))
        return (new, ns, policy, stats, h, acc), tr

    shard = (lambda: jax.lax.axis_index(axis_name)) if num_shards > 1 else (lambda: 0)  # heartbeats' source

    def unroll(carry, inp):
        (key, u), (es, ns, policy, stats, h, acc) = inp, carry
        mean0, cov0, _ = explore.belief(ns)
        carry, tr = jax.lax.scan(rollout_step, carry, jax.random.split(key, T))
        heartbeat.beat("rollout", u, U, shard())
        # (T, NL, ...) -> (NL, T, ...)
        tr = jax.tree.map(tm, tr)
        return carry, Batch(*tr, next_obs=carry[0].obs, mean0=mean0, cov0=cov0)

    # ------------------------------------------------------------------------------- update
    def minibatch(carry, inp, data: Batch, h: Hyper):
        params, opt, stats = carry
        idx, key = inp  # idx (NL, UM): the unrolls of each of this shard's environments
        mb = take(data, idx)
        eps = local(jax.random.normal(key, (N, UM, T, ACT), jnp.float32)).reshape(NL * UM, T, ACT)
        grads, sums = minibatch_grad(params, stats, mb, h, eps)
        grads = jax.tree.map(psum, grads)
        upd, opt = tx.update(grads, opt, params)
        params = jax.tree.map(lambda p, u: p + (-h.learning_rate) * u, params, upd)
        return (params, opt, stats), jax.tree.map(psum, sums)

    def minibatch_indices(key) -> jax.Array:
        """(M, NL, UM): for each minibatch, the unrolls it takes of each of this shard's environments
        (one permutation of the U unrolls per environment, drawn for all N from the shared key)."""
        perm = jax.vmap(lambda k: jax.random.permutation(k, U))(jax.random.split(key, N))
        return jnp.swapaxes(local(perm).reshape(NL, M, UM), 0, 1)

    def take(data: Batch, idx: jax.Array) -> Batch:
        """The minibatch of whole unrolls ``idx`` (NL, UM) of ``data`` (NL, U, ...): (NL * UM, ...)."""
        mb = jax.tree.map(lambda a: jax.vmap(lambda a_e, i_e: a_e[i_e])(a, idx), data)
        return jax.tree.map(lambda a: a.reshape((NL * UM,) + a.shape[2:]), mb)

    def minibatches(data: Batch, key: jax.Array) -> Batch:
        """One epoch's minibatches of ``data`` (NL, U, T, ...), stacked: (M, NL * UM, T, ...)."""
        return jax.vmap(lambda i: take(data, i))(minibatch_indices(key))

    def epoch(carry, inp, data: Batch, h: Hyper):
        (k_perm, k_mb), e = jax.random.split(inp[0]), inp[1]
        out = jax.lax.scan(lambda c, i: minibatch(c, i, data, h), carry,
                           (minibatch_indices(k_perm), jax.random.split(k_mb, M)))
        heartbeat.beat("update", e, E, shard())
        return out

    def rollout(st: PPOState, key: jax.Array):
        """One iteration's unrolls: ``((env, noise, sums), data)`` with ``data`` (NL, U, T, ...)."""
        acc0 = {k: jnp.zeros((), jnp.float32) for k in ("reward", "forward_speed", *TERMS)}
        acc0.update(trials=jnp.zeros((), jnp.int32), nonfinite=jnp.zeros((), jnp.int32))
        (es, ns, _, _, _, acc), data = jax.lax.scan(
            unroll, (st.env, st.noise, st.policy, st.obs_stats, st.hyper, acc0), (jax.random.split(key, U), jnp.arange(U)))
        return (es, ns, acc), jax.tree.map(tm, data)  # (U, NL) -> (NL, U)

    def learn(st: PPOState, data: Batch, key: jax.Array):
        """The observation statistics and ``epochs`` x ``num_minibatches`` Adam steps on ``data``:
        ``(params, opt, stats, sums)``."""
        stats = nn_.obs_update(st.obs_stats, data.obs, psum) if cfg.normalize_obs else st.obs_stats
        params = {"policy": st.policy, "value": st.value}
        (params, opt, _), sums = jax.lax.scan(lambda c, k: epoch(c, k, data, st.hyper), (params, st.opt, stats),
                                              (jax.random.split(key, E), jnp.arange(E)))
        return params, opt, stats, sums

    def iteration(st: PPOState, _):
        key, k_roll, k_sgd = jax.random.split(st.key, 3)
        (es, ns, acc), data = rollout(st, k_roll)
        params, opt, stats, sums = learn(st, data, k_sgd)
        norms = (global_norm(params["policy"]), global_norm(params["value"]))
        ok = jnp.all(jnp.isfinite(jnp.stack(norms))) & (jnp.maximum(*norms) < cfg.budget.max_param_norm)
        take_it = ok & ~st.diverged
        params = tree_where(take_it, params, {"policy": st.policy, "value": st.value})
        opt = tree_where(take_it, opt, st.opt)
        stats = tree_where(take_it, stats, st.obs_stats)
        trials = psum(acc["trials"])
        new = st.replace(policy=params["policy"], value=params["value"], opt=opt, obs_stats=stats, env=es, noise=ns,
                         key=key, step=st.step + U * T, trials=st.trials + trials, diverged=st.diverged | ~ok)
        out = {k: psum(acc[k]) / (N * U * T) for k in ("reward", "forward_speed", *TERMS)}
        out.update({k: jnp.sum(v) / (E * M * COUNT) for k, v in sums.items()})
        out.update(trials=trials, nonfinite=psum(acc["nonfinite"]), learn=take_it)
        return new, out

    def chunk(st: PPOState) -> tuple[PPOState, dict]:
        st, o = jax.lax.scan(iteration, st, None, length=ITERS)
        metrics = {
            "avg_reward": jnp.mean(o["reward"]),
            "forward_speed": jnp.mean(o["forward_speed"]),
            **{k: jnp.mean(o[k]) for k in TERMS},
            "trials_in_chunk": jnp.sum(o["trials"]),
            "nonfinite": jnp.sum(o["nonfinite"]),
            **{k: jnp.mean(o[k]) for k in ("policy_loss", "value_loss", "entropy", "approx_kl", "clip_frac", "std")},
            "updates_in_chunk": jnp.sum(o["learn"].astype(jnp.int32)) * E * M,
            "policy_norm": global_norm(st.policy),
            "value_norm": global_norm(st.value),
            "diverged": st.diverged,
            "step": st.step,
            "trials": st.trials,
        }
        return st, metrics

    return PPOTrainer(config=cfg, env=env, init=init, chunk=chunk, nets=nets, seq_logp=seq_logp, loss=loss,
                      rollout=rollout, learn=learn, minibatches=minibatches)
