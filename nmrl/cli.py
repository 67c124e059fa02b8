"""Command line: ``nmrl train``, ``nmrl sweep``, ``nmrl eval``, ``nmrl study``, ``nmrl baseline``.

``--learner NAME`` picks the learner (nmrl/learners/; default ``ac``, the paper's actor-critic;
a resume takes the run's own). Every field of the learner's config is an option of ``train`` and
``sweep`` (the actor-critic's :class:`nmrl.learners.ac_config.TrainConfig`: ``--beta-theta 2e-6``,
``--num-envs 256``, ``--actor-opt clip:10,sgd``, ...; ``nmrl train --learner NAME --help`` lists
them), and ``--exploration {white,nm-periods,ou,colored}`` with the process's parameters in seconds
or Hz sets the learner's exploration noise (the actor-critic: ``white`` is l = 1, ``nm-periods``
l = round(period_s / control_dt) and alpha = exp(-control_dt / corr_time_s); its default stays the
paper's nm-periods, ``--l``/``--alpha``). Bad values exit with status 2 and a message that names the
value, before anything is written.

Exit status (nmrl/runs/exits.py): 0 done, 2 bad input (one line ``nmrl: error: ...`` on stderr,
nothing written), 3 diverged (the last good checkpoint is kept), 4 another process of a distributed
run failed (nmrl/runs/distributed.py; the newest checkpoint is kept), 5 the disk or file system
refused a write (full, read-only, permission, immutable; one line naming the path and the cause),
6 another nmrl process is writing the same directory (named), 7 out of memory allocating the run,
128 + the signal when SIGINT (130) or SIGTERM (143) stopped the command (after the chunk in flight
was saved, ``--resume`` continues it; or before the first chunk, nothing of the run written).

Several processes (``--coordinator HOST:PORT --num-processes P --process-id I``, or
``--coordinator auto`` under SLURM/Open MPI): every process runs the same command; each is watched
by nmrl/runs/launch.py, which reports JAX's aborts (an unreachable coordinator, a dead peer) as
clear errors.

The benchmarks are not a command: they live in the checkout (``python -m benchmarks``, which
writes its measurements into results/benchmarks/), not in the installed package.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
import typing
from collections.abc import Callable

from nmrl.runs import devices as _devices
from nmrl.runs import exits as _exits
from nmrl.runs import launch as _launch
from nmrl.runs import parser as _parser
from nmrl.runs import signals as _signals

# nmrl.learners.ac_config (and with it JAX) is imported only after nmrl.runs.devices.configure has set the host
# device count (main()). The budget of a run given none is TrainConfig's (nmrl.learners.ac_config.DEFAULT_STEPS).
_SWEEP_SEED = "seed"  # ``nmrl sweep`` gives --seeds (a count) and the learner's sweep_field as a list
#: Longest ``nmrl eval --seconds`` (the GIF keeps every frame in memory: 25 per simulated second).
MAX_EVAL_SECONDS = 600.0


def _field_type(cls: type, f: dataclasses.Field) -> type:
    hints = typing.get_type_hints(cls)
    t = hints[f.name]
    args = [a for a in typing.get_args(t) if a is not type(None)]
    return args[0] if args else t


def _bool(text: str) -> bool:
    if text.lower() in ("1", "true", "yes", "on"):
        return True
    if text.lower() in ("0", "false", "no", "off"):
        return False
    raise argparse.ArgumentTypeError(f"{text!r} is not a boolean (true or false)")


def _learner(name: str | None = None):
    """The learner ``name`` (default: the actor-critic); ValueError naming it and the allowed ones."""
    from nmrl import learners

    return learners.get(name or learners.DEFAULT)


def _options(learner, skip: set[str] = frozenset(), group: str | None = None) -> list[dataclasses.Field]:
    """The config fields that are options of the group ``group`` (None: the learner's own)."""
    from nmrl import options

    return [f for f in dataclasses.fields(learner.config) if f.name not in skip
            and options.declaration(learner.config, f.name).cli
            and options.declaration(learner.config, f.name).group == group]


def add_config_options(p: argparse.ArgumentParser, skip: set[str] = frozenset(), learner=None) -> None:
    """One option per field of the learner's config (nmrl/learners/contract.py), spelled and explained
    by the field's declaration (nmrl/options.py), with its default unless the help names it."""
    from nmrl import options

    learner = learner or _learner()
    g = p.add_argument_group(f"options of the learner {learner.name!r} ({learner.doc})" if learner.doc
                             else f"options of the learner {learner.name!r}")
    for f in _options(learner, skip):
        t = _field_type(learner.config, f)
        t = _bool if t is bool else t
        doc = learner.help.get(f.name, "")
        default = f.default if f.default is not dataclasses.MISSING else "?"
        g.add_argument("--" + options.flag(learner.config, f.name), dest=f.name, type=t, default=None,
                       help=doc if "(default:" in doc else f"{doc} (default: {default})".strip())


def given_options(args: argparse.Namespace, skip: set[str] = frozenset()) -> dict:
    """The config fields of the command's learner given on the command line (name -> value)."""
    learner = _learner(getattr(args, "learner", None))
    given = {f.name: getattr(args, f.name) for f in dataclasses.fields(learner.config)
             if f.name not in skip and getattr(args, f.name, None) is not None}
    if getattr(args, "resume", False):  # a resumed run keeps its own control step
        return given
    return {**_task_control_dt(given), **given}


def _task_control_dt(given: dict) -> dict:
    """``{"control_dt": the task's own step}`` (frame skip x timestep, Gymnasium's ``dt``) for a
    Gymnasium task given by ``--env`` without ``--control-dt``; nothing otherwise."""
    env = given.get("env")
    if env is None or "control_dt" in given:
        return {}
    from nmrl.tasks.gym_v5 import TASKS

    return {"control_dt": TASKS[env].frame_skip * TASKS[env].timestep} if env in TASKS else {}


def config_from_args(args: argparse.Namespace, skip: set[str] = frozenset()):
    """The learner's config from the options given, with the exploration process (``--exploration``
    and its parameters in seconds/Hz) applied by the learner (:func:`_with_exploration`)."""
    learner = _learner(getattr(args, "learner", None))
    given = given_options(args, skip)
    return _with_exploration(args, learner, learner.config(**given), set(given))


# ----------------------------------------------------------------------------- exploration processes

def _exploration_params() -> dict[str, tuple[type, str]]:
    """The exploration processes' parameters (name -> (type, help)) from nmrl.explore's
    ExplorationSpec (its ``cli_options``), but ``sigma`` (each learner's own ``--sigma``): one option
    ``--<name>`` each (``--period-s``, ``--corr-time-s``, ...), parsed into ``<name>``."""
    from nmrl import explore

    return {o.field: (o.type, o.help) for o in explore.cli_options() if o.field not in ("kind", "sigma")}


def add_exploration_options(p: argparse.ArgumentParser, learner) -> None:
    """The options of the exploration processes the learner takes (``Learner.explorations``)."""
    from nmrl import explore

    kinds = ", ".join(explore.KINDS)
    own = {f.name: f.default for f in dataclasses.fields(learner.config)}
    default = (f" (default: {own['exploration']})" if "exploration" in own
               else " (default: the paper's nm-periods with --l and --alpha)" if learner.name == "ac" else "")
    g = p.add_argument_group("exploration process (nmrl.explore; times in seconds, frequencies in Hz)")
    g.add_argument("--exploration", default=None, metavar="KIND",
                   help=f"the exploration noise process: {kinds}; the learner {learner.name!r} takes "
                        f"{', '.join(learner.explorations)}{default}")
    for name, (t, doc) in _exploration_params().items():
        g.add_argument("--" + name.replace("_", "-"), dest=name, type=t, default=None, metavar=name.upper(), help=doc)


def _with_exploration(args: argparse.Namespace, learner, cfg, given: set[str]):
    """``cfg`` with the process of ``--exploration`` and its parameters: a learner whose config holds
    them (fields of the same names, e.g. PPO's) has them already; another maps them onto its own
    fields (``Learner.exploration``, e.g. the actor-critic's l and alpha). The config as it is when
    none is given. ValueError naming a bad process, one the learner cannot use, or a parameter that
    contradicts another option."""
    from nmrl import explore

    fields = {f.name for f in dataclasses.fields(learner.config)}
    kind = None if "exploration" in fields else getattr(args, "exploration", None)
    params = {k: getattr(args, k) for k in explore.PARAMETERS
              if k not in fields and getattr(args, k, None) is not None}
    if kind is None and not params:
        return cfg
    if kind is not None and kind not in explore.KINDS:
        raise ValueError(f"--exploration={kind!r} is unknown: choose one of {', '.join(explore.KINDS)}")
    return learner.exploration(cfg, kind, params, frozenset(given))


def _fail(msg: str, status: int = _exits.BAD_INPUT) -> int:
    """Print the one line ``nmrl: error: MSG`` and return ``status`` (a disk failure's line through
    nmrl/runs/io_errors.py's ``report``, which keeps orbax's late tracebacks of it off stderr)."""
    line = f"nmrl: error: {msg}"
    if status == _exits.IO_FAILED:
        from nmrl.runs import io_errors

        io_errors.report(line)
    else:
        print(line, file=sys.stderr, flush=True)
    return status


def _failure(e: BaseException) -> int | None:
    """The one line and exit status of a failure that is not a bug (nmrl/runs/exits.py): another
    writer (6), the disk or file system (5), memory (7), a damaged metrics file (2); None: other."""
    from nmrl.runs import io_errors, jsonl, lock

    if isinstance(e, lock.Locked):
        return _fail(str(e), _exits.LOCKED)
    if isinstance(e, io_errors.IOFailure):
        return _fail(str(e), _exits.IO_FAILED)
    if isinstance(e, jsonl.Corrupt):
        return _fail(str(e))
    if "nmrl.runs.errors" in sys.modules:
        from nmrl.runs import errors

        if isinstance(e, errors.OutOfMemory):
            return _fail(str(e), _exits.OUT_OF_MEMORY)
    f = io_errors.find(e)
    if f is not None and (isinstance(e, OSError) or type(e).__name__ in ("CheckpointError", "CorruptCheckpoint")):
        return _fail(f"{f.line()}; what was saved before is intact: run the same command again once the cause "
                     f"is gone", _exits.IO_FAILED)
    return None


def _guard(what: str, out: str | None, resume: bool) -> "_signals.Guard":
    """The command's signal handling for its whole life (nmrl/runs/signals.py), installed before JAX
    is imported; a second signal exits at once naming what is intact: before the run's files are
    written (a fresh run), nothing; else the newest checkpoint."""
    def second(signum: int, moment: str) -> str:
        head = f"nmrl: stopped at once by a second signal {signum} while {moment}"
        written = out and any(os.path.exists(os.path.join(out, f)) for f in ("config.json", "sweep.json"))
        if not resume and not written and moment in ("starting", "compiling"):
            return f"{head}; nothing of the run was written"
        where = f" in {out}" if out else ""
        return (f"{head}; the newest checkpoint{where} is intact (saves are atomic); continue with: nmrl {what} "
                f"--resume --out {out}")

    return _signals.Guard(on_second=second).install()


def add_distributed_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("several processes (jax.distributed; nmrl/runs/distributed.py)")
    g.add_argument("--coordinator", default=None,
                   help="HOST:PORT of process 0's coordinator (every process gives the same), or 'auto' to let "
                        "JAX detect the cluster (SLURM, Open MPI); default: one process")
    g.add_argument("--num-processes", type=int, default=None, help="how many processes run this command")
    g.add_argument("--process-id", type=int, default=None, help="this process's id, 0..num-processes-1")
    g.add_argument("--dist-timeout", type=int, default=_launch.DEFAULT_TIMEOUT_S,
                   help="seconds a process waits for the others (to connect, at a barrier, a silent peer) "
                        f"before it exits with an error (default {_launch.DEFAULT_TIMEOUT_S})")


def _cluster(args: argparse.Namespace) -> "_launch.Cluster | None":
    if args.coordinator is None:
        for o in ("num_processes", "process_id"):
            if getattr(args, o) is not None:
                raise ValueError(f"--{o.replace('_', '-')} needs --coordinator (HOST:PORT or auto)")
        return None
    c = _launch.Cluster(args.coordinator, args.num_processes, args.process_id, args.dist_timeout)
    c.validate()
    return c


def _join(args: argparse.Namespace, cluster: "_launch.Cluster | None") -> int | None:
    """Several processes (``cluster``, from :func:`_cluster`): join the run before JAX computes anything,
    and check that every process was given the same command. Returns an exit status when that fails
    (nothing written), else None."""
    if cluster is None:
        return None
    from nmrl.runs import distributed

    try:
        distributed.initialize(cluster)
        guard = _signals.active()
        if guard is not None:  # jax.distributed took SIGTERM over (its preemption notice)
            guard.reclaim()
        distributed.agree("command line", distributed.fingerprint(args.argv))
    except distributed.DistributedError as e:
        return _fail(f"{e}; nothing was written")
    except distributed.PeerFailed as e:
        print(_launch.peer_failed_message(cluster.who(), str(e), None), file=sys.stderr)
        return _launch.PEER_FAILED
    return None


T = typing.TypeVar("T")


def _ready(args: argparse.Namespace, check: Callable[[], T]) -> tuple[T, int | None] | int:
    """The common prologue of ``train`` and ``sweep``: ``check()`` (the command's own argument checks,
    returning what the command needs), the device count and the cluster; then, with several
    processes, join the run (:func:`_join`). Returns ``(check(), devices)``, or the exit status when
    an argument is bad (the value named, status 2) or joining fails; nothing is written either way."""
    try:
        value = check()
        n_dev = _devices.parse(args.devices)
        cluster = _cluster(args)
    except (ValueError, TypeError) as e:
        return _fail(str(e))
    joined = _join(args, cluster)
    return joined if joined is not None else (value, n_dev)


def _is_process_zero(args: argparse.Namespace) -> bool:
    if getattr(args, "coordinator", None) is None:
        return True
    import jax

    return jax.process_index() == 0


def _not_a_bug(args: argparse.Namespace, e: Exception) -> int:
    """The exit status of an unexpected exception that is not a bug: another writer, the disk,
    memory, a damaged metrics file (:func:`_failure`) or, in a distributed run, a process gone
    (:func:`_peer_failure`); anything else is re-raised."""
    failed = _failure(e)
    if failed is not None:
        return failed
    peer = _peer_failure(args, e)
    if peer is None:
        raise e
    return peer


def _peer_failure(args: argparse.Namespace, e: BaseException) -> int | None:
    """The exit status for an exception that means another process of the run is gone (else None)."""
    if getattr(args, "coordinator", None) is None:
        return None
    from nmrl.runs import distributed

    if isinstance(e, distributed.PeerFailed) or distributed.is_peer_failure(e):
        print(_launch.peer_failed_message(_cluster(args).who(), str(e).splitlines()[0][:400], args.out),
              file=sys.stderr, flush=True)
        return _launch.PEER_FAILED
    return None


def cmd_train(args: argparse.Namespace) -> int:
    from nmrl.runs import checkpoint, driver as run, store

    def check() -> tuple[dict, object]:
        store.out_path(args.out)
        given, cfg = given_options(args), config_from_args(args)
        run.check_config(cfg)
        if args.step is not None and args.step < 0:
            raise ValueError(f"--step={args.step} is invalid: a checkpoint step is >= 0")
        return given, cfg

    ready = _ready(args, check)
    if isinstance(ready, int):
        return ready
    (given, cfg), n_dev = ready
    status = 0
    try:
        run.train(cfg, args.out, resume=args.resume, progress=not args.quiet, devices=n_dev,
                  given=given if args.resume else None, step=args.step)
    except run.Diverged as e:
        print(f"nmrl: {e}", file=sys.stderr)
        return _exits.DIVERGED
    except run.Stopped as e:
        status = e.exit_status
    except (run.RunError, checkpoint.CheckpointError) as e:
        failed = _failure(e)
        return failed if failed is not None else _fail(str(e))
    except Exception as e:  # noqa: BLE001 - the disk, another writer, memory; several processes: a peer gone
        return _not_a_bug(args, e)
    try:
        rows = store.read_metrics(args.out)  # the run's, not only this session's
    except Exception:  # noqa: BLE001 - nothing of the run was written (stopped before its first chunk)
        rows = []
    if rows and _is_process_zero(args):
        first, last = rows[0], rows[-1]
        print(json.dumps({"out": args.out, "step": last["step"], "trials": last["trials"],
                          "avg_reward_first_chunk": first["avg_reward"], "avg_reward": last["avg_reward"],
                          "forward_speed": last["forward_speed"]}))
    return status


def cmd_eval(args: argparse.Namespace) -> int:
    s = args.seconds
    if not (math.isfinite(s) and 0 < s <= MAX_EVAL_SECONDS):
        return _fail(f"--seconds={s!r} is invalid: must be a finite number of simulated seconds in "
                     f"(0, {MAX_EVAL_SECONDS:g}]")
    from nmrl.options import SEED_MAX

    if not 0 <= args.seed <= SEED_MAX:
        return _fail(f"--seed={args.seed} is invalid: must be an integer in [0, {SEED_MAX}]")
    if args.step is not None and args.step < 0:
        return _fail(f"--step={args.step} is invalid: a checkpoint step is >= 0")
    from nmrl.runs import checkpoint, io_errors, lock, store

    try:
        store.out_path(args.run, "RUN")
        if args.out is not None:
            store.out_path(args.out)
    except ValueError as e:
        return _fail(str(e))
    from nmrl.analysis import evaluate

    out_dir = args.out if args.out is not None else os.path.join(args.run, evaluate.EVAL_DIR)
    held = None
    try:
        if os.path.isdir(args.run) or args.out is not None:
            io_errors.check_writable(out_dir)  # before the rollouts: the pictures and eval.json must fit
            try:
                held = lock.hold(out_dir)  # one writer of the eval's outputs
            except OSError as e:
                raise io_errors.IOFailure(io_errors.find(e, out_dir) or io_errors.Failure(
                    e.errno or 0, out_dir, (e.strerror or str(e)).lower())) from None
        result = evaluate.evaluate(args.run, step=args.step, seconds=args.seconds, seed=args.seed,
                                   render=not args.no_render, out_dir=args.out,
                                   warn=lambda m: print(f"nmrl: warning: {m}", file=sys.stderr, flush=True))
    except Exception as e:  # noqa: BLE001
        failed = _failure(e)
        if failed is not None:
            return failed
        if isinstance(e, checkpoint.CheckpointError):
            return _fail(str(e))
        raise
    finally:
        if held is not None:
            held.release(remove_if_empty=True)
    print(json.dumps(result, indent=2))
    return 0


def cmd_sweep(args: argparse.Namespace) -> int:
    from nmrl.experiments import sweep
    from nmrl.runs import checkpoint, driver, store

    learner = _learner(args.learner)
    field = learner.sweep_field

    def check() -> "sweep.SweepSpec":
        store.out_path(args.out)
        if field is not None and getattr(args, "period_s", None) is not None:
            raise ValueError(f"give the swept period lengths as --{field}, not --period-s")
        base = config_from_args(args, skip=_sweep_skip(learner))
        if args.vary is not None:
            return _varied_spec(args, learner, base)
        values = getattr(args, field, None) if field is not None else None
        plain = learner.config(**given_options(args, skip=_sweep_skip(learner)))
        if field is not None and values is not None and getattr(plain, field) != getattr(base, field):
            raise ValueError(f"--exploration {args.exploration or ''} sets {field}={getattr(base, field)!r}, which "
                             f"the sweep varies (--{field} {' '.join(map(str, values))}): give one of the two")
        if field is not None and values is None and not args.resume:
            raise ValueError(f"--{field} is required (the values of the sweep, e.g. --l 1 2 3 5 10 15 20 30)")
        spec = sweep.SweepSpec(ls=tuple(values or (1,)) if field is not None else (None,), seeds=args.seeds,
                               base=base, first=tuple(args.first or ()), field=field, seed0=args.seed0)
        spec.validate()
        if args.checkpoint_every < 1:
            raise ValueError(f"--checkpoint-every={args.checkpoint_every} is invalid: must be >= 1")
        if args.group < 1:
            raise ValueError(f"--group={args.group} is invalid: points vmapped together must be >= 1")
        return spec

    ready = _ready(args, check)
    if isinstance(ready, int):
        return ready
    spec, n_dev = ready
    try:
        sweep.run_sweep(spec, args.out, resume=args.resume, progress=not args.quiet,
                        checkpoint_every=args.checkpoint_every, group=args.group, devices=n_dev,
                        given=given_options(args, skip=_sweep_skip(learner)) if args.resume else None)
    except driver.Stopped as e:
        if e.rows or args.resume:
            print(f"nmrl: sweep stopped by signal {e.signum}; every active point was saved. Continue with: nmrl "
                  f"sweep --resume --out {args.out}", file=sys.stderr)
        return e.exit_status
    except (sweep.SweepError, driver.RunError, checkpoint.CheckpointError, ValueError) as e:
        failed = _failure(e)
        return failed if failed is not None else _fail(str(e))
    except Exception as e:  # noqa: BLE001 - the disk, another writer, memory; several processes: a peer gone
        return _not_a_bug(args, e)
    return 0


def _sweep_skip(learner) -> set[str]:
    return {_SWEEP_SEED} | ({learner.sweep_field} if learner.sweep_field else set())


def _learner_option(p: argparse.ArgumentParser, learner) -> None:
    p.add_argument("--learner", default=learner.name, metavar="NAME",
                   help=f"the learner (nmrl/learners/): {', '.join(_learner_names())} (default: ac, the paper's "
                        f"actor-critic; with --resume: the run's own); its options are listed below")


def _learner_names() -> list[str]:
    from nmrl import learners

    return learners.names()


def _varied_spec(args: argparse.Namespace, learner, base):
    """The spec of ``nmrl sweep --vary FIELD V1 V2 ...``: one point per value of the traced field and seed."""
    from nmrl.experiments import sweep

    name, *raw = args.vary
    if name not in learner.hyper_fields:
        raise ValueError(f"--vary {name} is invalid: the learner {learner.name!r} varies one of its traced "
                         f"hyperparameters: {', '.join(learner.hyper_fields)}")
    if not raw:
        raise ValueError(f"--vary {name} needs values, e.g. --vary {name} V1 V2")
    f = next(f for f in dataclasses.fields(learner.config) if f.name == name)
    t = _field_type(learner.config, f)
    try:
        values = tuple(t(x) for x in raw)
    except ValueError:
        raise ValueError(f"--vary {name} {' '.join(raw)} is invalid: its values are {t.__name__} numbers") from None
    if getattr(args, name, None) is not None:
        raise ValueError(f"give {name} as --vary {name} or as --{name.replace('_', '-')}, not both")
    sf = learner.sweep_field
    if sf is not None and sf != name and getattr(args, sf, None) is not None:
        one = getattr(args, sf)
        if len(one) != 1:
            raise ValueError(f"--{sf} takes one value when --vary {name} is the swept field, got {one}")
        base = dataclasses.replace(base, **{sf: one[0]})
    first = tuple(t(x) for x in (args.first or ()))
    spec = sweep.SweepSpec(ls=values, seeds=args.seeds, base=base, first=first, field=name, seed0=args.seed0)
    spec.validate()
    return spec


def build_parser(learner=None) -> argparse.ArgumentParser:
    """The command line; ``train`` and ``sweep`` take the options of ``learner`` (default: ac)."""
    learner = learner or _learner()
    ap = _parser.OneLineParser(prog="nmrl", description=__doc__,
                               formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)

    p = sub.add_parser("train", help="train one run of a learner (default: the paper's actor-critic, Table II)")
    _learner_option(p, learner)
    add_config_options(p, learner=learner)
    if learner.explorations:
        add_exploration_options(p, learner)
    p.add_argument("--out", required=True, help="run directory (config, metrics.jsonl, checkpoints)")
    p.add_argument("--resume", action="store_true",
                   help="continue the run in --out from its newest checkpoint with its own config "
                        "(only --steps/--trials may change)")
    p.add_argument("--step", type=int, default=None,
                   help="with --resume: the checkpoint step to continue from (default: the newest)")
    p.add_argument("--devices", default=_devices.AUTO,
                   help="host (CPU) devices to split the work over: 'auto' = every core (default), 1 = off")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    add_distributed_options(p)
    p.set_defaults(func=cmd_train)

    field = learner.sweep_field
    p = sub.add_parser("sweep", help="points of a learner (the actor-critic: over l and seeds, Fig. 3) as one "
                                     "compiled program")
    _learner_option(p, learner)
    add_config_options(p, skip=_sweep_skip(learner), learner=learner)
    if learner.explorations:
        add_exploration_options(p, learner)
    if field is not None:
        t = _field_type(learner.config, next(f for f in dataclasses.fields(learner.config) if f.name == field))
        p.add_argument("--" + field.replace("_", "-"), dest=field, type=t, nargs="+", default=None,
                       help=f"the values of {field} (one point per value and seed), e.g. 1 2 3 5 10 15 20 30 "
                            f"(with --resume: the saved ones)")
    p.add_argument("--vary", nargs="+", default=None, metavar="FIELD_OR_VALUE",
                   help=f"--vary FIELD V1 V2 ...: sweep one traced hyperparameter of the learner "
                        f"({', '.join(learner.hyper_fields)}) instead" +
                        (f" of --{field}" if field else " of the seeds alone"))
    p.add_argument("--seeds", type=int, default=3, help="seeds per value (seed0..seed0+seeds-1)")
    p.add_argument("--seed0", type=int, default=0, help="the first seed (default 0)")
    p.add_argument("--checkpoint-every", type=int, default=1, help="checkpoint the points every K chunks")
    p.add_argument("--first", type=_field_type(learner.config, next(f for f in dataclasses.fields(learner.config)
                                                                    if f.name == field)) if field else int,
                   nargs="+", default=None,
                   help=f"{field or 'the'} values whose points (all seeds) run to the budget before the others start")
    p.add_argument("--group", type=int, default=1,
                   help="points vmapped together on one device (default 1: one after another)")
    p.add_argument("--devices", default=_devices.AUTO,
                   help="host (CPU) devices to split the work over: 'auto' = every core (default), 1 = off")
    p.add_argument("--out", required=True)
    p.add_argument("--resume", action="store_true")
    p.add_argument("--quiet", action="store_true")
    add_distributed_options(p)
    p.set_defaults(func=cmd_sweep)

    p = sub.add_parser("eval", help="restore a policy, roll it out, print JSON, render the gait")
    p.add_argument("run", help="run directory written by nmrl train or nmrl sweep (a point), or a published "
                   "policy directory (compact.npz)")
    p.add_argument("--step", type=int, default=None,
                   help="checkpoint step (default: the newest; a corrupted newest one is skipped with a warning)")
    p.add_argument("--seconds", type=float, default=10.0,
                   help=f"simulated seconds per rollout (at most {MAX_EVAL_SECONDS:g})")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--no-render", action="store_true", help="skip the strobe PNG and the GIF")
    p.add_argument("--out", default=None, metavar="DIR",
                   help="where eval.json, strobe.png and gait.gif go (default: RUN/eval)")
    p.set_defaults(func=cmd_eval)

    sub.add_parser("baseline", help="Brax PPO on the paper's robot: nmrl baseline --help "
                   "(nmrl/experiments/baseline_ppo.py)", add_help=False)
    sub.add_parser("study", help="the finer-delta study: nmrl study --help (nmrl/experiments/study.py)", add_help=False)
    return ap


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


def main(argv: list[str] | None = None) -> int:
    """Run the command ``argv``; None: the process's own arguments, ``main`` being the process's
    entry point (which alone may mute stderr after a disk failure's line, nmrl/runs/io_errors.py)."""
    if argv is None:
        from nmrl.runs import io_errors

        io_errors.mute_after_report = True
    argv = sys.argv[1:] if argv is None else list(argv)
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
    if early is not None:
        early.raise_if_stopped(_stopped_early)
    if argv[:1] in (["train"], ["sweep"]):
        try:
            _devices.configure(_devices.requested(argv))  # before JAX is imported
        except ValueError as e:
            return _fail(str(e))
    if argv[:1] == ["baseline"]:  # its own parser (nmrl/experiments/baseline_ppo.py); Brax is optional
        try:
            _devices.configure(_devices.requested(argv))  # before JAX is imported
        except ValueError as e:
            return _fail(str(e))
        from nmrl.experiments import baseline_ppo

        return baseline_ppo.main(argv[1:])
    if argv[:1] == ["study"]:  # its own parser (argparse's REMAINDER would not pass --help on)
        from nmrl.experiments import study

        return study.main(argv[1:])
    learner = None
    if argv[:1] in (["train"], ["sweep"]):
        try:
            learner = _learner(learner_name(argv))
        except ValueError as e:
            return _fail(str(e).replace("learner=", "--learner=", 1))
    if argv[:1] in (["train"], ["sweep"]) and os.environ.get(_launch.CHILD_ENV) != "1":
        watched = _watch(argv)
        if watched is not None:
            return watched
    args = build_parser(learner).parse_args(argv)
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
        cluster = _cluster(ns)
    except ValueError as e:
        return _fail(str(e))
    return _launch.supervise(argv, cluster, ns.out)


if __name__ == "__main__":
    sys.exit(main())
