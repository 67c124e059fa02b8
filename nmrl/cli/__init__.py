"""The ``nmrl`` command: :func:`main` runs ``nmrl train``, ``sweep``, ``eval``, ``study`` or ``baseline``.

``main`` is the process's entry point (the console script ``nmrl``, ``python -m nmrl.cli``): before
JAX is imported it installs the signal guard of ``train`` and ``sweep`` for the command's whole
life (nmrl/runs/signals.py), sets the host device count (nmrl/runs/devices.py), picks the learner
(``--learner``, or the one a resumed run holds), runs a distributed command in a watched child
process (nmrl/runs/launch.py), and hands the rest to the command. The command line and its help
are nmrl/cli/arguments.py's; the commands nmrl/cli/commands.py's; the options are generated in
nmrl/cli/config_options.py (the learner's config), exploration_options.py and cluster_options.py;
a failure becomes one line and an exit status in nmrl/cli/failures.py (nmrl/runs/exits.py).
``nmrl study`` and ``nmrl baseline`` parse their own command lines (nmrl/experiments/study.py,
nmrl/experiments/baseline_ppo.py).
"""

from __future__ import annotations

import argparse
import json
import os
import sys

from nmrl.cli.arguments import build_parser
from nmrl.cli.cluster_options import add_distributed_options, cluster_of
from nmrl.cli.config_options import get_learner
from nmrl.cli.failures import fail
from nmrl.runs import devices as _devices
from nmrl.runs import launch as _launch
from nmrl.runs import signals as _signals


def _guard(what: str, out: str | None, resume: bool) -> "_signals.Guard":
    """The command's signal handling for its whole life (nmrl/runs/signals.py), installed before JAX
    is imported; a second signal, or a first one whose grace ran out during a chunk, exits at once
    naming what is intact: before the run's files are written (a fresh run), nothing; else the
    newest checkpoint."""
    def second(signum: int, moment: str) -> str:
        head = f"nmrl: stopped at once by a second signal {signum} while {moment}"
        written = out and any(os.path.exists(os.path.join(out, f)) for f in ("config.json", "sweep.json"))
        if not resume and not written and moment in ("starting", "compiling"):
            return f"{head}; nothing of the run was written"
        where = f" in {out}" if out else ""
        return (f"{head}; the newest checkpoint{where} is intact (saves are atomic); continue with: nmrl {what} "
                f"--resume --out {out}")

    def grace(signum: int, grace_s: float) -> str:
        return (f"nmrl: stopped by signal {signum}: the chunk in flight was not saved within the grace of "
                f"{grace_s:g} s (--grace-s, {_signals.GRACE_ENV}); what was saved before is intact (saves are "
                f"atomic); continue with: nmrl {what} --resume --out {out}")

    return _signals.Guard(on_second=second, on_grace=grace).install()


def _flag(argv: list[str], name: str) -> str | None:
    """The value of ``--name V`` or ``--name=V`` in ``argv`` (the last one), without parsing the rest."""
    val = None
    for i, a in enumerate(argv):
        if a == name and i + 1 < len(argv):
            val = argv[i + 1]
        elif a.startswith(name + "="):
            val = a[len(name) + 1:]
    return val


def learner_name(argv: list[str]) -> str | None:
    """The learner a ``train``/``sweep`` command line names (``--learner``), else with ``--resume`` the
    one its ``--out`` holds (config.json, sweep.json: no name is the actor-critic); None: the default."""
    name = _flag(argv, "--learner")
    if name is not None or "--resume" not in argv:
        return name
    out = _flag(argv, "--out")
    if out is None:
        return None
    spec = os.path.join(out, "sweep.json" if argv[:1] == ["sweep"] else "config.json")
    try:
        with open(spec) as f:
            saved = json.load(f)
    except (OSError, ValueError):
        return None
    name = saved.get("learner") if isinstance(saved, dict) else None
    return name if isinstance(name, str) else None


#: where compiled programs are kept between commands unless ``JAX_COMPILATION_CACHE_DIR`` says
#: otherwise; ``NMRL_COMPILE_CACHE=off`` turns the cache off (docs/runs.md)
COMPILE_CACHE = os.path.join("~", ".cache", "nmrl", "xla")


def compile_cache() -> None:
    """Before JAX is imported: XLA's persistent compile cache in :data:`COMPILE_CACHE` (or the user's
    ``JAX_COMPILATION_CACHE_DIR``), so a second command of the same shapes skips most compiling;
    ``NMRL_COMPILE_CACHE`` = off / 0 / false leaves it off. Programs that call back into MuJoCo C
    (``--physics c``) are not cached by JAX."""
    if os.environ.get("NMRL_COMPILE_CACHE", "").strip().lower() in ("off", "0", "false", "no"):
        return
    os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", os.path.expanduser(COMPILE_CACHE))


