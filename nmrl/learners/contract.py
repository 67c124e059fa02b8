"""The learner contract: what the one driver (nmrl/runs/) needs of a learner, and the registry.

A learner is a :class:`Learner` record registered under a short name (``"ac"``: the paper's
actor-critic, nmrl/learners/ac.py; ``"ppo"``: nmrl/learners/ppo.py). The driver, the checkpoints,
the sweep, evaluation and the command line take any registered learner through this record and
nothing else; the shape is Stoix's ``LearnerFn: state -> (state, metrics)`` and rejax's one loop:

* ``config`` -- a frozen dataclass of the learner's own fields and its groups (``nmrl.options.group``),
  the run's identity: ``config.json`` is ``{"learner": name, **options.flat(config)}`` (every leaf by
  its flat name, :func:`config_dict`), and :func:`config_from_dict` gives the config back from it; no
  field may be named ``learner``. Every learner's config holds the group ``environment`` (a
  ``nmrl.tasks.EnvFields``: ``env``, ``control_dt`` [s], ``stop_prob`` (per control step), ...,
  and ``env_config()``, the ``nmrl.paper.env.EnvConfig`` of its environment, ``auto_reset=True``)
  and the group ``budget`` with ``seed: int``, ``num_envs: int``, ``chunk_steps: int`` (control
  steps per environment in one chunk), ``steps: int | None`` (budget in control steps per
  environment), ``trials: int | None`` (budget in trials summed over the environments; at most one
  of the two) and ``max_param_norm: float`` (:data:`COMMON_FIELDS`), and the methods ``validate()``
  (ValueError naming the value and what is allowed) and ``resolved()`` (validated, every default
  filled in, e.g. a default budget: what the run records); ``config()`` (every field at its default)
  is valid, and a resolved config has ``chunk_steps`` and a budget set. Field types are written as
  ``int``, ``float``, ``str``, ``bool`` or ``X | None``, each field declared once with
  :func:`nmrl.options.option` (help, traced or static, range or choices, option spelling): the
  command line makes one option of each leaf, and ``help``, ``hyper_fields``, ``hyper`` and the
  bounds checked before a run come from the declarations (nmrl/options.py).
* ``hyper(config)`` -- the traced hyperparameters, a pytree of arrays (e.g. a NamedTuple whose
  ``from_config`` reads the config fields of the same names). ``hyper_fields`` names those config
  fields (by flat name): the points of one sweep may differ only in them and in the seed (one compiled program,
  ``jax.vmap``/``lax.map`` over the stacked states), so a point equals the same run alone up to
  float rounding. ``sweep_field``: the one ``nmrl sweep`` varies by default (the actor-critic's l;
  None: seeds only; ``--vary FIELD V...`` picks any of ``hyper_fields``).
* ``make(config, env=None, *, axis_name=None, num_shards=1) -> Trainer`` -- the pure functions of a
  run (``env`` default: the environment of ``config.environment``). With ``num_shards`` > 1 ``chunk`` is
  written for ``jax.shard_map`` over the environment axis of the state's ``env_fields`` (``psum``
  over ``axis_name``), the other fields replicated; its results equal the unsharded program's up to
  float rounding.
* ``Trainer`` (:class:`Trainer`): ``config`` (resolved), ``env``, ``init(key, hyper=None) -> state``
  (``hyper`` None: ``hyper(config)``), ``chunk(state) -> (state, metrics)``: ``config.budget.chunk_steps``
  control steps of every environment, pure and jittable (one ``lax.scan``), no host callbacks.
* The state: a pytree dataclass (``flax.struct.dataclass``) with at least ``step`` (int32, control
  steps per environment so far), ``trials`` (int32, trials ended, summed over the environments),
  ``diverged`` (bool: once True the learner freezes its parameters), ``key`` (the PRNG key) and
  ``hyper``. A checkpoint holds the whole state and gives it back bit for bit (a resumed run equals
  an uninterrupted one); zero-size leaves are fine. ``env_fields``: the top-level fields whose
  leaves have the environment axis (``num_envs``) first.
* The metrics of a chunk: a flat dict of scalars with at least ``avg_reward`` (mean reward per
  control step per environment over the chunk, the reward the environment gives, not a scaled one),
  ``forward_speed`` (mean, m/s), ``trials_in_chunk``, ``step``, ``trials``, ``diverged`` (the
  state's, after the chunk) and the global norms of the learned parameters under names ending in
  ``_norm`` (e.g. ``theta_norm``; a non-finite one marks the chunk diverged, :func:`is_diverged`).
* The compact continuation state (``compact.npz``, small enough to commit; nmrl/runs/compact.py):
  the top-level state fields named in ``compact_fields`` (e.g. parameters, optimizer state,
  observation statistics) and ``step``, ``trials``, ``diverged``, ``key``. A run continues from it
  by ``k_init, key = split(saved key)``, ``state = trainer.init(k_init)`` with those fields, the
  counters and ``key`` replaced: every environment starts a new trial (statistically, not bitwise,
  equal to the full checkpoint).
* The deterministic policy for evaluation: ``policy_fields`` are the top-level state fields it
  reads (saved beside every checkpoint as its small ``policy`` item, so evaluation reads only
  them; a subset of ``compact_fields``), and ``policy(config, env) -> Policy`` gives
  ``act(params, obs, xi) -> action`` with ``params = {field: state.field for field in
  policy_fields}``: the action the learner sends to ``env.step`` (after its observation
  normalisation, squashing or clipping) for the exploration noise ``xi`` (zeros: the deterministic
  policy), and the noise process of the exploring policy (:class:`Policy`). ``act``, ``noise_init``
  and ``noise_step`` may depend only on config fields outside ``hyper_fields`` (evaluation compiles
  one rollout per :func:`program_key`); ``noise_args`` on any.
* ``restorable`` / ``fill``: top-level state fields a checkpoint written by an earlier version of the
  learner may lack, and ``fill(trainer, state) -> state`` that sets them (exactly what the older
  run would have had); ``check(config)``: checks made before ``config.validate()`` (default: none).
* ``explorations`` / ``exploration``: the exploration processes of nmrl.explore the learner takes
  and how ``--exploration KIND`` with its parameters in seconds/Hz (one option group for every
  learner, made from the declarations of ``nmrl.explore.ExplorationFields`` and parsed under its
  field names) sets its config: a config that holds those fields itself (a group whose class
  derives from ``ExplorationFields``, e.g. PPO's ``noise``) takes them as they are; another maps them onto its own fields
  (``exploration``, e.g. the actor-critic's l and alpha).

A new learner provides these and registers itself at import: ``register(Learner(name="x", ...))``
in its module, and its module path in :data:`BUILTIN` (or the caller imports it before use; a
test registers a toy learner this way). :func:`get` imports a built-in learner on first use. A
built-in learner registers from its config's module (``ac_config``, ``ppo_config``: no JAX, so that
a command line's options and ``--help`` are made without it), its program's functions named by
module (:func:`lazy`) and imported when a run first calls them.
"""

