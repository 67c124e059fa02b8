"""The actor-critic's update rules: optimizer chains named by a small vocabulary (Table II, steps 4, 5).

The parameter steps of Table II are plain gradient *ascent* along the pseudo-gradients
sum_e d_e z_e (actor) and sum_e d_e y_e (critic); optax minimises, so the training program
(nmrl/learners/ac_train.py) hands each optimizer the negated pseudo-gradient and applies its update.

``actor_opt`` and ``critic_opt`` (nmrl/learners/ac_config.py) name an optax chain per network from
:data:`OPT_VOCAB` (``sgd``, ``adam``, ``clip`` = clip by global norm; :func:`parse_opt`), e.g.
``"clip:1000,sgd"`` or ``"sgd,clip:1"`` or ``"adam:b1=0.8"``; exactly one element (sgd or adam) takes
the traced step size. The chain is compiled into the program (a sweep's points share it) and
recorded in canonical form (:func:`format_opt`) in the config, so it is part of the run's identity;
its state (e.g. Adam's moments) is in ``opt_theta`` / ``opt_v`` of the training state. The presets
name ``sgd`` for both networks, and a chain of one ``sgd`` is ``optax.sgd`` itself (no
``optax.chain`` around it).

The step size is not baked into the program: each chain is wrapped in ``optax.inject_hyperparams``
(:func:`injected`) and its ``learning_rate`` is overwritten at every control step from the traced
hyperparameters (:func:`with_learning_rate`), so a sweep over beta is one compiled program.

The sgd chain is the paper's update written by hand, ``theta + beta * sum_e d_e z_e``: optax.sgd
adds -beta * -S, and -beta * -S == beta * S exactly in floating point (tests/test_learner.py
recomputes the hand-written rule around every control step of a chunk and compares).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Callable, NamedTuple

from nmrl import options

if TYPE_CHECKING:  # the rules import optax when they are made: the grammar is read without JAX (--help)
    import jax
    import optax

OptState = Any

#: The update rules a config may name for the actor (``actor_opt``) and the critic (``critic_opt``):
#: a chain of optax transformations, written ``name[:param[:param...]][,name...]``, applied left to
#: right to the negated pseudo-gradient (module docstring). Parameters are given in the order
#: below or as ``key=value``; omitted ones take the defaults (None: required). Exactly one element
#: is a *step* (sgd or adam): its learning rate is the traced step size of ``Hyper``
#: (beta_theta / beta_v). ``clip`` before the step bounds the global norm of the summed
#: pseudo-gradient sum_e d_e z_e; after it, the global norm of the update itself (parameter units).
OPT_VOCAB: dict[str, dict[str, float | None]] = {
    "sgd": {},  #: optax.sgd(beta): p += beta * sum_e d_e z_e, the paper's rule
    "adam": {"b1": 0.9, "b2": 0.999, "eps": 1e-8},  #: optax.adam(beta, b1, b2, eps)
    "clip": {"max_norm": None},  #: optax.clip_by_global_norm(max_norm)
}
#: The elements that take the step size (one per chain).
OPT_STEPS = ("sgd", "adam")
OPT_HELP = ("optimizer chain, e.g. 'sgd' (the paper's rule), 'clip:10,sgd' (clip the summed pseudo-gradient "
            "by global norm 10, then sgd), 'sgd,clip:0.01' (clip the update), 'adam' or "
            "'adam:b1=0.9:b2=0.999:eps=1e-8'; elements: sgd, adam[:b1:b2:eps], clip:max_norm; exactly one "
            "sgd or adam, whose step size is --beta-theta / --beta-v")


class OptStep(NamedTuple):
    """One element of an optimizer chain: a name of :data:`OPT_VOCAB` and its parameters (all given)."""

    name: str
    params: tuple[tuple[str, float], ...]


def parse_opt(spec: Any, field: str = "opt") -> tuple[OptStep, ...]:
    """The chain an optimizer spec names (see :data:`OPT_VOCAB`); ValueError naming the bad part and
    listing what is allowed."""
    allowed = ", ".join(f"{n}" + "".join(f"[:{k}]" if d is not None else f":{k}" for k, d in ps.items())
                        for n, ps in OPT_VOCAB.items())
    if not isinstance(spec, str) or not spec.strip():
        raise options.invalid(field, spec, f"must be a chain of {allowed} separated by commas, e.g. 'clip:10,sgd'")
    chain = []
    for part in spec.split(","):
        name, *args = [a.strip() for a in part.strip().split(":")]
        if name not in OPT_VOCAB:
            raise options.invalid(field, spec, f"unknown optimizer {name!r}; allowed: {allowed} (e.g. 'clip:10,sgd')")
        defaults = OPT_VOCAB[name]
        keys = list(defaults)
        given: dict[str, float] = {}
        if len(args) > len(keys):
            raise options.invalid(field, spec, f"{name} takes {len(keys)} parameter(s) ({', '.join(keys) or 'none'}), "
                                          f"got {len(args)}")
        for i, a in enumerate(args):
            k, eq, v = a.partition("=")
            k, v = (k.strip(), v.strip()) if eq else (keys[i], a)
            if k not in defaults:
                raise options.invalid(field, spec, f"{name} has no parameter {k!r}; its parameters: "
                                              f"{', '.join(keys) or 'none'}")
            if k in given:
                raise options.invalid(field, spec, f"{name}'s parameter {k} is given twice")
            try:
                x = float(v)
            except ValueError:
                raise options.invalid(field, spec, f"{name}'s {k}={v!r} is not a number") from None
            if not math.isfinite(x):
                raise options.invalid(field, spec, f"{name}'s {k}={v!r} must be finite")
            given[k] = x
        params = []
        for k, d in defaults.items():
            x = given.get(k, d)
            if x is None:
                raise options.invalid(field, spec, f"{name} needs {k} (e.g. '{name}:10')")
            ok = {"max_norm": x > 0, "eps": x > 0, "b1": 0 <= x < 1, "b2": 0 <= x < 1}[k]
            if not ok:
                rng = {"max_norm": "> 0", "eps": "> 0", "b1": "in [0, 1)", "b2": "in [0, 1)"}[k]
                raise options.invalid(field, spec, f"{name}'s {k}={x!r} must be {rng}")
            params.append((k, x))
        chain.append(OptStep(name, tuple(params)))
    steps = [s.name for s in chain if s.name in OPT_STEPS]
    if len(steps) != 1:
        raise options.invalid(field, spec, f"needs exactly one step element ({' or '.join(OPT_STEPS)}, which takes the "
                                      f"step size beta), got {len(steps)}")
    return tuple(chain)


def format_opt(chain: tuple[OptStep, ...]) -> str:
    """The canonical spec of a chain (every parameter spelled out): what config.json records."""
    return ",".join(s.name + "".join(f":{k}={x!r}" for k, x in s.params) for s in chain)


def canonical_opt(spec: str, field: str = "opt") -> str:
    return format_opt(parse_opt(spec, field))


def opt_rule(chain: tuple[OptStep, ...]) -> Callable[[jax.Array], optax.GradientTransformation]:
    """``learning_rate -> GradientTransformation`` of a parsed chain. A chain of one ``sgd`` is exactly
    :func:`sgd_rule` (the paper's rule, with the state of a plain ``optax.sgd``)."""
    import optax

    def rule(learning_rate: jax.Array) -> optax.GradientTransformation:
        parts = []
        for s in chain:
            p = dict(s.params)
            if s.name == "sgd":
                parts.append(sgd_rule(learning_rate))
            elif s.name == "adam":
                parts.append(optax.adam(learning_rate, b1=p["b1"], b2=p["b2"], eps=p["eps"]))
            elif s.name == "clip":
                parts.append(optax.clip_by_global_norm(p["max_norm"]))
            else:  # pragma: no cover - parse_opt admits only the vocabulary
                raise ValueError(s.name)
        return parts[0] if len(parts) == 1 else optax.chain(*parts)

    return rule


def sgd_rule(learning_rate: jax.Array) -> optax.GradientTransformation:
    """The paper's update (Table II, steps 4 and 5): p := p - beta g on the negated pseudo-gradient
    g = -sum_e d_e z_e (actor) or -sum_e d_e y_e (critic), i.e. p := p + beta sum_e d_e z_e."""
    import optax

    return optax.sgd(learning_rate)


def injected(rule: Callable[[jax.Array], optax.GradientTransformation], learning_rate: jax.Array
             ) -> optax.GradientTransformation:
    """``rule`` with its step size as a traced hyperparameter (``optax.inject_hyperparams``)."""
    import optax

    return optax.inject_hyperparams(lambda learning_rate: rule(learning_rate))(learning_rate=learning_rate)


def with_learning_rate(state: OptState, learning_rate: jax.Array) -> OptState:
    """The injected-hyperparameter state with its ``learning_rate`` replaced (traced per point)."""
    return state._replace(hyperparams={**state.hyperparams, "learning_rate": learning_rate})