def main(argv: list[str] | None = None) -> int:
    """Run the command ``argv``; None: the process's own arguments, ``main`` being the process's
    entry point (which alone may mute stderr after a disk failure's line, nmrl/runs/io_errors.py)."""
    if argv is None:
        from nmrl.runs import io_errors

        io_errors.mute_after_report = True
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv:  # bare `nmrl`: the commands, not an error
        build_parser(None).print_help()
        return 0
    compile_cache()
    trains = argv[:1] in (["train"], ["sweep"])
    # this process runs the command (a distributed one's watcher forwards signals instead): from its
    # first line on, before JAX is imported, a signal never raises inside JAX (nmrl/runs/signals.py)
    watcher = trains and _flag(argv, "--coordinator") is not None and os.environ.get(_launch.CHILD_ENV) != "1"
    guard = _guard(argv[0], _flag(argv, "--out"), "--resume" in argv) if trains and not watcher else None
    try:
        return _command(argv, guard)
    except _signals.Interrupted as e:
        return e.exit_status
    finally:
        if guard is not None:
            guard.restore()


def _command(argv: list[str], guard: "_signals.Guard | None") -> int:
    """The command ``argv`` under ``guard`` (train and sweep; None for the others). A signal before
    the command starts its run stops it there (one process; several processes stop together at the
    driver's agreed points)."""
    early = guard if guard is not None and _flag(argv, "--coordinator") is None else None
    if guard is not None and early is None:  # several processes stop together, at agreed points
        guard.alone = False
    if early is not None:
        early.raise_if_stopped(_stopped_early)
    if argv[:1] in (["train"], ["sweep"], ["baseline"]):
        try:
            _devices.configure(_devices.requested(argv))  # before JAX is imported
        except ValueError as e:
            return fail(str(e))
    if argv[:1] == ["baseline"]:  # its own parser (nmrl/experiments/baseline_ppo.py); Brax is optional
        from nmrl.experiments import baseline_ppo

        return baseline_ppo.main(argv[1:])
    if argv[:1] == ["study"]:  # its own parser (argparse's REMAINDER would not pass --help on)
        from nmrl.experiments import study

        return study.main(argv[1:])
    learner = None
    if argv[:1] in (["train"], ["sweep"]):
        try:
            learner = get_learner(learner_name(argv))
        except ValueError as e:
            return fail(str(e).replace("learner=", "--learner=", 1))
    if argv[:1] in (["train"], ["sweep"]) and os.environ.get(_launch.CHILD_ENV) != "1":
        watched = _watch(argv)
        if watched is not None:
            return watched
    parser = build_parser(learner)
    args, unknown = parser.parse_known_args(argv)
    if unknown:  # only then the other learners' parsers are built, for the hint
        hint = _option_of_another_learner(argv, learner, parser) if learner is not None else None
        if hint is not None:
            return fail(hint)
        parser.parse_args(argv)  # argparse's one line naming the unknown option(s)
    args.argv = argv
    if early is not None:
        early.raise_if_stopped(_stopped_early)
    try:
        status = args.func(args)
    except _signals.Interrupted as e:
        status = e.exit_status
    if getattr(args, "coordinator", None) is not None and "jax" in sys.modules:
        from nmrl.runs import distributed

        sys.stdout.flush()
        sys.stderr.flush()
        if status == _launch.PEER_FAILED:  # the run is broken: leave at once, waiting for no one
            os._exit(status)
        distributed.leave()  # every process leaves here together (the end, a signal, a refusal)
    return status


def _command_options(parser: argparse.ArgumentParser, cmd: str) -> set[str]:
    """The option strings the subcommand ``cmd`` of ``parser`` takes."""
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return set(sub.choices[cmd]._option_string_actions)


def _option_of_another_learner(argv: list[str], learner, parser: argparse.ArgumentParser) -> str | None:
    """For ``train``/``sweep`` whose ``parser`` (of ``learner``) found unknown options: the line naming
    one that ``learner`` does not take but another learner does (``--learning-rate`` without
    ``--learner ppo``), else None (argparse answers). It builds every other learner's parser, so
    it runs only when parsing has failed."""
    from nmrl import learners
    from nmrl.cli.config_options import get_learner

    mine = _command_options(parser, argv[0])
    given = [a.split("=", 1)[0] for a in argv[1:] if a.startswith("--")]
    unknown = [a for a in given if a not in mine]
    for other in learners.names():
        if other == learner.name or not unknown:
            continue
        theirs = _command_options(build_parser(get_learner(other)), argv[0])
        belong = [a for a in unknown if a in theirs]
        if belong:
            return (f"{', '.join(belong)}: an option of the learner {other!r}, not of {learner.name!r} (give "
                    f"--learner {other}, see nmrl {argv[0]} --learner {other} --help)")
    return None


def _stopped_early(signum: int) -> str:
    print(f"stopped by signal {signum} before the run started; nothing was written", file=sys.stderr, flush=True)
    return f"stopped by signal {signum} before the run started"


def _watch(argv: list[str]) -> int | None:
    """A distributed ``train``/``sweep`` (``--coordinator`` given): run it in a watched child process
    (nmrl/runs/launch.py) and return its status; None for a 1-process command. Only the options of
    several processes are read here (no JAX); the child checks the rest before it connects."""
    pre = argparse.ArgumentParser(prog=f"nmrl {argv[0]}", add_help=False)
    add_distributed_options(pre)
    pre.add_argument("--out", default=None)
    ns, _ = pre.parse_known_args(argv[1:])
    if ns.coordinator is None:
        return None
    try:
        cluster = cluster_of(ns)
    except ValueError as e:
        return fail(str(e))
    return _launch.supervise(argv, cluster, ns.out)