from __future__ import annotations

import dataclasses
import importlib
import math
from typing import Any, Callable, NamedTuple, Protocol

from nmrl import options

#: learner name -> module that registers it when imported
BUILTIN = {"ac": "nmrl.learners.ac_config", "ppo": "nmrl.learners.ppo_config"}
#: the learner of a run whose config.json or checkpoint names none (every run before there were two)
DEFAULT = "ac"
#: the key of ``config.json`` (and of a checkpoint's metadata) that names the learner
KEY = "learner"
#: the fields of the group ``budget`` every learner's config has (the driver reads them)
COMMON_FIELDS = ("seed", "num_envs", "chunk_steps", "steps", "trials", "max_param_norm")
#: metrics every chunk reports
METRICS = ("avg_reward", "forward_speed", "trials_in_chunk", "step", "trials", "diverged")


class Budget(Protocol):
    """The group ``budget`` of every learner's config (:data:`COMMON_FIELDS`)."""

    seed: int
    num_envs: int
    chunk_steps: int
    steps: int | None
    trials: int | None
    max_param_norm: float


class Config(Protocol):
    """What the driver reads of every learner's config (its groups ``environment``, a
    ``nmrl.tasks.EnvFields``, and ``budget``, checked for each registered learner by :func:`register`):
    the one meaning of ``Config`` in nmrl.runs. A learner's config is a frozen dataclass declared with
    ``option(...)`` (nmrl/options.py)."""

    environment: Any
    budget: Budget

    def resolved(self) -> "Config":
        """The config with its derived fields filled in (a preset's step sizes, ...)."""

    def validate(self) -> None:
        """ValueError naming a bad value and what is allowed."""


class Trainer(Protocol):
    """What ``Learner.make`` returns: the one meaning of ``Trainer`` in nmrl (the actor-critic's
    :class:`nmrl.learners.ac_train.ACTrainer` has these fields and more)."""

    config: Any
    env: Any
    init: Callable[..., Any]
    chunk: Callable[[Any], tuple[Any, dict]]


