"""The Brax side of the PPO baseline: Brax's PPO, its networks and deterministic policy, the
environment it trains on, and the evaluation of its parameters like ``nmrl eval``.

:func:`brax_ppo` imports Brax (optional: ``pip install -e '.[brax]'``); :func:`train_kwargs` maps a
:class:`~nmrl.experiments.baseline_config.BaselineConfig` onto ``brax.training.agents.ppo.train``'s
arguments (Brax's own networks, ``make_ppo_networks``, of the config's sizes; the learning's
rewards summed by nmrl.adapters.brax_env.Tally instead of Brax's logger); :func:`environment` is
:class:`nmrl.adapters.brax_env.BraxHalfCheetah` (the paper's robot, state, reward (8)-(14) and stop
rule) or a v5 task (nmrl/adapters/brax_task.py). :func:`policy_action` is the mode of Brax's
tanh-Gaussian policy mapped to the environment's action; :func:`evaluate_params` rolls it out for
``eval_seconds`` (nmrl.analysis.evaluate.rollout_policy) or, on a task, for 10 episodes
(nmrl.analysis.task_eval.act_episodes); :func:`evaluate_checkpoint` evaluates a run directory's
checkpoint (or compact state) into eval.json, a strobe picture and a GIF.
"""

from __future__ import annotations

import functools
import json
import os
import pathlib
from typing import Any, Callable

import jax.numpy as jnp

from nmrl import tasks
from nmrl.adapters import brax_env, brax_task
from nmrl.analysis import evaluate, task_eval
from nmrl.experiments.baseline_config import BaselineConfig, load_config
from nmrl.paper.env import EnvConfig
from nmrl.runs import checkpoint, errors, store
from nmrl.tasks.env import Task, TaskConfig

__all__ = ["brax_ppo", "train_kwargs", "environment", "policy_action", "initial_params", "evaluate_params",
           "evaluate_checkpoint"]


def brax_ppo():
    """Brax's PPO (``train``, ``networks``) and its running statistics; ImportError naming the extra
    to install when Brax is missing."""
    brax_env.require_brax()
    from brax.training.agents.ppo import networks as ppo_networks
    from brax.training.agents.ppo import train as ppo_train
    from brax.training.acme import running_statistics

    return ppo_train, ppo_networks, running_statistics


@functools.lru_cache(maxsize=4)
def _networks(policy_hidden: tuple[int, ...], value_hidden: tuple[int, ...], normalize: bool,
              dims: tuple[int, int] = (brax_env.OBS_DIM, brax_env.ACT_DIM)):
    _, ppo_networks, running_statistics = brax_ppo()
    pre = running_statistics.normalize if normalize else (lambda x, y: x)
    return ppo_networks.make_ppo_networks(*dims, preprocess_observations_fn=pre,
                                          policy_hidden_layer_sizes=policy_hidden,
                                          value_hidden_layer_sizes=value_hidden)


def _network_factory(cfg: BaselineConfig) -> Callable:
    def factory(obs_size, act_size, preprocess_observations_fn):
        _, ppo_networks, _ = brax_ppo()
        return ppo_networks.make_ppo_networks(obs_size, act_size, preprocess_observations_fn=preprocess_observations_fn,
                                              policy_hidden_layer_sizes=cfg.policy_hidden,
                                              value_hidden_layer_sizes=cfg.value_hidden)
    return factory


@functools.lru_cache(maxsize=8)
def _actor(policy_hidden: tuple[int, ...], value_hidden: tuple[int, ...], normalize: bool,
           env: str = tasks.PAPER, control_dt: float = 0.02) -> Callable:
    """A module-level-stable ``act(params, obs) -> a``: the mode of Brax's tanh-Gaussian policy (its
    deterministic action u), mapped to the environment's action: the paper's a = ACTION_SCALE u, a
    task's ``offset + scale u`` (brax_task.BraxTask.action)."""
    if env == tasks.PAPER:
        nets = _networks(policy_hidden, value_hidden, normalize)
        to_action = lambda u: brax_env.ACTION_SCALE * jnp.clip(u, -1.0, 1.0)  # noqa: E731
    else:
        task = Task(env, TaskConfig(control_dt=control_dt))
        nets = _networks(policy_hidden, value_hidden, normalize, (task.obs_dim, task.act_dim))
        lo, scale = jnp.asarray(task.action_offset, jnp.float32), jnp.asarray(task.action_scale, jnp.float32)
        to_action = lambda u: lo + scale * jnp.clip(u, -1.0, 1.0)  # noqa: E731

    def act(params, obs):
        logits = nets.policy_network.apply(params[0], params[1], obs)
        return to_action(nets.parametric_action_distribution.mode(logits))

    return act


def policy_action(cfg: BaselineConfig) -> Callable:
    """``act(params, obs)`` of the deterministic PPO policy of ``cfg``'s networks (params =
    (normalizer, policy, value), as Brax returns and :func:`run` saves them)."""
    return _actor(tuple(cfg.policy_hidden), tuple(cfg.value_hidden), bool(cfg.normalize_observations),
                  cfg.env, float(cfg.control_dt))


def _tally_every(cfg: BaselineConfig) -> int:
    """Steps per environment between two reports of brax_env.Tally: the largest divisor of an
    iteration's steps per environment up to 256, so that each metrics row sums exactly the steps of
    its iteration."""
    per_env = cfg.steps_per_iteration // cfg.num_envs
    return max(d for d in range(1, min(256, per_env) + 1) if per_env % d == 0)


