"""A study's cell as typed data, checked against its learner's declarations, and the one ``nmrl sweep``
command line it becomes.

A :class:`Cell` names its directory under the study's and what its points compute, as values rather
than command-line text: its learner (nmrl/learners/contract.py), the config fields every point shares
(``settings``: flat field name -> value, the names ``nmrl sweep --points`` takes), the budget
(``steps`` or ``trials``), and its points: one traced field's values (``vary``) x ``seeds`` seeds from
``seed0``, or the seeds alone, or the points one by one (``points``, ``nmrl sweep --points``: dicts
of a name and the fields each sets). Every name and value is checked against its field's declaration
(nmrl/options.py: its type, range or choices, float32/int32 representability) when the cell is made,
so a study naming a field its learner lacks, or a value the field does not allow, fails as it is
defined, with one line naming the cell, the field and what is allowed. How a cell runs, not what it
computes (``--group``, ``--checkpoint-every``, ``--quiet``, ``--devices``), is a dict of
:class:`SweepOptions`' fields, the study's and the cell's.

:func:`sweep_argv` is the one place a cell becomes the options of ``nmrl sweep``: each field by its
declared flag (``options.flag``), each value written so that the command line reads back the same
value (a float by its shortest round-trip text, a bool as true or false). The kit runs that command
as its own process, with its own devices, memory and signals (nmrl/experiments/kit.py).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Mapping

from nmrl import options
from nmrl.options import AT_LEAST_ONE, option

#: the config fields a cell gives apart from its settings: the budget and the seed (the sweep's own options)
_NOT_SETTINGS = ("steps", "trials", "seed")


@dataclasses.dataclass(frozen=True)
class SweepOptions:
    """The options of ``nmrl sweep`` that say how a cell runs, not what it computes (the command's
    own, nmrl/cli/arguments.py; a test checks each against the command's parser)."""

    group: int = option(1, "points vmapped together on one device", range=AT_LEAST_ONE)
    checkpoint_every: int = option(1, "checkpoint the points every K chunks", range=AT_LEAST_ONE)
    quiet: bool = option(False, "no progress display")
    devices: str = option("auto", "host (CPU) devices to split the work over: 'auto' = every core, 1 = off")


def _learner(name: str):
    from nmrl import learners

    return learners.get(name)


def _owner(learner, name: str) -> type | None:
    """The dataclass whose declaration of ``name`` the command line uses for ``learner``: its config,
    or the exploration's fields for a learner that maps them onto its own (the actor-critic's)."""
    from nmrl.explore import fields

    if name in options.leaves(learner.config):
        return learner.config if options.declaration(learner.config, name).cli else None
    if learner.explorations and name in fields.ExplorationFields.__dataclass_fields__:
        return fields.ExplorationFields
    return None


def _check(cls: type, name: str, value: Any) -> None:
    """ValueError (one line) unless ``value`` is one the field ``name`` of ``cls`` allows before a run."""
    for v in (value if options.is_sequence(cls, name) and isinstance(value, (tuple, list)) else (value,)):
        options.check_value(name, v, options.kind(cls, name), options.declaration(cls, name))


def _text(cls: type, name: str, value: Any) -> list[str]:
    """The command-line text of ``value`` for the field ``name`` of ``cls``: each value of a sequence."""
    values = value if options.is_sequence(cls, name) and isinstance(value, (tuple, list)) else (value,)
    return [("true" if v else "false") if isinstance(v, bool) else repr(v) if isinstance(v, float) else str(v)
            for v in values]


@dataclasses.dataclass(frozen=True)
class Cell:
    """One ``nmrl sweep`` of a study (module docstring); ValueError as it is made if a name or value is
    not one its learner's declarations allow."""

    name: str  #: directory under the study's, e.g. "screen/dt0.0025/white"
    learner: str = "ac"
    #: the config fields every point shares: flat field name -> value (neither the budget nor the seed)
    settings: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    steps: int | None = None  #: the budget in control steps per environment (given again on a resume)
    trials: int | None = None  #: the budget in trials
    #: ``(field, values)``: one point per value of the traced field and seed; None: the seeds alone
    vary: tuple[str, tuple] | None = None
    seeds: int | None = None  #: seeds per value (None: the sweep's default)
    seed0: int | None = None  #: the first seed (None: 0)
    #: the points one by one (``nmrl sweep --points``: dicts of a name and the config fields it sets,
    #: its seed among them); () : the fields above make the points
    points: tuple[dict, ...] = ()
    #: :class:`SweepOptions` of how this cell runs, given on its start and on every resume after the
    #: study's own (``Study.run_options``)
    run_options: Mapping[str, Any] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        try:
            self._check()
        except ValueError as e:
            raise ValueError(f"cell {self.name}: {e}") from None

    def _check(self) -> None:
        learner = _learner(self.learner)
        for k, v in self.settings.items():
            cls = _owner(learner, k)
            if cls is None or k in _NOT_SETTINGS or k == learner.sweep_field and (self.vary or (k,))[0] == k:
                swept = f", the seed and the swept {learner.sweep_field}" if learner.sweep_field else " and the seed"
                raise ValueError(f"setting {k!r} is invalid: a cell's settings are options of the learner "
                                 f"{learner.name!r} other than the budget{swept} (steps, trials, vary, seeds and "
                                 f"seed0 are the cell's own)")
            _check(cls, k, v)
        for k in ("steps", "trials"):
            _check(learner.config, k, getattr(self, k))
        if self.points:
            if self.vary is not None or self.seeds is not None or self.seed0 is not None:
                raise ValueError("a cell of listed points has no vary, seeds or seed0 (each point sets its seed)")
            for p in self.points:
                for k, v in p.items():
                    if k == "name":
                        continue
                    cls = _owner(learner, k) if k != "seed" else learner.config
                    if cls is not learner.config or k in ("steps", "trials"):
                        raise ValueError(f"point {p.get('name')!r} sets {k!r}: a point sets fields of the "
                                         f"learner {learner.name!r}'s config other than the budget")
                    _check(cls, k, v)
        if self.vary is not None:
            field, values = self.vary
            if field not in learner.hyper_fields and field != learner.sweep_field:
                raise ValueError(f"vary={field!r} is invalid: the learner {learner.name!r} varies one of its "
                                 f"traced hyperparameters: {', '.join(learner.hyper_fields)}")
            if not values:
                raise ValueError(f"vary {field} needs values")
            for v in values:
                _check(learner.config, field, v)
        if self.seeds is not None:
            options.check_value("seeds", self.seeds, int, options.Option(range=AT_LEAST_ONE))
        if self.seed0 is not None:
            options.check_seed(self.seed0, "seed0")
        for k, v in self.run_options.items():
            check_run_option(k, v)

    def budget_limit(self) -> tuple[str, int] | None:
        """The state counter the budget bounds and its limit: ``("step", N)`` for ``steps``,
        ``("trials", N)`` for ``trials``; None without a budget."""
        if self.steps is not None:
            return "step", self.steps
        if self.trials is not None:
            return "trials", self.trials
        return None


def check_run_option(name: str, value: Any) -> None:
    """ValueError (one line) unless ``name`` is a field of :class:`SweepOptions` and ``value`` one it allows."""
    if name not in SweepOptions.__dataclass_fields__:
        raise ValueError(f"run option {name!r} is invalid: choose one of "
                         f"{', '.join(SweepOptions.__dataclass_fields__)}")
    _check(SweepOptions, name, value)


def _budget(cell: Cell) -> list[str]:
    learner = _learner(cell.learner)
    return [t for k in ("steps", "trials") if getattr(cell, k) is not None
            for t in ("--" + options.flag(learner.config, k), *_text(learner.config, k, getattr(cell, k)))]


def _run(run_options: Mapping[str, Any]) -> list[str]:
    out: list[str] = []
    for k, v in run_options.items():
        check_run_option(k, v)
        flag = "--" + options.flag(SweepOptions, k)
        if isinstance(v, bool):  # a switch: given or not
            out += [flag] if v else []
        else:
            out += [flag, *_text(SweepOptions, k, v)]
    return out


def sweep_argv(cell: Cell, run_options: Mapping[str, Any] = {}, *, points_file: str | None = None,  # noqa: B006
               resume: bool = False) -> list[str]:
    """The options of ``nmrl sweep`` (after ``sweep``, before ``--out``) that run ``cell`` with
    ``run_options`` (the study's and the cell's :class:`SweepOptions`, merged): a fresh start (its
    points read from ``points_file`` when the cell lists them), or with ``resume`` the continuation
    of its saved sweep at the cell's budget."""
    if resume:
        return ["--resume", *_budget(cell), *_run(run_options)]
    learner = _learner(cell.learner)
    argv = ["--learner", learner.name]
    for k, v in cell.settings.items():
        cls = _owner(learner, k)
        argv += ["--" + options.flag(cls, k), *_text(cls, k, v)]
    argv += _budget(cell)
    if cell.vary is not None:
        field, values = cell.vary
        head = ["--" + options.flag(learner.config, field)] if field == learner.sweep_field else ["--vary", field]
        argv += [*head, *(t for v in values for t in _text(learner.config, field, v))]
    if cell.seeds is not None:
        argv += ["--seeds", str(cell.seeds)]
    if cell.seed0 is not None:
        argv += ["--seed0", str(cell.seed0)]
    if cell.points:
        if points_file is None:
            raise ValueError(f"cell {cell.name} lists its points: give the file that holds them")
        argv += ["--points", points_file]
    return [*argv, *_run(run_options)]
