"""Command-line parsing that refuses a bad option in one line, without argparse's usage page.

argparse answers ``--num-envs 1.5`` with the whole usage (15-18 lines) and then ``error: argument
--num-envs: invalid int value: '1.5'``. The project's rule for bad input is one line naming the
value and what is allowed, exit status 2 (nmrl/cli/). :class:`OneLineParser` keeps argparse's
parsing and rewrites only its error: ``nmrl train: error: --num-envs='1.5' is invalid: must be an
integer`` (an unknown option: ``... unknown option(s) --trials -5; see nmrl train --help``).
Subparsers made by ``add_subparsers`` are of the same class, so every command answers alike.
:func:`integer` is a strict ``type=`` for integer options (``1e3``, ``nan``, ``1.0`` are refused by
name; ``int()`` would refuse them too, this says what is allowed). :func:`add_declared` makes the
option of a field declared with ``nmrl.options.option`` (its spelling, type and help from the
declaration), for every command that takes such a field; :func:`add_fields` every option of a
config at once, and :func:`given_fields` reads back those given. :func:`add_grace_option` is every
running command's ``--grace-s``.
"""

from __future__ import annotations

import argparse
import dataclasses
import re
import sys
import typing
from typing import NoReturn

from nmrl.runs import signals

_INVALID = re.compile(r"argument (\S+?)(?:/\S+)?: invalid (\w+) value: (.*)$")
_TYPES = {"int": "an integer", "integer": "an integer", "float": "a number", "_bool": "true or false",
          "_period": "seconds > 0 or 'stationary'"}


def integer(text: str) -> int:
    """An integer option's value: decimal digits with an optional sign, nothing else."""
    s = text.strip()
    if not re.fullmatch(r"[+-]?\d+", s):
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer")
    return int(s)


def one_line(message: str) -> str:
    """argparse's error message as the project's one line (``--opt=VALUE is invalid: ...``)."""
    m = _INVALID.match(message)
    if m:
        opt, kind, value = m.groups()
        return f"{opt}={value} is invalid: must be {_TYPES.get(kind, kind)}"
    m = re.match(r"argument (\S+?)(?:/\S+)?: ('.*') is not (an integer|a number)$", message)
    if m:
        opt, value, kind = m.groups()
        return f"{opt}={value} is invalid: must be {kind}"
    m = re.match(r"argument (\S+?)(?:/\S+)?: (.*)$", message)
    if m:
        opt, why = m.groups()
        return f"{opt}: {why}"
    m = re.match(r"unrecognized arguments: (.*)$", message)
    if m:
        return f"unknown option(s) {m.group(1)}"
    return message.replace("\n", " ")


class OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line on stderr (exit status 2), naming the option and
    what it allows, with a pointer to ``--help`` instead of the usage."""

    def error(self, message: str) -> NoReturn:
        print(f"{self.prog}: error: {one_line(message)} (see {self.prog} --help)", file=sys.stderr, flush=True)
        self.exit(2)


def field_type(cls: type, name: str) -> type:
    """The type of the config field (leaf) ``name`` of ``cls`` (``X`` for ``X | None``)."""
    from nmrl import options

    owner = options.leaves(cls)[name][1]
    t = typing.get_type_hints(owner)[options.leaves(cls)[name][0][-1]]
    args = [a for a in typing.get_args(t) if a is not type(None)]
    return args[0] if args else t


def _bool(text: str) -> bool:
    if text.lower() in ("1", "true", "yes", "on"):
        return True
    if text.lower() in ("0", "false", "no", "off"):
        return False
    raise argparse.ArgumentTypeError(f"{text!r} is not a boolean (true or false)")


def add_declared(p, cls: type, name: str, default=None, help: str | None = None, metavar: str | None = None) -> None:
    """The option ``--<flag>`` of the field (leaf) ``name`` of the dataclass ``cls``, spelled, typed and explained
    by its declaration (nmrl/options.py), parsed into ``name`` with ``default`` (None: the field's own is
    applied later, by the config); the field's default is named unless the help names one. A
    ``tuple[X, ...]`` field takes one or more values; a declaration's ``parse`` reads each value.
    ``metavar``: the value's name in the help (default: the option's spelling in capitals)."""
    from nmrl import options

    f = options.field(cls, name)
    decl = options.declaration(cls, name)
    many = options.is_sequence(cls, name)
    t = options.kind(cls, name) if many else field_type(cls, name)
    doc = decl.help if help is None else help
    shown = f.default if f.default is not dataclasses.MISSING else "?"
    shown = " ".join(map(str, shown)) if many and isinstance(shown, tuple) else shown
    p.add_argument("--" + options.flag(cls, name), dest=name, type=decl.parse or (_bool if t is bool else t),
                   default=default, metavar=metavar or (decl.flag.upper().replace("-", "_") if decl.flag else None),
                   nargs="+" if many else None,
                   help=doc if "(default:" in doc else f"{doc} (default: {shown})".strip())


def add_fields(p, cls: type, helps: dict[str, str] | None = None) -> None:
    """:func:`add_declared` for every field of ``cls`` declared an option (``cli``), in field order, each
    parsed into its name with the default None (the config's own applies); ``helps`` replaces a help."""
    from nmrl import options

    for name, decl in options.declarations(cls).items():
        if decl.cli:
            add_declared(p, cls, name, help=(helps or {}).get(name))


def given_fields(args: argparse.Namespace, cls: type) -> dict:
    """The fields of ``cls`` that :func:`add_fields` made options of and that were given (name ->
    value; one or more values as a tuple)."""
    from nmrl import options

    return {name: tuple(v) if isinstance(v, list) else v for name, decl in options.declarations(cls).items()
            if decl.cli and (v := getattr(args, name, None)) is not None}


def add_grace_option(p: argparse.ArgumentParser) -> None:
    """``--grace-s``: how long a first SIGTERM/SIGINT leaves the chunk in flight (nmrl/runs/signals.py);
    read as text and checked with ``NMRL_GRACE_S`` by the command (``signals.grace_of``: one line,
    status 2)."""
    p.add_argument("--grace-s", default=None, metavar="SECONDS",
                   help=f"after a first SIGTERM/SIGINT, the seconds the chunk in flight has to finish and be "
                        f"saved before the run stops with its last saved chunk (default: ${signals.GRACE_ENV}, "
                        f"else {signals.DEFAULT_GRACE_S:g}: inside SLURM's default KillWait of 30 s)")
