"""The config of the Brax PPO baseline (nmrl/experiments/baseline_ppo.py): its fields and checks,
Brax's own Half-Cheetah setting and every departure from it, a task's config, and the config as a
run directory stores it.

**Hyperparameters.** The starting point is Brax's own PPO setting for its Half-Cheetah (the Brax
training notebook, :data:`BRAX_HALFCHEETAH`); :data:`CHANGES` lists every change with its reason.
:class:`BaselineConfig` is that setting with the changes, on the paper's robot at the paper's
sample budget (2.5*10^7 control steps: 10^5 trials of ~250 steps).

**The tasks** (``env`` = ``halfcheetah-v5``, ``hopper-v5``, ``walker2d-v5``; :func:`task_config`): the
task's own control step (``control_dt``) and its time limit as Brax's episode length (``episode_cap``
= the task's ``max_steps``: a truncation; the task's ``terminated`` a termination). ``env`` is
stored in ``config.json`` only when it is not the paper's robot (:func:`stored`), so a run made
before the field existed keeps its config file and resumes; :func:`load_config` reads every
published one (results/baseline_ppo/, results/standard_tasks/brax/).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import pathlib
from typing import Any

from nmrl import options, tasks
from nmrl.options import AT_LEAST_ONE, NON_NEGATIVE, POSITIVE, Range, option, run_option
from nmrl.paper.control_step import DELTA_0
from nmrl.paper.env import EnvConfig
from nmrl.runs import errors, store

__all__ = ["BaselineConfig", "BRAX_HALFCHEETAH", "CHANGES", "RESUMABLE", "task_config", "load_config", "stored",
           "check_resume"]

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


_B = BRAX_HALFCHEETAH


@dataclasses.dataclass(frozen=True)
class BaselineConfig:
    """Brax PPO on the paper's Half-Cheetah. Defaults: BRAX_HALFCHEETAH's values (taken from it) with
    CHANGES, and the paper's control step and stop rule. Every field is declared once
    (nmrl/options.py: help, range, whether it is an option of ``nmrl baseline ppo``); the seed and the
    environment's fields as nmrl's runs declare them (``options.run_option``, nmrl.tasks.EnvFields)."""

    seed: int = run_option("seed", 0)
    num_timesteps: int = option(25_000_000, "control steps over all environments", range=AT_LEAST_ONE)
    num_envs: int = option(64, "environments in lock-step", range=AT_LEAST_ONE)
    batch_size: int = option(_B["batch_size"], "unrolls per minibatch", range=AT_LEAST_ONE)
    num_minibatches: int = option(_B["num_minibatches"], "minibatches per iteration", range=AT_LEAST_ONE)
    unroll_length: int = option(_B["unroll_length"], "control steps per unroll", range=AT_LEAST_ONE)
    num_updates_per_batch: int = option(_B["num_updates_per_batch"], "epochs over an iteration's data",
                                        range=AT_LEAST_ONE)
    discounting: float = option(_B["discounting"], "discount per control step", range=Range(0.0, 1.0, open_lo=True))
    learning_rate: float = option(_B["learning_rate"], "Adam's step size", range=POSITIVE)
    entropy_cost: float = option(_B["entropy_cost"], "weight of the entropy bonus", range=NON_NEGATIVE)
    reward_scaling: float = option(float(_B["reward_scaling"]), "the learner receives reward_scaling * r",
                                   range=POSITIVE, cli=False)
    normalize_observations: bool = option(_B["normalize_observations"], "running observation normalisation",
                                          cli=False)
    policy_hidden: tuple[int, ...] = option(_B["policy_hidden"], "the policy's layer sizes", range=AT_LEAST_ONE)
    value_hidden: tuple[int, ...] = option(_B["value_hidden"], "the value net's layer sizes", range=AT_LEAST_ONE)
    episode_cap: int = option(10_000, "Brax's episode length: a cap (a task's time limit)", range=AT_LEAST_ONE,
                              cli=False)
    control_dt: float = options.same_as(tasks.EnvFields, "control_dt", DELTA_0, cli=False)
    stop_prob: float = options.same_as(tasks.EnvFields, "stop_prob", 1 / 250, cli=False)
    eval_seconds: float = option(10.0, "simulated seconds of each evaluation", range=POSITIVE, cli=False)
    #: the environment's physics engine and the environment (the paper's robot or a v5 task), as a
    #: learner's run declares them (nmrl.tasks.EnvFields)
    physics: str = options.same_as(tasks.EnvFields, "physics", "mjx", group=None)
    env: str = options.same_as(tasks.EnvFields, "env", tasks.PAPER, group=None)

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
        """Every field by its declaration (nmrl/options.py), then what relates them: minibatches of
        whole environments, environments split evenly over the devices, the environment's relations
        (its control step and stop rule; a task's time limit as ``episode_cap``)."""
        options.check(self, limits=False)
        if (self.batch_size * self.num_minibatches) % self.num_envs:
            raise ValueError(f"num_envs={self.num_envs} is invalid: batch_size x num_minibatches = "
                             f"{self.batch_size * self.num_minibatches} must be a multiple of it")
        if self.num_envs % n_devices:
            raise ValueError(f"num_envs={self.num_envs} is invalid: must be a multiple of the {n_devices} "
                             f"device(s) Brax splits it over")
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


def task_config(env: str, **fields: Any) -> BaselineConfig:
    """The config of Brax PPO on ``env`` with ``fields`` changed: on a task, its own control step (frame
    skip x timestep) and its time limit as the episode length unless ``fields`` give them."""
    if env == tasks.PAPER or env not in tasks.TASKS:
        return BaselineConfig(env=env, **fields)
    spec = tasks.TASKS[env]
    dt = fields.pop("control_dt", spec.frame_skip * spec.timestep)
    return BaselineConfig(env=env, control_dt=dt, episode_cap=fields.pop("episode_cap", _time_limit(env, dt)),
                          **fields)


RESUMABLE = ("num_timesteps",)


def load_config(run_dir: str | os.PathLike) -> BaselineConfig:
    """The config a baseline run directory stores (``config.json``; a run of the paper's robot made
    before ``env`` or ``physics`` existed takes their defaults); RunError naming a file that is not one."""
    path = pathlib.Path(run_dir) / store.CONFIG_FILE
    try:
        d = json.loads(path.read_text())
        for k in ("policy_hidden", "value_hidden"):
            d[k] = tuple(d[k])
        return BaselineConfig(**d)
    except (OSError, json.JSONDecodeError, TypeError, KeyError) as e:
        raise errors.RunError(f"{path}: not a PPO baseline config ({type(e).__name__}: {e})") from e


def stored(cfg: BaselineConfig) -> dict:
    """The config as stored (config.json, checkpoints): every field, ``env`` only when it is a task."""
    d = dataclasses.asdict(cfg)
    if not cfg.is_task:
        del d["env"]
    d["policy_hidden"], d["value_hidden"] = list(cfg.policy_hidden), list(cfg.value_hidden)
    return d


def check_resume(cfg: BaselineConfig, saved: BaselineConfig, out: pathlib.Path) -> None:
    """RunError naming every field of ``cfg`` that differs from the run's ``saved`` config, but
    :data:`RESUMABLE` (the budget): a resume continues the same run."""
    a, b = dataclasses.asdict(saved), dataclasses.asdict(cfg)
    diff = [f"{k}: run {a[k]!r} vs given {b[k]!r}" for k in a if k not in RESUMABLE and a[k] != b[k]]
    if diff:
        raise errors.RunError(f"{out}: --resume keeps the run's config; only {RESUMABLE} may change: "
                              + "; ".join(diff))
