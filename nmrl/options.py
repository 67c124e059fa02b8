"""One declaration per config field, and what is generated from it (rejax's one-line traced field).

A learner's config is a frozen dataclass whose fields are declared with :func:`option`::

    clip_eps: float = option(0.3, "PPO's clip epsilon of the ratio", traced=True, range=POSITIVE)

The declaration holds the field's default, its help (``--help``), whether it is traced (a leaf of
the learner's ``Hyper`` pytree: a sweep's points may differ in it, one compiled program serves every
value), the values it allows (a :class:`Range` or ``choices``), its command-line spelling where it is
not the field name with dashes, how the command line reads a value where not by its type, and
whether it is an option at all. A setting that several configs hold is declared once and taken by
the others with :func:`same_as` (their own default).

**Groups.** A config holds groups of fields as fields of its own, each made by :func:`group` (a
learner's ``environment``, ``budget`` and PPO's ``noise``: ``config.environment.control_dt``), and
every field of a group is declared in the group's class. The declared fields of a config are its
*leaves*: its own fields and, in their place, the leaves of its groups, each named by its field name
alone (its *flat name*, unique in the config; :func:`leaves`). Everything below works on leaves by
flat name: the command line walks the nesting, :func:`flat` is the config as one flat dict in leaf
order (config.json and the run's identity, the same for a grouped config as for one whose fields
are all its own), :func:`build` and :func:`replace` make or change a config by flat names (a sweep's
points, ``--vary``, a preset), refusing an unknown name in one line. From the declarations come:

* :func:`helps`: the help of every option (``Learner.help``; nmrl/cli/config_options.py builds one option per field);
* :func:`traced`: the traced fields (``Learner.hyper_fields``, what ``nmrl sweep --vary`` takes);
* :func:`hyper_leaves` and :func:`hyper_values`: the leaves of the learner's ``Hyper`` NamedTuple
  (a class written out beside the config, so that editors and type checkers read it; a test checks
  it against the declarations) are the traced fields in declaration order, cast to float32 or int32
  by the field's type; a field whose traced value needs code (PPO's
  ``gamma = exp(-control_dt / discount_horizon_s)``) names its leaf (``traced="gamma"``) and the
  learner gives that leaf's function once;
* :func:`check`: the type, finiteness and range or choices of every field (one line
  ``NAME=VALUE is invalid: ...`` naming what is allowed), what a config's ``validate`` runs; with
  ``limits``, what nmrl/runs/bounds.py runs before anything of a run is written, also float32/int32
  representability and the caps of sense (a step size at most 1, :attr:`Range.cap`).

A learner computes in float32 and counts in int32, so a value Python holds exactly may not survive
the cast (``--sigma 1e300`` becomes inf): before a run, a ``float`` must be finite in float32 and,
when not 0, not below float32's smallest normal number; an ``int`` must fit in int32, except a field whose range
says otherwise (the seed: JAX's PRNG keys take 32-bit unsigned seeds, :data:`SEED_MAX`).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import typing
from typing import Any, Callable, Mapping

import numpy as np

F32_MAX = float(np.finfo(np.float32).max)
F32_TINY = float(np.finfo(np.float32).tiny)
INT32_MAX = 2**31 - 1
#: JAX's PRNG seeds are 32-bit unsigned (``jax.random.PRNGKey(2**32 - 1)`` is a key of its own;
#: larger or negative seeds wrap around to another seed's key)
SEED_MAX = 2**32 - 1
#: the longest evaluation rollout, ``nmrl eval --seconds`` and ``nmrl baseline eval --seconds`` (the GIF
#: keeps every frame in memory: 25 per simulated second)
MAX_EVAL_SECONDS = 600.0
#: the metadata key of a declaration in a dataclass field
KEY = "nmrl.option"
#: the metadata key of a group's class in the field that holds it (:func:`group`)
GROUP_KEY = "nmrl.group"


@dataclasses.dataclass(frozen=True)
class Range:
    """``lo <= x <= hi`` (``lo`` excluded when ``open_lo``), with the reason in words."""

    lo: float
    hi: float = math.inf
    open_lo: bool = False
    why: str = ""
    #: ``hi`` is a cap of sense (a step size at most 1, a noise sigma at most 10), checked before a run
    #: (nmrl/runs/bounds.py) but not by a config's ``validate``: code may go beyond it (a test that
    #: makes a run diverge on purpose); False: nothing beyond ``hi`` means anything (a probability)
    cap: bool = False

    def contains(self, x: float, cap: bool = True) -> bool:
        """``x`` in the range (``cap`` False: a cap's upper end not checked)."""
        return (x > self.lo if self.open_lo else x >= self.lo) and (x <= self.hi or self.cap and not cap)

    def text(self, kind: type = float) -> str:
        """``must be ...`` in words: an interval, or a bound when the range has no upper end."""
        if self.hi == math.inf:
            what = "an integer" if kind is int else "a finite number"
            text = f"{what} {'>' if self.open_lo else '>='} {self.lo:g}"
        elif kind is int:
            text = f"an integer in [{int(self.lo)}, {int(self.hi)}]"
        else:
            text = f"in {'(' if self.open_lo else '['}{self.lo:g}, {self.hi:g}]"
        return f"{text} ({self.why})" if self.why else text


#: ranges many fields share
POSITIVE = Range(0.0, open_lo=True)
NON_NEGATIVE = Range(0.0)
AT_LEAST_ONE = Range(1)
STEP_SIZE = Range(0.0, 1.0, why="a step size", cap=True)


@dataclasses.dataclass(frozen=True)
class Option:
    """A field's declaration (see the module docstring)."""

    help: str = ""
    #: False: static (compiled into the program); True: a ``Hyper`` leaf of the same name; a name:
    #: the derived ``Hyper`` leaf the field feeds (its function given to :func:`hyper_values`)
    traced: bool | str = False
    range: Range | None = None
    choices: tuple | None = None
    #: the command-line spelling without ``--`` (None: the field name with dashes)
    flag: str | None = None
    #: False: not a command-line option (a diagnostic set by code)
    cli: bool = True
    #: the option group the command line puts it in (None: the learner's own options)
    group: str | None = None
    #: how the command line reads one value (None: by the field's type), e.g. a study's period
    #: ``stationary`` as None
    parse: Callable[[str], Any] | None = None


def option(default: Any = dataclasses.MISSING, help: str = "", **meta: Any) -> Any:
    """A dataclass field with its declaration (:class:`Option`'s fields as keywords)."""
    return dataclasses.field(default=default, metadata={KEY: Option(help=help, **meta)})


#: the seeds a run allows, the range of the run field ``seed`` (a sweep's last seed is held to it too)
SEED_RANGE = Range(0, SEED_MAX, why="JAX's PRNG seeds are 32-bit; others wrap around to another seed")
#: the declarations of the run fields every learner's config has (nmrl/learners/contract.py)
_RUN_OPTIONS: dict[str, dict[str, Any]] = {
    "seed": dict(help="PRNG seed", range=SEED_RANGE),
    "steps": dict(help="budget in control steps per environment", range=AT_LEAST_ONE),
    "trials": dict(help="budget in trials, summed over the environments", range=AT_LEAST_ONE),
    "max_param_norm": dict(help="a parameter norm above this (or NaN) marks the run diverged", range=POSITIVE),
}


def check_seed(value: Any, name: str = "seed") -> None:
    """ValueError (one line, ``name`` naming the value) unless ``value`` is a seed the run field ``seed``
    allows: the one seed range, for a command's seed outside a learner's config (``nmrl eval --seed``,
    the Brax baseline's)."""
    check_value(name, value, int, Option(**_RUN_OPTIONS["seed"]))


def same_as(cls: type, name: str, default: Any, **changes: Any) -> Any:
    """A dataclass field declared as the field ``name`` of ``cls`` is (help, range, choices, ...) with
    its own ``default`` and ``changes`` of the declaration (e.g. ``cli=False``, another ``flag``): a
    setting that several configs hold, declared once (the environment's ``physics`` in a study's
    spec, the exploration's kind in PPO's config with PPO's default)."""
    decl = declaration(cls, name)
    return dataclasses.field(default=default, metadata={KEY: dataclasses.replace(decl, **changes) if changes else decl})


def run_option(name: str, default: Any, help: str | None = None) -> Any:
    """The declared run field ``name`` of :data:`_RUN_OPTIONS` with a learner's ``default`` (and help)."""
    meta = dict(_RUN_OPTIONS[name])
    meta["help"] = help or meta["help"]
    return option(default, **meta)


def group(cls: type) -> Any:
    """A dataclass field that holds the group ``cls`` (a dataclass of declared fields), by default
    ``cls()``: its fields are leaves of the config that holds it (module docstring)."""
    return dataclasses.field(default_factory=cls, metadata={GROUP_KEY: cls})


@functools.lru_cache(maxsize=None)
def leaves(cls: type) -> dict[str, tuple[tuple[str, ...], type]]:
    """Flat name -> (the attribute path from a ``cls`` to the leaf, the class that declares it), in
    leaf order: ``cls``'s fields, each group's leaves in its place. TypeError for a flat name twice."""
    out: dict[str, tuple[tuple[str, ...], type]] = {}
    for f in dataclasses.fields(cls):
        sub = f.metadata.get(GROUP_KEY)
        inner = {k: ((f.name, *path), owner) for k, (path, owner) in leaves(sub).items()} if sub else \
            {f.name: ((f.name,), cls)}
        twice = sorted(set(inner) & set(out))
        if twice:
            raise TypeError(f"{cls.__name__}: the field name(s) {twice} occur twice among its leaves")
        out.update(inner)
    return out


def groups(cls: type) -> dict[str, type]:
    """Group field name -> its class, the groups ``cls`` holds directly."""
    return {f.name: f.metadata[GROUP_KEY] for f in dataclasses.fields(cls) if GROUP_KEY in f.metadata}


def _owner(cls: type, name: str) -> tuple[type, str]:
    """(the class that declares the leaf ``name`` of ``cls``, its field name there); KeyError if none."""
    path, owner = leaves(cls)[name]
    return owner, path[-1]


def field(cls: type, name: str) -> dataclasses.Field:
    """The dataclass field of the leaf ``name`` of ``cls`` (its default, its metadata)."""
    owner, attr = _owner(cls, name)
    return owner.__dataclass_fields__[attr]


def value(config: Any, name: str) -> Any:
    """The value of the leaf ``name`` of ``config``, read along its path."""
    for attr in leaves(type(config))[name][0]:
        config = getattr(config, attr)
    return config


def flat(config: Any) -> dict[str, Any]:
    """The config as one dict, flat name -> value, in leaf order (config.json's layout)."""
    return {name: value(config, name) for name in leaves(type(config))}


def _unknown(cls: type, names: Any) -> None:
    """ValueError in one line naming the flat names of ``names`` that ``cls`` has no leaf of."""
    bad = sorted(set(names) - set(leaves(cls)))
    if bad:
        raise ValueError(f"{', '.join(bad)}: no such field of {cls.__name__} (its fields: {', '.join(leaves(cls))})")


def build(cls: type, **values: Any) -> Any:
    """A ``cls`` whose leaves are ``values`` by flat name, every other leaf at its default
    (:func:`_unknown`'s ValueError for a name ``cls`` has no leaf of)."""
    _unknown(cls, values)
    kw = {}
    for f in dataclasses.fields(cls):
        sub = f.metadata.get(GROUP_KEY)
        if sub is not None:
            kw[f.name] = build(sub, **{k: v for k, v in values.items() if k in leaves(sub)})
        elif f.name in values:
            kw[f.name] = values[f.name]
    return cls(**kw)


def replace(config: Any, **values: Any) -> Any:
    """``config`` with the leaves ``values`` (by flat name) replaced, in whichever group they are
    (:func:`_unknown`'s ValueError for a name the config has no leaf of)."""
    cls = type(config)
    _unknown(cls, values)
    kw = {}
    for name, sub in groups(cls).items():
        inner = {k: v for k, v in values.items() if k in leaves(sub)}
        if inner:
            kw[name] = replace(getattr(config, name), **inner)
    own = {k: v for k, v in values.items() if leaves(cls)[k][0] == (k,)}
    return dataclasses.replace(config, **own, **kw) if own or kw else config


def declaration(cls: type, name: str) -> Option:
    """The declaration of the leaf ``name`` of the dataclass ``cls`` (an empty one if it has none)."""
    return field(cls, name).metadata.get(KEY, Option())


def declarations(cls: type) -> dict[str, Option]:
    """Flat name -> declaration, in leaf order."""
    return {name: declaration(cls, name) for name in leaves(cls)}


def flag(cls: type, name: str) -> str:
    """The command-line option of a field, without ``--``."""
    return declaration(cls, name).flag or name.replace("_", "-")


def helps(cls: type) -> dict[str, str]:
    """The help of every declared field that has one."""
    return {n: d.help for n, d in declarations(cls).items() if d.help}


def traced(cls: type) -> tuple[str, ...]:
    """The traced fields, in field order."""
    return tuple(n for n, d in declarations(cls).items() if d.traced)


@functools.lru_cache(maxsize=None)
def _hint(cls: type, name: str) -> Any:
    """The annotation of the leaf ``name`` of ``cls`` (None if it cannot be resolved). Cached per class
    and field: resolving a class's annotations (``typing.get_type_hints``) costs ~1 ms, and a sweep
    checks every field of every point (10,000 points: minutes, before the cache)."""
    try:
        owner, attr = _owner(cls, name)
        return typing.get_type_hints(owner)[attr]
    except Exception:  # noqa: BLE001 - an unresolvable annotation: no kind
        return None


def is_sequence(cls: type, name: str) -> bool:
    """The field is a ``tuple[X, ...]``: one or more values, each of :func:`kind` and checked by the
    field's declaration (a study's control steps, a network's layer sizes)."""
    return typing.get_origin(_hint(cls, name)) is tuple


@functools.lru_cache(maxsize=None)
def kind(cls: type, name: str) -> type | None:
    """``float``, ``int``, ``bool`` or ``str`` for a field typed so (or ``X | None``, or a ``tuple`` of
    such values: the kind of each), else None."""
    t = _hint(cls, name)
    if t is None:
        return None
    if typing.get_origin(t) is tuple:
        t = typing.get_args(t)[0]
    args = [a for a in typing.get_args(t) if a is not type(None)] or [t]
    for k in (bool, float, int, str):
        if k in args:
            return k
    return None


def invalid(name: str, value: Any, allowed: str) -> ValueError:
    """The one-line refusal of a value: ``NAME=VALUE is invalid: what is allowed``."""
    return ValueError(f"{name}={value!r} is invalid: {allowed}")


def check_value(name: str, value: Any, kind_: type | None, decl: Option = Option(), limits: bool = True) -> None:
    """ValueError (one line) unless ``value`` is of its kind, finite, and allowed by the declaration's
    choices or range; with ``limits`` also representable for its use (float32 for ``float``, int32 for
    ``int`` unless the range says otherwise) and within a range's cap (:attr:`Range.cap`). None passes
    (a field that is None means "the default")."""
    if value is None:
        return
    if decl.choices is not None and value not in decl.choices:
        raise invalid(name, value, f"choose one of {', '.join(map(str, decl.choices))}")
    if kind_ is bool and not isinstance(value, bool):
        raise invalid(name, value, "must be true or false")
    if kind_ not in (int, float) or isinstance(value, bool) and decl.range is None:
        return
    r = decl.range
    if kind_ is int:
        if not isinstance(value, int) or isinstance(value, bool):
            raise invalid(name, value, f"must be {r.text(int)}" if r else "must be an integer")
        if limits and (r is None or r.hi == math.inf) and abs(value) > INT32_MAX:
            raise invalid(name, value, f"must fit in 32 bits (|{name}| <= {INT32_MAX}), as the counters and traced "
                                    f"integers do")
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        x = float(value)
        if not math.isfinite(x) and not limits:
            raise invalid(name, value, "must be a finite number")
        with np.errstate(over="ignore", under="ignore"):
            x32 = float(np.float32(x))  # rounded to nearest, as the learner's cast does
        if limits and not math.isfinite(x32):
            raise invalid(name, value, f"must be a finite number in float32 (|{name}| <= {F32_MAX:.4g}); the learner "
                                    f"computes in float32")
        if limits and x != 0 and abs(x32) < F32_TINY:
            raise invalid(name, value, f"below float32's smallest normal number {F32_TINY:.4g} (it would become 0 "
                                    f"or lose its precision); give 0 or a larger value")
    else:
        raise invalid(name, value, f"must be {r.text(float)}" if r else "must be a number")
    if r is not None and not r.contains(float(value), cap=limits):
        raise invalid(name, value, f"must be {r.text(kind_)}")


def check(config: Any, skip: frozenset[str] = frozenset(), limits: bool = True) -> None:
    """:func:`check_value` for every leaf of the dataclass ``config`` (but ``skip``; each value of a
    :func:`is_sequence` field), in leaf order: ValueError for the first that is not allowed. A
    config's ``validate`` checks without ``limits`` (what is meaningless anywhere);
    nmrl/runs/bounds.py with them, before a run."""
    cls = type(config)
    for name, decl in declarations(cls).items():
        if name in skip:
            continue
        v = value(config, name)
        if is_sequence(cls, name):
            if not isinstance(v, (tuple, list)) or not v:
                raise invalid(name, v, "give one or more values")
            for x in v:
                check_value(name, x, kind(cls, name), decl, limits)
        else:
            check_value(name, v, kind(cls, name), decl, limits)


def hyper_leaves(cls: type) -> tuple[str, ...]:
    """The leaves of ``cls``'s ``Hyper``: one per traced field (``traced=True``: the field's name) or per
    derived leaf (a field declared ``traced="leaf"``), in the order of the fields."""
    out: list[str] = []
    for name, decl in declarations(cls).items():
        leaf = name if decl.traced is True else decl.traced
        if leaf and leaf not in out:
            out.append(leaf)
    return tuple(out)


def hyper_values(hyper: type, config: Any, derived: Mapping[str, Callable[[Any], Any]] = {}) -> Any:  # noqa: B006
    """``hyper`` (a NamedTuple whose fields are :func:`hyper_leaves` of the config's class) of
    ``config``'s traced values: a traced field's value as float32 or int32 by its type, a derived
    leaf as ``derived[leaf](config)``. TypeError naming a leaf that is not declared or has no value."""
    import jax.numpy as jnp  # not at import: the command line sets JAX's devices first

    cls = type(config)
    names = hyper_leaves(cls)
    if tuple(hyper._fields) != names:
        raise TypeError(f"{hyper.__name__}{tuple(hyper._fields)} is not the traced values {names} of {cls.__name__}")
    missing = sorted(set(names) - set(traced(cls)) - set(derived))
    if missing:
        raise TypeError(f"{cls.__name__}: no function for the derived traced value(s) {missing}")
    dtype = {int: jnp.int32, float: jnp.float32}
    return hyper(**{leaf: derived[leaf](config) if leaf in derived
                    else jnp.asarray(value(config, leaf), dtype[kind(cls, leaf)]) for leaf in names})
