"""The actor-critic's run config (:class:`TrainConfig`), its traced hyperparameters (:class:`Hyper`)
and its step-size presets (:data:`PRESETS`).

Defaults are the paper's (Sec. V-C, Table II). Every field is declared once (nmrl/options.py):
help, range and whether it is traced; the traced ones (l, Delta, alpha, sigma, gamma, lambda,
beta^theta, beta^v) are the leaves of :class:`Hyper`, so a sweep over any of them is one compiled
program (nmrl/learners/ac_train.py). The update rules ``actor_opt`` / ``critic_opt`` are optimizer
chains of nmrl/learners/optimizers.py, recorded in canonical form.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any, NamedTuple

from nmrl import options
from nmrl.explore.fields import SIGMA_RANGE
from nmrl.learners.contract import Learner, lazy, register
from nmrl.learners.optimizers import OPT_HELP, canonical_opt, parse_opt
from nmrl.options import AT_LEAST_ONE, POSITIVE, STEP_SIZE, Range, option, run_option
from nmrl.tasks import EnvFields

if TYPE_CHECKING:  # the module imports no JAX: the declarations are read when a command line is built
    import jax

#: the exploration processes the actor-critic can use
EXPLORATIONS = ("white", "nm-periods")
#: the training state's optimizer states (nmrl/learners/ac_train.py): a checkpoint written before they
#: were saved lacks them (``Learner.restorable``)
OPT_FIELDS = ("opt_theta", "opt_v")
#: the hidden units' arctan implementations by name, the keys of nmrl.paper.networks.ARCTANS (which
#: imports JAX; tests/test_config_model.py checks they agree)
ARCTANS = ("fast", "xla")

#: Named step-size presets. "paper" is Sec. V-C. "fast" is for the budgets this 2-core machine
#: allows (10^3-10^4 trials instead of the paper's 10^5): with the paper's step sizes and 16-64
#: environments nothing measurable is learned within a few thousand control steps (measured when
#: the preset was chosen; no test or record of those runs is kept; 256 environments do learn:
#: -0.71 -> +0.57 in 4000 steps, README), while beta^theta = 5x and beta^v = 50x the paper's raise the
#: average reward of 64 environments from -0.68 to +0.55 within 4000 steps (~1000 trials;
#: tests/test_learner.py::test_halfcheetah_learning_raises_average_reward). The critic needs the
#: larger factor: with the paper's beta^v its value estimates lag and the TD errors are mostly noise.
#: The budget of a run given none (control steps per environment): a few minutes on 2 CPU cores.
DEFAULT_STEPS = 4000

#: Each preset also names the update rule of actor and critic (an optimizer chain, see
#: :func:`parse_opt`); "paper" and "fast" use the paper's rule, plain sgd.
PRESETS: dict[str, dict[str, Any]] = {
    "paper": {"beta_theta": 2e-6, "beta_v": 1e-5, "actor_opt": "sgd", "critic_opt": "sgd"},
    "fast": {"beta_theta": 1e-5, "beta_v": 5e-4, "actor_opt": "sgd", "critic_opt": "sgd"},
    #: the fast step sizes with every update clipped by global norm (results/fast_preset/):
    #: in the fast preset's collapses the critic blows up first (|v| 90 -> 58,000 within one chunk,
    #: TD errors x10^4, the actor then takes one huge step). The bounds are in parameter units (after
    #: sgd): the actor's summed update had a mean norm of ~0.01 per control step, the critic's ~0.3-1.5
    #: (l = 1, 2 highest), with outliers of 0.1-0.2 and 10-100 in the first chunk.
    "fast_clip": {"beta_theta": 1e-5, "beta_v": 5e-4, "actor_opt": "sgd,clip:0.03", "critic_opt": "sgd,clip:1"},
}


@dataclasses.dataclass(frozen=True)
class ACBudget:
    """The actor-critic's budget and layout (``config.budget``): environments in lock-step, the chunk,
    the budget in steps or trials, the seed and the divergence bound, each declared here once."""

    num_envs: int = option(256, "N environments in lock-step", range=AT_LEAST_ONE)
    chunk_steps: int = option(250, "control steps per environment in one jitted chunk", range=AT_LEAST_ONE)
    steps: int | None = run_option("steps", None, f"budget in control steps per environment (default: {DEFAULT_STEPS})")
    trials: int | None = run_option("trials", None, "budget in trials, summed over environments (the paper's measure)")
    seed: int = run_option("seed", 0)
    max_param_norm: float = run_option("max_param_norm", 1e5)


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Everything that defines a training run. Defaults are the paper's (Sec. V-C, Table II). Every
    field is declared once (nmrl/options.py); ``traced`` ones are :class:`Hyper`'s leaves. The
    environment (``config.environment``: ``env``, ``control_dt``, ``physics``, ...) is a
    :class:`nmrl.tasks.EnvFields`, the budget and layout (``config.budget``) an :class:`ACBudget`; the
    noise's l, alpha, sigma and Delta are the learner's own fields (Table II's exploration)."""

    environment: EnvFields = options.group(EnvFields)
    # Table II / Sec. V-C
    l: int = option(10, "nm-period length l [control steps]", traced=True, range=AT_LEAST_ONE)
    delta: int = option(4, "sampling interval Delta of the likelihood ratio (7) [control steps]", traced=True,
                        range=AT_LEAST_ONE)
    alpha: float = option(0.8, "AR coefficient alpha of the noise xi, eq. (4)", traced=True,
                          range=Range(0.0, 1.0, open_lo=True))
    sigma: float = option(1.0, "standard deviation of xi (Sigma = sigma^2 I)", traced=True, range=SIGMA_RANGE)
    gamma: float = option(0.995, "discount per control step", traced=True, range=Range(0.0, 1.0))
    lam: float = option(0.5, "lambda of the TD(lambda) traces", traced=True, range=Range(0.0, 1.0))
    beta_theta: float | None = option(None, "actor step size (default: the preset's)", traced=True, range=STEP_SIZE)
    beta_v: float | None = option(None, "critic step size (default: the preset's)", traced=True, range=STEP_SIZE)
    actor_opt: str | None = option(None, f"actor update rule: {OPT_HELP} (default: the preset's)")
    critic_opt: str | None = option(None, "critic update rule, as --actor-opt (default: the preset's)")
    preset: str = option("paper", f"step-size and update-rule preset: {', '.join(sorted(PRESETS))}",
                         choices=tuple(sorted(PRESETS)))
    hidden_actor: int = option(100, "hidden units M^A of the actor", range=AT_LEAST_ONE)
    hidden_critic: int = option(200, "hidden units M^C of the critic", range=AT_LEAST_ONE)
    arctan: str = option("fast", "the hidden units' arctan: fast (Cephes' atanf, within 3 float32 ulp) or xla "
                                 "(XLA's atan2, ~15x slower on a CPU; the runs made before this option)",
                         choices=ARCTANS)
    # batching and budget
    budget: ACBudget = options.group(ACBudget)
    #: the finer-delta study gives delta / 0.02 s, so that the discounted return, an integral over time,
    #: keeps its scale (nmrl/experiments/timescale.py)
    reward_scale: float = option(1.0, "the learner receives reward_scale * r_t; metrics report r_t", range=POSITIVE)
    #: per-period actor gradient estimates g_k = d_k grad ln pi for nmrl/experiments/gradvar.py (costs a little)
    grad_stats: bool = option(False, "diagnostic: every chunk also returns sums of the per-period actor gradient "
                                     "estimates", cli=False)

    def resolved(self) -> "TrainConfig":
        """Validate, fill step sizes from the preset and the default budget (:data:`DEFAULT_STEPS`)."""
        self.validate()
        p = PRESETS[self.preset]
        out = dataclasses.replace(
            self,
            beta_theta=p["beta_theta"] if self.beta_theta is None else self.beta_theta,
            beta_v=p["beta_v"] if self.beta_v is None else self.beta_v,
            actor_opt=canonical_opt(p["actor_opt"] if self.actor_opt is None else self.actor_opt, "actor_opt"),
            critic_opt=canonical_opt(p["critic_opt"] if self.critic_opt is None else self.critic_opt, "critic_opt"),
        )
        if out.budget.steps is None and out.budget.trials is None:
            out = options.replace(out, steps=DEFAULT_STEPS)
        return out

    def validate(self) -> None:
        """Eq. (4)'s alpha and the period lengths (nmrl.paper.noise), every field by its declaration
        (type, finiteness, range, choices; nmrl/options.py), the update rules, one budget, the
        environment's relations (:meth:`nmrl.tasks.EnvFields.check_env`)."""
        from nmrl.paper import noise

        noise.validate(alpha=self.alpha, l=self.l, delta=self.delta)
        options.check(self, limits=False)
        for name in ("actor_opt", "critic_opt"):
            if getattr(self, name) is not None:
                parse_opt(getattr(self, name), name)
        if self.budget.steps is not None and self.budget.trials is not None:
            raise ValueError("give the budget as steps or as trials, not both")
        self.environment.check_env()


