"""The peer on the same robot: Brax's PPO on the paper's Half-Cheetah, at the paper's sample budget;
and Brax's PPO on Gymnasium's v5 tasks (``env``: nmrl/adapters/brax_task.py).

``run(PPOConfig(seed=s), out)`` trains ``brax.training.agents.ppo.train`` on
:class:`nmrl.adapters.brax_env.BraxHalfCheetah` (the paper's robot, state, reward (8)-(14) and stop
rule; Brax's wrappers do the auto-reset, the stop is a truncation) for ``num_timesteps`` control
steps (default 2.5*10^7: the samples of 10^5 trials of ~250 steps, the paper's budget), in a run
directory of the run store's layout (nmrl/runs/store.py)::

    OUT/config.json     the PPOConfig (resume may change only num_timesteps)
    OUT/metrics.jsonl   one row per PPO iteration (batch_size * num_minibatches * unroll_length
                        control steps): step, wall time, the learning's average reward and forward
                        speed per control step (the exploring policy, every step since the previous
                        row, the paper's measure: nmrl.adapters.brax_env.Tally), the trials ended, and
                        this policy evaluated deterministically for ``eval_seconds``
                        (nmrl.analysis.evaluate.rollout_policy)
    OUT/checkpoints/N   the normalizer, policy and value parameters after N control steps (orbax,
                        nmrl.runs.checkpoint.save_tree), every iteration, newest 3 kept
    OUT/compact.npz     the newest of them as one small file (checkpoint.save_tree_compact, ~1 MB):
                        what results/baseline_ppo/ commits while the run is unfinished, so that a
                        fresh clone continues it (a finished seed's is not committed: its
                        ``--resume`` needs no parameters and does nothing)
    OUT/resumes.jsonl   one line per resume

**Hyperparameters.** The starting point is Brax's own PPO setting for its Half-Cheetah (the Brax
training notebook, ``BRAX_HALFCHEETAH``); :data:`CHANGES` lists every change with its reason.

**The tasks** (``env`` = ``halfcheetah-v5``, ``hopper-v5``, ``walker2d-v5``; :func:`task_config`): the
task's own control step (``control_dt``), its time limit as Brax's episode length (``episode_cap`` =
the task's ``max_steps``: a truncation; the task's ``terminated`` a termination), and, per
iteration, the deterministic policy's returns of 10 episodes (``eval_return``: mean,
nmrl.analysis.task_eval.act_episodes, the reset states of ``nmrl eval``) in place of the 10 s
rollout. ``env`` is stored in ``config.json`` only when it is not the paper's robot, so a run made
before the field existed keeps its config file and resumes.

**Resume** (``resume=True``): Brax's ``ppo.train`` runs as one call that cannot be checkpointed
mid-way; it can start from given parameters (``restore_params``). An interrupted run therefore
continues from its newest checkpoint's parameters and normalizer (or, with no ``checkpoints/``, from
``compact.npz``: the same arrays, so the same continuation) with a fresh Adam state, fresh
environments (every trial starts anew) and a new PRNG stream (``seed`` folded with the resume
count): statistically, not bitwise, the uninterrupted run. An uninterrupted run is exactly Brax's
PPO. SIGINT/SIGTERM stop after the iteration in flight is saved (:class:`nmrl.runs.driver.Stopped`).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
import pathlib
import sys
import threading
import time
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

from nmrl import tasks
from nmrl.analysis import evaluate, task_eval
from nmrl.adapters import brax_env, brax_task
from nmrl.paper.env import PHYSICS_HELP, EnvConfig
from nmrl.runs import checkpoint, driver, store

__all__ = ["PPOConfig", "BRAX_HALFCHEETAH", "CHANGES", "run", "load_config", "policy_action",
           "evaluate_checkpoint", "task_config"]

#: Brax's PPO setting for its Half-Cheetah (brax/notebooks/training.ipynb, ``train_fn`` for
#: ``halfcheetah``; networks: ``ppo_networks.make_ppo_networks``' defaults).
BRAX_HALFCHEETAH = {
    "num_timesteps": 50_000_000, "num_evals": 20, "reward_scaling": 1, "episode_length": 1000,
    "normalize_observations": True, "action_repeat": 1, "unroll_length": 20, "num_minibatches": 32,
    "num_updates_per_batch": 8, "discounting": 0.95, "learning_rate": 3e-4, "entropy_cost": 1e-3,
    "num_envs": 2048, "batch_size": 512, "policy_hidden": (32, 32, 32, 32), "value_hidden": (256,) * 5,
}

#: (field, Brax's value, ours, why) for every departure from BRAX_HALFCHEETAH.
CHANGES = (
    ("num_timesteps", "5e7", "2.5e7", "the paper's sample budget: 10^5 trials x ~250 control steps"),
    ("episode_length", "1000 (fixed)", "the paper's stop rule",
     "a trial stops with probability 1/250 after each step (Sec. V-C), a truncation (Sec. V-D); "
     "episode_length is only a cap, 10^4 (never reached: P = e^-40)"),
    ("num_evals", "20 (Brax's evaluator, fixed 1000-step episodes)",
     "one per iteration, nmrl's evaluation",
     "a checkpoint per iteration; the deterministic policy is rolled out for 10 s like nmrl eval"),
    ("num_envs", "2048", "64",
     "this machine is 2 CPU cores: MJX's step cost per environment grows with the batch per "
     "device (docs/performance.md); the samples per update (batch_size x num_minibatches x "
     "unroll_length = 327,680) are Brax's"),
)


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """Brax PPO on the paper's Half-Cheetah. Defaults: BRAX_HALFCHEETAH with CHANGES."""

    seed: int = 0
    num_timesteps: int = 25_000_000
    num_envs: int = 64
    batch_size: int = 512
    num_minibatches: int = 32
    unroll_length: int = 20
    num_updates_per_batch: int = 8
    discounting: float = 0.95
    learning_rate: float = 3e-4
    entropy_cost: float = 1e-3
    reward_scaling: float = 1.0
    normalize_observations: bool = True
    policy_hidden: tuple[int, ...] = (32, 32, 32, 32)
    value_hidden: tuple[int, ...] = (256, 256, 256, 256, 256)
    episode_cap: int = 10_000
    control_dt: float = 0.02
    stop_prob: float = 1 / 250
    eval_seconds: float = 10.0
    physics: str = "mjx"  #: the environment's physics engine (nmrl/paper/env.py PHYSICS)
    env: str = tasks.PAPER  #: the environment (nmrl.tasks.ENVS): the paper's robot or a v5 task

    @property
    def is_task(self) -> bool:
        return self.env != tasks.PAPER

    @property
    def steps_per_iteration(self) -> int:
        """Control steps (over all environments) per PPO iteration."""
        return self.batch_size * self.num_minibatches * self.unroll_length

    @property
    def iterations(self) -> int:
        """PPO iterations of the budget (rounded up: the run ends at or after num_timesteps)."""
        return math.ceil(self.num_timesteps / self.steps_per_iteration)

    def validate(self, n_devices: int = 1) -> None:
        for name in ("num_timesteps", "num_envs", "batch_size", "num_minibatches", "unroll_length",
                     "num_updates_per_batch", "episode_cap"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise ValueError(f"{name}={v!r} is invalid: must be an integer >= 1")
        if not 0 <= self.seed < 2**31:
            raise ValueError(f"seed={self.seed!r} is invalid: must be an integer in [0, 2^31 - 1]")
        if (self.batch_size * self.num_minibatches) % self.num_envs:
            raise ValueError(f"num_envs={self.num_envs} is invalid: batch_size x num_minibatches = "
                             f"{self.batch_size * self.num_minibatches} must be a multiple of it")
        if self.num_envs % n_devices:
            raise ValueError(f"num_envs={self.num_envs} is invalid: must be a multiple of the {n_devices} "
                             f"device(s) Brax splits it over")
        if not 0 < self.discounting <= 1:
            raise ValueError(f"discounting={self.discounting!r} is invalid: must be in (0, 1]")
        for name in ("learning_rate", "reward_scaling", "eval_seconds", "control_dt"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name}={v!r} is invalid: must be a finite number > 0")
        if not (math.isfinite(self.entropy_cost) and self.entropy_cost >= 0):
            raise ValueError(f"entropy_cost={self.entropy_cost!r} is invalid: must be >= 0")
        for name in ("policy_hidden", "value_hidden"):
            v = getattr(self, name)
            if not v or any(not isinstance(h, int) or h < 1 for h in v):
                raise ValueError(f"{name}={v!r} is invalid: layer sizes must be integers >= 1")
        env_config = EnvConfig(control_dt=self.control_dt, stop_prob=self.stop_prob, physics=self.physics)
        env_config.validate()
        tasks.check_env(self.env, env_config)
        if self.is_task and self.episode_cap != _time_limit(self.env, self.control_dt):
            raise ValueError(f"episode_cap={self.episode_cap!r} is invalid: with env={self.env!r} it is the task's "
                             f"time limit, {_time_limit(self.env, self.control_dt)} control steps")


def _time_limit(env: str, control_dt: float) -> int:
    """A task's time limit in control steps of ``control_dt`` (1,000 of its own steps; nmrl/tasks/env.py)."""
    spec = tasks.TASKS[env]
    return int(round(spec.max_episode_steps * spec.frame_skip * spec.timestep / control_dt))


def task_config(env: str, **fields: Any) -> PPOConfig:
    """The config of Brax PPO on ``env`` with ``fields`` changed: on a task, its own control step (frame
    skip x timestep) and its time limit as the episode length unless ``fields`` give them."""
    if env == tasks.PAPER or env not in tasks.TASKS:
        return PPOConfig(env=env, **fields)
    spec = tasks.TASKS[env]
    dt = fields.pop("control_dt", spec.frame_skip * spec.timestep)
    return PPOConfig(env=env, control_dt=dt, episode_cap=fields.pop("episode_cap", _time_limit(env, dt)), **fields)


RESUMABLE = ("num_timesteps",)


def load_config(run_dir: str | os.PathLike) -> PPOConfig:
    path = pathlib.Path(run_dir) / store.CONFIG_FILE
    try:
        d = json.loads(path.read_text())
        for k in ("policy_hidden", "value_hidden"):
            d[k] = tuple(d[k])
        return PPOConfig(**d)
    except (OSError, json.JSONDecodeError, TypeError, KeyError) as e:
        raise driver.RunError(f"{path}: not a PPO baseline config ({type(e).__name__}: {e})") from e


# ----------------------------------------------------------------------------- Brax pieces


def _ppo():
    brax_env.require_brax()
    from brax.training.agents.ppo import networks as ppo_networks
    from brax.training.agents.ppo import train as ppo_train
    from brax.training.acme import running_statistics

    return ppo_train, ppo_networks, running_statistics


@functools.lru_cache(maxsize=4)
def _networks(policy_hidden: tuple[int, ...], value_hidden: tuple[int, ...], normalize: bool,
              dims: tuple[int, int] = (brax_env.OBS_DIM, brax_env.ACT_DIM)):
    _, ppo_networks, running_statistics = _ppo()
    pre = running_statistics.normalize if normalize else (lambda x, y: x)
    return ppo_networks.make_ppo_networks(*dims, preprocess_observations_fn=pre,
                                          policy_hidden_layer_sizes=policy_hidden,
                                          value_hidden_layer_sizes=value_hidden)


def _network_factory(cfg: PPOConfig) -> Callable:
    def factory(obs_size, act_size, preprocess_observations_fn):
        _, ppo_networks, _ = _ppo()
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
        task = tasks.Task(env, tasks.TaskConfig(control_dt=control_dt))
        nets = _networks(policy_hidden, value_hidden, normalize, (task.obs_dim, task.act_dim))
        lo, scale = jnp.asarray(task.action_offset, jnp.float32), jnp.asarray(task.action_scale, jnp.float32)
        to_action = lambda u: lo + scale * jnp.clip(u, -1.0, 1.0)  # noqa: E731

    def act(params, obs):
        logits = nets.policy_network.apply(params[0], params[1], obs)
        return to_action(nets.parametric_action_distribution.mode(logits))

    return act


def policy_action(cfg: PPOConfig) -> Callable:
    """``act(params, obs)`` of the deterministic PPO policy of ``cfg``'s networks (params =
    (normalizer, policy, value), as Brax returns and :func:`run` saves them)."""
    return _actor(tuple(cfg.policy_hidden), tuple(cfg.value_hidden), bool(cfg.normalize_observations),
                  cfg.env, float(cfg.control_dt))


def _tally_every(cfg: PPOConfig) -> int:
    """Steps per environment between two reports of brax_env.Tally: the largest divisor of an
    iteration's steps per environment up to 256, so that each metrics row sums exactly the steps of
    its iteration."""
    per_env = cfg.steps_per_iteration // cfg.num_envs
    return max(d for d in range(1, min(256, per_env) + 1) if per_env % d == 0)


def _train_kwargs(cfg: PPOConfig, tally: Callable | None = None) -> dict:
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


def _env(cfg: PPOConfig) -> brax_env.BraxHalfCheetah | brax_task.BraxTask:
    if cfg.is_task:
        return brax_task.BraxTask(cfg.env, cfg.control_dt, cfg.physics)
    return brax_env.BraxHalfCheetah(EnvConfig(control_dt=cfg.control_dt, stop_prob=cfg.stop_prob,
                                              physics=cfg.physics))


def initial_params(cfg: PPOConfig) -> Any:
    """Brax's initial (normalizer, policy, value) for ``cfg`` (``ppo.train`` with no steps)."""
    ppo_train, _, _ = _ppo()
    _, params, _ = ppo_train.train(_env(cfg), num_timesteps=0, seed=cfg.seed, **_train_kwargs(cfg))
    return params


def evaluate_params(cfg: PPOConfig, params: Any, *, seconds: float | None = None, seed: int = 0) -> dict:
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
    state; one with neither is refused (driver.RunError)."""
    run_dir = pathlib.Path(run_dir)
    cfg = load_config(run_dir)
    if not checkpoint.checkpoint_dir(run_dir).exists() and not checkpoint.has_compact(run_dir):
        raise driver.RunError(
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


# ----------------------------------------------------------------------------- the run


class _Recorder:
    """The host side of one ``ppo.train`` call: sums the learning's rewards (``tally``, the sink of
    brax_env.Tally) and, after every iteration (Brax's ``policy_params_fn``), evaluates, checkpoints
    and appends the metrics row; raises :class:`driver.Stopped` after the save when a signal came."""

    def __init__(self, cfg: PPOConfig, out: pathlib.Path, step0: int, stop: Any, progress: bool):
        self.cfg, self.out, self.step0, self.stop, self.progress = cfg, out, step0, stop, progress
        self.rows: list[dict] = []
        self.t0 = self.t_last = time.perf_counter()
        self._lock = threading.Lock()
        self._sums = np.zeros(4)  # reward, forward speed, stops, steps since the last row

    def tally(self, reward, speed, stops, steps) -> None:
        """brax_env.Tally's sink (numpy only: it runs inside the training computation)."""
        with self._lock:
            self._sums += np.array([reward, speed, stops, steps], np.float64)

    def _take(self) -> np.ndarray:
        with self._lock:
            s, self._sums = self._sums, np.zeros(4)
        return s

    def on_params(self, current_step: int, _make_policy: Any, params: Any) -> None:
        if current_step == 0:
            if self.step0 == 0:  # the initial policy, evaluated once (fresh run)
                self._record(0, params, compile_s=time.perf_counter() - self.t0)
            self.t_last = time.perf_counter()
            return
        self._record(self.step0 + int(current_step), params)
        if self.stop.signal is not None:  # the signal guard's first signal: stop after this save
            raise driver.Stopped(self.stop.signal, self.step0 + int(current_step), self.rows)

    def _record(self, step: int, params: Any, compile_s: float | None = None) -> None:
        now = time.perf_counter()
        wall = now - self.t_last
        jax.effects_barrier()  # every report of this iteration's steps has reached tally()
        r, v, stops, n = self._take()
        ev = evaluate_params(self.cfg, params)
        ev.pop("_traj", None)
        row = {"step": step, "iteration": step // self.cfg.steps_per_iteration, "wall_s": wall,
               "steps_per_s": (self.cfg.steps_per_iteration / wall) if step and wall > 0 else None,
               "train_reward_per_step": r / n if n else None, "train_forward_speed": v / n if n else None,
               "train_steps_tallied": int(n), "trials_ended": int(stops),
               **_eval_fields(ev), "eval_forward_speed": ev["forward_speed"],
               "eval_nonfinite": ev["nonfinite"], "unix_time": time.time()}
        if compile_s is not None:
            row["setup_s"] = compile_s
        meta = {"kind": "brax-ppo", "config": _asdict(self.cfg)}
        self.stop.at("saving")
        checkpoint.save_tree(self.out, step, params, meta)
        checkpoint.save_tree_compact(self.out, step, params, meta)
        store.append_metrics(self.out, row)
        self.stop.at("training")
        self.rows.append(row)
        self.t_last = time.perf_counter()
        if self.progress:
            tr = row["train_reward_per_step"]
            ev_text = (f"return {row['eval_return']:+.1f}" if "eval_return" in row else f"{row['eval_avg_reward']:+.3f}")
            print(f"ppo seed {self.cfg.seed}: {step:>11,} steps  train {tr if tr is None else f'{tr:+.3f}'}  "
                  f"eval {ev_text} ({row['eval_forward_speed']:+.2f} m/s)  "
                  f"{row['steps_per_s'] or 0:,.0f} steps/s", file=sys.stderr, flush=True)


def _eval_fields(ev: dict) -> dict:
    """A metrics row's evaluation: the paper robot's average reward per step, a task's episode returns."""
    if "return" not in ev:
        return {"eval_avg_reward": ev["avg_reward"]}
    return {"eval_return": ev["return"]["mean"], "eval_return_sd": ev["return"]["sd"],
            "eval_length_mean": float(np.mean(ev["length"])), "eval_terminated": ev["terminated"]}


def finished_step(out: str | os.PathLike, cfg: PPOConfig) -> int | None:
    """The last metrics row's control step when it reaches ``cfg``'s budget (``iterations`` whole
    iterations: the run is finished), else None."""
    rows = store.read_metrics(pathlib.Path(out))
    if rows and rows[-1]["step"] // cfg.steps_per_iteration >= cfg.iterations:
        return int(rows[-1]["step"])
    return None


def _asdict(cfg: PPOConfig) -> dict:
    """The config as stored (config.json, checkpoints): every field, ``env`` only when it is a task."""
    d = dataclasses.asdict(cfg)
    if not cfg.is_task:
        del d["env"]
    d["policy_hidden"], d["value_hidden"] = list(cfg.policy_hidden), list(cfg.value_hidden)
    return d


def _check_resume(cfg: PPOConfig, saved: PPOConfig, out: pathlib.Path) -> None:
    a, b = dataclasses.asdict(saved), dataclasses.asdict(cfg)
    diff = [f"{k}: run {a[k]!r} vs given {b[k]!r}" for k in a if k not in RESUMABLE and a[k] != b[k]]
    if diff:
        raise driver.RunError(f"{out}: --resume keeps the run's config; only {RESUMABLE} may change: " + "; ".join(diff))


def run(cfg: PPOConfig, out: str | os.PathLike, *, resume: bool = False, progress: bool = True,
        max_iterations: int | None = None) -> list[dict]:
    """Train (or, with ``resume``, continue) the PPO baseline in ``out``; returns the rows written.

    ``max_iterations`` stops after that many iterations of this call (for tests and chunked
    sessions; the run continues with ``resume``). Raises driver.RunError for a bad ``out`` or a
    resume with another config, driver.Stopped after SIGINT/SIGTERM (everything saved).
    """
    out = pathlib.Path(out)
    cfg.validate(len(jax.local_devices()))  # bad values are named first, with or without Brax
    brax_env.require_brax()
    template = None
    step0, n_resume = 0, 0
    if resume:
        saved = load_config(out)
        _check_resume(cfg, saved, out)
        template = initial_params(saved)
        if driver.existing_step(out) is not None:
            meta, params = checkpoint.restore_tree(out, template)
        elif checkpoint.has_compact(out):  # a fresh clone of an unfinished published run: the same parameters
            meta, params = checkpoint.restore_tree_compact(out, template)
        elif finished_step(out, cfg) is not None:
            return []  # a fresh clone of a finished published seed (no parameters kept): nothing to do
        else:
            rows = store.read_metrics(out)
            reached = f"its metrics reach {rows[-1]['step']:,} control steps" if rows else "it has no metrics"
            raise driver.RunError(
                f"{out}: no checkpoint (or compact.npz) to resume from, and the run is not finished "
                f"({reached}, --num-timesteps is {cfg.num_timesteps:,}); a published seed keeps its "
                f"parameters (compact.npz) only while it is unfinished")
        step0 = int(meta["step"])
        if cfg.iterations - step0 // cfg.steps_per_iteration <= 0:
            return []  # finished: nothing to continue, nothing written
        store.truncate_metrics(out, step0)
        n_resume = len(store.read_jsonl(out / store.RESUMES_FILE)) + 1
        store.append_resume(out, {"from_step": step0, "num_timesteps": cfg.num_timesteps,
                                  "unix_time": time.time()})
        store.atomic_write_json(out / store.CONFIG_FILE, _asdict(cfg))
    else:
        driver.fresh_out(out)
        driver.create_dir(out)
        store.atomic_write_json(out / store.CONFIG_FILE, _asdict(cfg))
        params = None
    spi = cfg.steps_per_iteration
    left = cfg.iterations - step0 // spi
    if max_iterations is not None:
        left = min(left, max_iterations)
    if left <= 0:
        return []
    ppo_train, _, _ = _ppo()
    seed = cfg.seed if n_resume == 0 else int(jax.random.randint(
        jax.random.fold_in(jax.random.PRNGKey(cfg.seed), n_resume), (), 0, 2**31 - 1))
    with driver.guarded() as guard:  # the command's signal guard, as every run of nmrl has
        guard.at("training")
        rec = _Recorder(cfg, out, step0, guard, progress)
        ppo_train.train(_env(cfg), num_timesteps=left * spi, num_evals=left + 1, seed=seed,
                        restore_params=params, policy_params_fn=rec.on_params, **_train_kwargs(cfg, rec.tally))
    return rec.rows


# ----------------------------------------------------------------------------- command line


def main(argv: list[str] | None = None) -> int:
    """``nmrl baseline ppo ...`` (train or continue) and ``nmrl baseline eval RUN`` (evaluate)."""
    import argparse

    d = PPOConfig()
    ap = argparse.ArgumentParser(prog="nmrl baseline", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("ppo", help="train Brax PPO on the paper's Half-Cheetah (needs pip install -e '.[brax]')")
    p.add_argument("--out", required=True, help="run directory")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its newest checkpoint")
    p.add_argument("--seed", type=int, default=None, help=f"default {d.seed}")
    p.add_argument("--num-timesteps", type=int, default=None,
                   help=f"control steps over all environments (default {d.num_timesteps:.2g})")
    for name in ("num_envs", "batch_size", "num_minibatches", "unroll_length", "num_updates_per_batch"):
        p.add_argument("--" + name.replace("_", "-"), type=int, default=None, help=f"default {getattr(d, name)}")
    for name in ("discounting", "learning_rate", "entropy_cost"):
        p.add_argument("--" + name.replace("_", "-"), type=float, default=None, help=f"default {getattr(d, name)}")
    for name in ("policy_hidden", "value_hidden"):
        p.add_argument("--" + name.replace("_", "-"), type=int, nargs="+", default=None,
                       help=f"layer sizes (default {' '.join(map(str, getattr(d, name)))})")
    p.add_argument("--max-iterations", type=int, default=None,
                   help="stop after this many PPO iterations of this call (continue with --resume)")
    p.add_argument("--physics", default=None, help=f"{PHYSICS_HELP} (default {d.physics})")
    p.add_argument("--env", default=None, help=f"one of {', '.join(tasks.ENVS)} (default {d.env}; a task runs at "
                   "its own control step with its time limit: docs/tasks.md)")
    p.add_argument("--devices", default="auto", help="CPU devices Brax splits the environments over")
    p.add_argument("--quiet", action="store_true")
    e = sub.add_parser("eval", help="evaluate a PPO baseline checkpoint like nmrl eval (JSON, strobe, GIF)")
    e.add_argument("run")
    e.add_argument("--step", type=int, default=None)
    e.add_argument("--seconds", type=float, default=10.0)
    e.add_argument("--out", default=None, metavar="DIR", help="default: RUN/eval")
    e.add_argument("--no-render", action="store_true")
    a = ap.parse_args(argv)
    try:
        if a.cmd == "eval":
            if not (math.isfinite(a.seconds) and 0 < a.seconds <= 600):
                raise ValueError(f"--seconds={a.seconds!r} is invalid: must be in (0, 600]")
            res = evaluate_checkpoint(a.run, a.step, seconds=a.seconds, render=not a.no_render, out_dir=a.out)
            print(json.dumps(res, indent=2))
            return 0
        if a.max_iterations is not None and a.max_iterations < 1:
            raise ValueError(f"--max-iterations={a.max_iterations} is invalid: must be >= 1")
        given = {k: getattr(a, k) for k in ("seed", "num_timesteps", "num_envs", "batch_size", "num_minibatches",
                                             "unroll_length", "num_updates_per_batch", "discounting", "learning_rate",
                                             "entropy_cost", "policy_hidden", "value_hidden", "physics")
                 if getattr(a, k) is not None}
        for k in ("policy_hidden", "value_hidden"):
            if k in given:
                given[k] = tuple(given[k])
        if a.env is not None and not a.resume:
            base = task_config(a.env)  # the task's own control step and time limit
        else:
            base = load_config(a.out) if a.resume else PPOConfig()
            if a.env is not None:
                given["env"] = a.env
        cfg = dataclasses.replace(base, **given)  # a resume refuses any change but num_timesteps (run)
        run(cfg, a.out, resume=a.resume, progress=not a.quiet, max_iterations=a.max_iterations)
    except (ValueError, ImportError, driver.RunError, checkpoint.CheckpointError) as err:
        print(f"nmrl baseline: error: {err}", file=sys.stderr)
        return 2
    except driver.Stopped as err:
        print(f"nmrl baseline: {err}; saved; continue with --resume", file=sys.stderr)
        return err.exit_status
    return 0