def train_kwargs(cfg: BaselineConfig, tally: Callable | None = None) -> dict:
    """``ppo.train``'s arguments for ``cfg`` but the environment, budget, seed and callbacks; ``tally``:
    the sink of the learning's rewards (brax_env.Tally), None for none."""
    return dict(
        num_envs=cfg.num_envs, episode_length=cfg.episode_cap, action_repeat=1,
        wrap_env_fn=(brax_env.wrap_for_training if tally is None
                     else functools.partial(brax_env.wrap_for_training, tally=tally, tally_every=_tally_every(cfg))),
        learning_rate=cfg.learning_rate,
        entropy_cost=cfg.entropy_cost, discounting=cfg.discounting, unroll_length=cfg.unroll_length,
        batch_size=cfg.batch_size, num_minibatches=cfg.num_minibatches,
        num_updates_per_batch=cfg.num_updates_per_batch, normalize_observations=cfg.normalize_observations,
        reward_scaling=cfg.reward_scaling, network_factory=_network_factory(cfg), run_evals=False,
        log_training_metrics=False,  # Brax's logger deadlocked with 2 CPU devices: brax_env.Tally instead
    )


def environment(cfg: BaselineConfig) -> brax_env.BraxHalfCheetah | brax_task.BraxTask:
    """The Brax environment of ``cfg``: the paper's robot or its v5 task."""
    if cfg.is_task:
        return brax_task.BraxTask(cfg.env, cfg.control_dt, cfg.physics)
    return brax_env.BraxHalfCheetah(EnvConfig(control_dt=cfg.control_dt, stop_prob=cfg.stop_prob,
                                              physics=cfg.physics))


def initial_params(cfg: BaselineConfig) -> Any:
    """Brax's initial (normalizer, policy, value) for ``cfg`` (``ppo.train`` with no steps)."""
    ppo_train, _, _ = brax_ppo()
    _, params, _ = ppo_train.train(environment(cfg), num_timesteps=0, seed=cfg.seed, **train_kwargs(cfg))
    return params


def evaluate_params(cfg: BaselineConfig, params: Any, *, seconds: float | None = None, seed: int = 0) -> dict:
    """The deterministic policy's rollout of ``seconds`` (default cfg.eval_seconds), summarized as in
    ``nmrl eval`` (avg_reward per step, forward_speed, terms, ground shares); ``traj`` kept under
    ``"_traj"`` for pictures. On a task: the returns of 10 episodes (task_eval.act_episodes), no ``_traj``."""
    if cfg.is_task:
        return task_eval.act_episodes(policy_action(cfg), params, cfg.env, cfg.control_dt, cfg.physics, seed=seed)
    traj = evaluate.rollout_policy(policy_action(cfg), params, control_dt=cfg.control_dt,
                                   seconds=cfg.eval_seconds if seconds is None else seconds, seed=seed,
                                   physics=cfg.physics)
    out = evaluate.summarize(traj)
    out["_traj"] = traj
    return out


def evaluate_checkpoint(run_dir: str | os.PathLike, step: int | None = None, *, seconds: float = 10.0,
                        render: bool = True, out_dir: str | os.PathLike | None = None) -> dict:
    """Evaluate a PPO baseline checkpoint like ``nmrl eval`` (JSON, strobe, GIF in ``out_dir``,
    default RUN_DIR/eval). A directory with ``compact.npz`` and no ``checkpoints/`` (a seed
    published while unfinished, ``results/baseline_ppo/ppo_s{seed}``) is evaluated from its compact
    state; one with neither is refused (errors.RunError)."""
    run_dir = pathlib.Path(run_dir)
    cfg = load_config(run_dir)
    if not checkpoint.checkpoint_dir(run_dir).exists() and not checkpoint.has_compact(run_dir):
        raise errors.RunError(
            f"{run_dir}: no parameters to evaluate (no checkpoints/, no compact.npz); a finished seed "
            f"published under results/baseline_ppo keeps only its config and metrics: evaluate the run "
            f"directory that trained it (runs/baseline_ppo/ppo_s{{seed}}); the best seed's gait is "
            f"published in results/baseline_ppo/gaits/ppo_best")
    restore = checkpoint.restore_tree_compact if checkpoint.uses_compact(run_dir) else checkpoint.restore_tree
    meta, params = restore(run_dir, initial_params(cfg), step)
    ev = evaluate_params(cfg, params, seconds=seconds)
    traj = ev.pop("_traj", None)
    out_dir = pathlib.Path(out_dir) if out_dir is not None else run_dir / evaluate.EVAL_DIR
    out_dir.mkdir(parents=True, exist_ok=True)
    result = {"run_dir": str(run_dir), "step": int(meta["step"]), "seconds": float(seconds),
              "control_dt": cfg.control_dt, "deterministic": ev}
    if render and traj is not None:
        title = f"{run_dir.name} (Brax PPO), {int(meta['step']):,} control steps, deterministic policy"
        strobe = evaluate.plot_strobe(traj["pos"], cfg.control_dt, out_dir / "strobe.png", title=title)
        gif = evaluate.write_gif(traj["pos"], cfg.control_dt, out_dir / "gait.gif")
        result["files"] = {"strobe": str(strobe), "gif": str(gif)}
    store.atomic_write_text(out_dir / "eval.json", json.dumps(result, indent=2, allow_nan=False) + "\n")
    return result