class Hyper(NamedTuple):
    """The traced values of a :class:`TrainConfig`: one leaf per field declared ``traced``, in their
    order (``options.hyper_leaves``; tests/test_config_model.py checks it), int32 or float32 by the
    field's type. One compiled program serves every value (the sweep vmaps over them)."""

    l: jax.Array  #: int32, the nm-period length
    delta: jax.Array  #: int32, Delta
    alpha: jax.Array
    sigma: jax.Array
    gamma: jax.Array
    lam: jax.Array
    beta_theta: jax.Array
    beta_v: jax.Array

    @staticmethod
    def from_config(config: TrainConfig) -> "Hyper":
        return options.hyper_values(Hyper, config)


#: the learner ``ac``: its declarations here, its program in nmrl/learners/ac.py (imported at a run's
#: first call of ``make``, ``policy``, ...: the command line reads the declarations without JAX)
LEARNER = register(Learner(
    name="ac",
    config=TrainConfig,
    hyper=Hyper.from_config,
    hyper_fields=options.traced(TrainConfig),
    make=lazy("nmrl.learners.ac", "make"),
    env_fields=("slots",),
    compact_fields=("theta", "v", "periods"),
    policy_fields=("theta", "v"),
    policy=lazy("nmrl.learners.ac", "policy"),
    doc="the paper's actor-critic with TD(lambda) over nm-periods (Table II)",
    help=options.helps(TrainConfig),
    restorable=OPT_FIELDS,
    fill=lazy("nmrl.learners.ac", "fill"),
    check=lazy("nmrl.learners.ac", "check"),
    describe=lambda c: {"l": int(c.l), "alpha": float(c.alpha), "sigma": float(c.sigma)},
    explorations=EXPLORATIONS,
    sweep_field="l",
    exploration=lazy("nmrl.learners.ac", "exploration"),
))
