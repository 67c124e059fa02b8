"""PPO's run config (:class:`PPOConfig`) and its traced hyperparameters (:class:`Hyper`).

Every field is declared once (nmrl/options.py): help, range and whether it is traced; the traced
ones (the step size, the entropy cost, the clip epsilon, the value-loss weight, the reward scale,
the discount and GAE factors per control step and the exploration process) are the leaves of
:class:`Hyper`, so a sweep over any of them is one compiled program (nmrl/learners/ppo.py).

The config holds three groups (nmrl/options.py's ``group``): the environment
(``config.environment``, :class:`nmrl.tasks.EnvFields`), the exploration (``config.noise``,
:class:`PPONoise`: the fields :class:`nmrl.explore.ExplorationFields` declares, the process
``exploration``, default white, and its parameters in seconds and Hz, with the noise's ``sigma``;
:meth:`PPONoise.spec` is its nmrl.explore.ExplorationSpec, every process of nmrl.explore allowed)
and the budget and layout (``config.budget``, :class:`PPOBudget`).

**Time in seconds.** The discount ``gamma = exp(-control_dt / discount_horizon_s)``, the GAE
``lambda = exp(-control_dt / gae_horizon_s)``, the unroll ``unroll_s`` and the noise's correlation
times are given in seconds; at 0.02 s every default is the Brax baseline's (results/baseline_ppo,
``gamma = 0.95``, ``lambda = 0.95``, ``T = 20``, 32 minibatches of 512 unrolls, 8 epochs, lr 3e-4,
entropy 1e-3, clip 0.3, policy 4x32, value 5x256, 64 environments, observation normalisation,
reward scaling 1). docs/ppo.md has the conversions and what differs from Brax.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Callable, NamedTuple

from nmrl import explore, options
from nmrl.explore.fields import KINDS, PARAMS, SIGMA_RANGE
from nmrl.learners.contract import Learner, lazy, register
from nmrl.options import AT_LEAST_ONE, NON_NEGATIVE, POSITIVE, Range, option, run_option
from nmrl.tasks import EnvFields

if TYPE_CHECKING:  # the module imports no JAX: the declarations are read when a command line is built
    import jax

#: the horizon (s) of Brax's discounting 0.95 (and GAE lambda 0.95) at the baseline's 0.02 s step
BRAX_HORIZON_S = -0.02 / math.log(0.95)
SQUASHES = ("tanh", "clip")
#: Adam's step size: > 0 (0 would learn nothing), at most 1
_LEARNING_RATE = Range(0.0, 1.0, open_lo=True, why="a step size", cap=True)
#: iterations of the budget a run given none gets
DEFAULT_ITERATIONS = 1


def _per_step(horizon: str) -> Callable[["PPOConfig"], jax.Array]:
    """``exp(-control_dt / horizon_s)`` in float32: a horizon in seconds as a factor per control step."""

    def factor(c: "PPOConfig") -> jax.Array:
        import jax.numpy as jnp

        return jnp.asarray(math.exp(-c.environment.control_dt / getattr(c, horizon)), jnp.float32)

    return factor


_TIME = Range(0.0, open_lo=True, why="seconds, at least the control step")


@dataclasses.dataclass(frozen=True)
class PPONoise(explore.ExplorationFields):
    """PPO's exploration (``config.noise``): the process and its parameters as
    :class:`nmrl.explore.ExplorationFields` declares them, PPO's default process (white), and the
    noise's ``sigma``."""

    exploration: str = explore.kind_option("white")
    sigma: float = option(1.0, "marginal std of the noise xi, multiplying the learned std_theta (1: Brax's learned "
                               "std alone)", traced="process", range=SIGMA_RANGE)

    def spec(self) -> explore.ExplorationSpec:
        """The exploration as an nmrl.explore.ExplorationSpec (parameters None: the kind's defaults)."""
        return explore.ExplorationSpec(kind=self.exploration, **{k: getattr(self, k) for k in SPEC_FIELDS})