class Policy(NamedTuple):
    """A policy for evaluation (one environment, unbatched ``obs`` of shape (obs_dim,)).

    ``act(params, obs, xi) -> action``; ``noise_init(act_dim) -> noise state``;
    ``noise_step(noise_args, noise_state, eps) -> (noise_state, xi)`` with ``eps`` ~ N(0, I) of shape
    (act_dim,) drawn per control step; ``noise_args``: a pytree of arrays (traced, so one compiled
    rollout serves every value). The exploring rollout is ``a_t = act(params, s_t, xi_t)``, the
    deterministic one the same with ``xi_t`` multiplied by a traced 0.
    """

    act: Callable[[Any, Any, Any], Any]
    noise_init: Callable[[int], Any]
    noise_step: Callable[[Any, Any, Any], tuple[Any, Any]]
    noise_args: Any


@dataclasses.dataclass(frozen=True)
class Learner:
    """One learner as the driver sees it (see the module docstring for each part)."""

    name: str
    config: type
    hyper: Callable[[Any], Any]
    hyper_fields: tuple[str, ...]
    make: Callable[..., Trainer]
    env_fields: tuple[str, ...]
    compact_fields: tuple[str, ...]
    policy_fields: tuple[str, ...]
    policy: Callable[[Any, Any], Policy]
    #: one line for ``nmrl train --help``
    doc: str = ""
    #: option help per config field (``--help``; nmrl.options.helps of the config's declarations);
    #: fields without one show their default only
    help: dict[str, str] = dataclasses.field(default_factory=dict)
    restorable: tuple[str, ...] = ()
    fill: Callable[[Trainer, Any], Any] | None = None
    check: Callable[[Any], None] | None = None
    #: a few config fields that describe a run in one line (eval.json, progress); default: none
    describe: Callable[[Any], dict] | None = None
    #: the exploration processes (nmrl.explore kinds) the learner can use, and
    #: ``exploration(config, kind, params, given) -> config``: the config with the process ``kind``
    #: (None: the learner's default process) and its parameters ``params`` (seconds/Hz, e.g.
    #: ``{"period_s": 0.2}``) applied; ``given`` names the config fields the user set (a parameter that
    #: contradicts one of them is refused). ValueError naming the value and what is allowed, also for a
    #: process the learner cannot use. None: the config holds the spec's fields itself (or the
    #: learner takes no exploration options: ``explorations`` empty).
    explorations: tuple[str, ...] = ()
    #: the traced config field ``nmrl sweep`` varies by default (given as a list: ``--l 1 2 10``); None:
    #: a sweep of this learner runs its seeds only
    sweep_field: str | None = None
    exploration: Callable[[Any, str | None, dict, frozenset], Any] | None = None

    def validate(self, config: Any) -> None:
        """``config.validate()`` and the learner's own checks (ValueError naming the value)."""
        if not isinstance(config, self.config):
            raise ValueError(f"learner {self.name!r} takes a {self.config.__name__}, got {type(config).__name__}")
        if self.check is not None:
            self.check(config)
        config.validate()


_REGISTRY: dict[str, Learner] = {}


def register(learner: Learner) -> Learner:
    """Add ``learner`` under its name (replacing one of the same name and config class)."""
    groups = options.groups(learner.config)
    budget = options.leaves(groups["budget"]) if "budget" in groups else {}
    missing = [f for f in COMMON_FIELDS if f not in budget] + [g for g in ("environment", "budget") if g not in groups]
    if missing:
        raise TypeError(f"learner {learner.name!r}: its config {learner.config.__name__} lacks {missing}")
    old = _REGISTRY.get(learner.name)
    if old is not None and old.config is not learner.config and old.config.__qualname__ != learner.config.__qualname__:
        raise ValueError(f"a learner named {learner.name!r} is already registered ({old.config.__name__})")
    _REGISTRY[learner.name] = learner
    return learner


def lazy(module: str, name: str) -> Callable[..., Any]:
    """The function ``name`` of ``module``, imported at its first call. A built-in learner registers
    from its config's module, which imports no JAX (a command line's ``--help`` reads the learners'
    declarations), and names its program's functions (``make``, ``policy``, ...) this way."""

    def call(*args: Any, **kwargs: Any) -> Any:
        return getattr(importlib.import_module(module), name)(*args, **kwargs)

    call.__name__, call.__qualname__ = name, f"{module}.{name}"
    return call