@dataclasses.dataclass(frozen=True)
class PPOBudget:
    """PPO's budget and layout (``config.budget``): environments in lock-step, the chunk, the budget
    in steps or trials, the seed and the divergence bound, each declared here once."""

    num_envs: int = option(64, "environments in lock-step (must divide --batch-size)", range=AT_LEAST_ONE)
    chunk_steps: int | None = option(None, "control steps per environment per chunk, a multiple of one iteration's "
                                           "(default: one)", range=AT_LEAST_ONE)
    steps: int | None = run_option("steps", None, "budget in control steps per environment (default: one iteration)")
    trials: int | None = run_option("trials", None)
    seed: int = run_option("seed", 0)
    max_param_norm: float = run_option("max_param_norm", 1e5)


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """A PPO run. Defaults at control_dt = 0.02 s are the Brax baseline's (module docstring). Every
    field is declared once (nmrl/options.py); ``traced`` ones are :class:`Hyper`'s leaves. The
    environment (``config.environment``: ``env``, ``control_dt``, ``physics``, ...) is a
    :class:`nmrl.tasks.EnvFields`, the exploration (``config.noise``: ``exploration``, ``period_s``,
    ``beta``, ..., ``sigma``) a :class:`PPONoise`, the budget and layout (``config.budget``) a
    :class:`PPOBudget`."""

    environment: EnvFields = options.group(EnvFields)
    noise: PPONoise = options.group(PPONoise)
    learn_std: bool = option(True, "learn a state-dependent std_theta(s) = softplus + min_std (Brax); false: "
                                   "std_theta = 1")
    min_std: float = option(1e-3, "floor of the learned std (Brax: 0.001)", range=POSITIVE)
    squash: str = option("tanh", "env action = 20 tanh(x) (Brax) or 20 clip(x, -1, 1)", choices=SQUASHES)
    period_wise: bool = option(False, "learn on nm-periods as wholes: one ratio per period (eq. (7)), advantage and "
                                      "critic at period starts (ppo_losses.period_gae; default: per-step conditional "
                                      "ratios). Warning: on the paper's robot at 20 ms it learns about half as fast per "
                                      "iteration as per-step ratios with white noise: its mean policy stood after 16 "
                                      "iterations and walked in 1 of 2 seeds after 32 (docs/exploration-study-2.md)")
    # PPO, times in seconds
    discount_horizon_s: float = option(BRAX_HORIZON_S, "discount horizon [s]: gamma = exp(-control_dt / it) (0.95 "
                                                       "at 0.02 s)", traced="gamma", range=_TIME)
    gae_horizon_s: float = option(BRAX_HORIZON_S, "GAE horizon [s]: lambda = exp(-control_dt / it) (0.95 at 0.02 s)",
                                  traced="lam", range=_TIME)
    unroll_s: float = option(0.4, "unroll length [s]: T = round(unroll_s / control_dt) steps (20 at 0.02 s)",
                             range=_TIME)
    batch_size: int = option(512, "unrolls per minibatch (a multiple of --num-envs)", range=AT_LEAST_ONE)
    num_minibatches: int = option(32, "minibatches per epoch", range=AT_LEAST_ONE)
    epochs: int = option(8, "passes over an iteration's data (Brax: num_updates_per_batch)", range=AT_LEAST_ONE)
    grad_chunks: int = option(1, "take each minibatch's gradient in this many parts of its unrolls, summed (the same "
                                 "Adam step up to float rounding, a smaller working set; must divide batch_size / "
                                 "num_envs)", range=AT_LEAST_ONE)
    learning_rate: float = option(3e-4, "Adam's step size", traced=True, range=_LEARNING_RATE)
    entropy_cost: float = option(1e-3, "weight of the entropy bonus", traced=True, range=NON_NEGATIVE)
    clip_eps: float = option(0.3, "PPO's clip epsilon of the ratio", traced=True, range=POSITIVE)
    vf_coef: float = option(0.5, "weight of the value loss", traced=True, range=POSITIVE)
    reward_scale: float = option(1.0, "the learner receives reward_scale * r (delta / 0.02 s keeps the return's "
                                      "scale); metrics report r", traced=True, range=POSITIVE)
    max_grad_norm: float | None = option(None, "clip the gradient's global norm (default: no clipping, Brax's)",
                                         range=POSITIVE)
    normalize_obs: bool = option(True, "running mean/std observation normalisation (Brax's)")
    normalize_advantage: bool = option(True, "normalise advantages per minibatch (Brax's)")
    policy_layers: int = option(4, "hidden layers of the policy", range=AT_LEAST_ONE)
    policy_width: int = option(32, "units per policy layer", range=AT_LEAST_ONE)
    value_layers: int = option(5, "hidden layers of the value net", range=AT_LEAST_ONE)
    value_width: int = option(256, "units per value layer", range=AT_LEAST_ONE)
    # batching, budget (common to every learner)
    budget: PPOBudget = options.group(PPOBudget)

    # ----------------------------------------------------------------------- derived
    @property
    def unroll_length(self) -> int:
        """T, control steps per unroll."""
        return max(1, int(math.floor(self.unroll_s / self.environment.control_dt + 0.5)))

    @property
    def unrolls_per_env(self) -> int:
        """U, unrolls of each environment per iteration."""
        return self.batch_size * self.num_minibatches // self.budget.num_envs

    @property
    def iteration_steps(self) -> int:
        """Control steps per environment in one iteration (U T)."""
        return self.unrolls_per_env * self.unroll_length

    def validate(self) -> None:
        """Every field by its declaration (type, finiteness, range, choices; nmrl/options.py), then
        what relates fields: the exploration at the control step, the period-wise learning's process,
        times of at least one control step, minibatches of whole environments, chunks of whole
        iterations, one budget, the environment's relations (:meth:`nmrl.tasks.EnvFields.check_env`)."""
        options.check(self, limits=False)
        self.noise.spec().validate(self.environment.control_dt)
        if self.period_wise and self.noise.exploration != "nm-periods":
            raise options.invalid("period_wise", self.period_wise, "true only with --exploration nm-periods (a process whose "
                                                        "noise restarts at period starts), else false")
        dt, b = self.environment.control_dt, self.budget
        for name in ("discount_horizon_s", "gae_horizon_s", "unroll_s"):
            if getattr(self, name) < dt * (1 - 1e-9):
                raise options.invalid(name, getattr(self, name), f"must be a finite time >= the control step {dt:g} s")
        if self.batch_size % b.num_envs:
            raise options.invalid("num_envs", b.num_envs, f"must divide batch_size={self.batch_size} (every minibatch "
                                                  f"holds batch_size / num_envs unrolls of each environment)")
        if (self.batch_size // b.num_envs) % self.grad_chunks:
            raise options.invalid("grad_chunks", self.grad_chunks, f"must divide the {self.batch_size // b.num_envs} "
                                                        f"unrolls of each environment in a minibatch "
                                                        f"(batch_size / num_envs)")
        if b.chunk_steps is not None and b.chunk_steps % self.iteration_steps:
            raise options.invalid("chunk_steps", b.chunk_steps, f"must be a multiple of one iteration's "
                                                        f"{self.iteration_steps} control steps per environment")
        if b.steps is not None and b.trials is not None:
            raise ValueError("give the budget as steps or as trials, not both")
        self.environment.check_env()

    def resolved(self) -> "PPOConfig":
        """Validated, with the exploration's defaults, one iteration per chunk and a budget of
        :data:`DEFAULT_ITERATIONS` iterations filled in where not given."""
        self.validate()
        spec = self.noise.spec()
        out = options.replace(self, **{k: getattr(spec, k) for k in SPEC_FIELDS})
        if out.budget.chunk_steps is None:
            out = options.replace(out, chunk_steps=out.iteration_steps)
        if out.budget.steps is None and out.budget.trials is None:
            out = options.replace(out, steps=DEFAULT_ITERATIONS * out.iteration_steps)
        return out


#: the exploration parameters of the config, as nmrl.explore.ExplorationSpec names them (its
#: ``PARAMETERS``: sigma and the declared parameters)
SPEC_FIELDS = ("sigma", *PARAMS)
#: the derived traced values: the discount and GAE factors per control step (from the config's
#: seconds) and the noise process
_DERIVED = {"gamma": _per_step("discount_horizon_s"), "lam": _per_step("gae_horizon_s"),
            "process": lambda c: c.noise.spec().process(c.environment.control_dt)}


class Hyper(NamedTuple):
    """The traced values of a :class:`PPOConfig`, in the order of the fields that feed them
    (``options.hyper_leaves``; tests/test_config_model.py checks it): one compiled program serves
    every value."""

    process: explore.Process  #: the exploration noise process at the control step (``sigma`` and the spec's)
    gamma: jax.Array  #: float32, exp(-control_dt / discount_horizon_s)
    lam: jax.Array  #: float32, exp(-control_dt / gae_horizon_s)
    learning_rate: jax.Array
    entropy_cost: jax.Array
    clip_eps: jax.Array
    vf_coef: jax.Array
    reward_scale: jax.Array

    @staticmethod
    def from_config(config: PPOConfig) -> "Hyper":
        return options.hyper_values(Hyper, config, _DERIVED)


#: the learner ``ppo``: its declarations here, its program in nmrl/learners/ppo.py and its evaluation
#: policy in ppo_policy.py (imported at a run's first call: the command line reads the declarations
#: without JAX)
LEARNER = register(Learner(
    name="ppo",
    config=PPOConfig,
    hyper=Hyper.from_config,
    hyper_fields=options.traced(PPOConfig),
    make=lazy("nmrl.learners.ppo", "make_ppo"),
    env_fields=("env", "noise"),
    compact_fields=("policy", "value", "opt", "obs_stats"),
    policy_fields=("policy", "obs_stats"),
    policy=lazy("nmrl.learners.ppo_policy", "policy"),
    doc="PPO (Brax's settings at 0.02 s) with the exact likelihood of any exploration process",
    help=options.helps(PPOConfig),
    describe=lambda c: {"exploration": c.noise.exploration, "sigma": float(c.noise.sigma)},
    explorations=KINDS,
))