def _load(name: str) -> None:
    module = BUILTIN.get(name)
    if module is None or name in _REGISTRY:
        return
    try:
        importlib.import_module(module)
    except ModuleNotFoundError as e:
        if e.name != module:  # the learner's module exists but imports something that does not
            raise


def names() -> list[str]:
    """The learners that can be used: the built-in ones that import and any registered (a built-in
    learner whose module fails to import is left out here; :func:`get` raises its error)."""
    for n in BUILTIN:
        try:
            _load(n)
        except Exception:  # noqa: BLE001 - listed only; get(n) reports the error
            pass
    return sorted(_REGISTRY)


def get(name: str) -> Learner:
    """The learner ``name``; ValueError naming it and the allowed names if there is none."""
    _load(name)
    if name not in _REGISTRY:
        raise ValueError(f"learner={name!r} is unknown: choose one of {', '.join(names())}")
    return _REGISTRY[name]


def of(config: Any) -> Learner:
    """The learner whose config class ``config`` is an instance of."""
    for lr in _REGISTRY.values():
        if type(config) is lr.config:
            return lr
    names()  # a built-in learner not imported yet
    for lr in _REGISTRY.values():
        if type(config) is lr.config:
            return lr
    raise TypeError(f"{type(config).__name__} is the config of no registered learner ({', '.join(names())})")


def config_dict(config: Any) -> dict:
    """What ``config.json`` holds: ``{"learner": name, **options.flat(config)}``, the config's leaves by
    flat name in leaf order (the identity's view, nmrl/runs/identity.py)."""
    return {KEY: of(config).name, **options.flat(config)}


#: Config fields added after runs were saved without them, with the value those runs had: a saved
#: config without such a field gets that value back (:func:`saved_fields`), and a run's identity
#: leaves a field at that value out (nmrl/runs/identity.py), so older runs keep their digests and
#: continue as they ran (the paper's rule, plain sgd, the actor-critic, PPO's gradient of a whole
#: minibatch at once, XLA's arctan).
LATER_FIELDS: dict[str, object] = {"actor_opt": "sgd", "critic_opt": "sgd", KEY: DEFAULT,
                                   "physics": "mjx", "trial_s": None,
                                   "physics_timestep": None, "env": "paper-cheetah",
                                   "grad_chunks": 1, "arctan": "xla"}


def saved_fields(cls: type, d: dict) -> dict:
    """A saved config's fields ``d`` for the config class ``cls``, with every field of
    :data:`LATER_FIELDS` that ``cls`` has and ``d`` lacks set to the value runs had before it existed."""
    names = options.leaves(cls)
    return {**{k: v for k, v in LATER_FIELDS.items() if k in names and k not in d}, **d}


def config_from_dict(d: dict, learner: str | None = None) -> Any:
    """The config a flat dict of :func:`config_dict` (config.json's layout, with or without the key
    ``learner``; without it of the learner ``learner``, default :data:`DEFAULT`) describes, fields it
    predates as :func:`saved_fields` fills them; ValueError for an unknown learner, TypeError for
    unknown fields (named)."""
    d = dict(d)
    name = d.pop(KEY, None) or learner or DEFAULT
    lr = get(name)
    unknown = sorted(set(d) - set(options.leaves(lr.config)))
    if unknown:
        raise TypeError(f"the config of learner {name!r} has no fields {unknown}")
    return options.build(lr.config, **saved_fields(lr.config, d))


def replace_state(state: Any, **fields: Any) -> Any:
    """``state`` with some top-level fields replaced (a dataclass pytree or a NamedTuple)."""
    if hasattr(state, "_replace"):
        return state._replace(**fields)
    return dataclasses.replace(state, **fields)


def norm_keys(row: dict) -> list[str]:
    """The parameter-norm metrics of a row (names ending in ``_norm``)."""
    return [k for k in row if k.endswith("_norm")]


def is_diverged(row: dict) -> bool:
    """A metrics row of a diverged chunk: its flag, or a non-finite parameter norm."""
    return bool(row["diverged"]) or not all(math.isfinite(row[k]) for k in norm_keys(row))


def program_key(config: Any) -> Any:
    """The part of a config compiled into the program: the config with its traced fields and seed at
    the class defaults (two configs with equal keys run as points of one program)."""
    lr = of(config)
    default = lr.config()
    return options.replace(config, seed=0, **{k: options.value(default, k) for k in lr.hyper_fields})
