"""The commands ``nmrl train``, ``nmrl sweep`` and ``nmrl eval``, each ``cmd_*(args) -> exit status``.

``train`` and ``sweep`` share their prologue (:func:`ready`): the command's own argument checks,
the device count and the cluster, then, with several processes, joining the run; a bad value exits
with status 2 and a message that names it, before anything is written. Each command ends through
nmrl/cli/failures.py (the exit statuses of nmrl/runs/exits.py). The learner and JAX are imported
only here, after nmrl.runs.devices.configure has set the host device count (nmrl.cli.main).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import pathlib
import sys
import typing
from collections.abc import Callable

from nmrl.cli.cluster_options import cluster_of, is_process_zero
from nmrl.cli.config_options import config_from_args, field_type, get_learner, given_options
from nmrl.cli.failures import exit_status, fail
from nmrl.runs import devices as _devices
from nmrl.runs import exits as _exits
from nmrl.runs import launch as _launch
from nmrl.runs import signals as _signals

_SWEEP_SEED = "seed"  # ``nmrl sweep`` gives --seeds (a count) and the learner's sweep_field as a list

T = typing.TypeVar("T")


def join(args: argparse.Namespace, cluster: "_launch.Cluster | None") -> int | None:
    """Several processes (``cluster``, nmrl/cli/cluster_options.py): join the run before JAX computes
    anything, and check that every process was given the same command. Returns an exit status when
    that fails (nothing written), else None."""
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
        return fail(f"{e}; nothing was written")
    except distributed.PeerFailed as e:
        print(_launch.peer_failed_message(cluster.who(), str(e), None), file=sys.stderr)
        return _launch.PEER_FAILED
    return None


def ready(args: argparse.Namespace, check: Callable[[], T]) -> tuple[T, int | None] | int:
    """The common prologue of ``train`` and ``sweep``: the grace of the command's signal guard
    (``--grace-s``, ``NMRL_GRACE_S``: nmrl/runs/signals.py), ``check()`` (the command's own argument
    checks, returning what the command needs), the device count and the cluster; then, with several
    processes, join the run (:func:`join`). Returns ``(check(), devices)``, or the exit status when
    an argument is bad (the value named, status 2) or joining fails; nothing is written either way."""
    try:
        grace_s = _signals.grace_of(getattr(args, "grace_s", None))
        value = check()
        n_dev = _devices.parse(args.devices)
        cluster = cluster_of(args)
    except (ValueError, TypeError) as e:
        return fail(str(e))
    guard = _signals.active()
    if guard is not None:
        guard.grace_s = grace_s
        guard.show_setup = not getattr(args, "quiet", False)
        guard.stop_setup()  # a signal during the checks (one process): nothing is written
    joined = join(args, cluster)
    return joined if joined is not None else (value, n_dev)


def cmd_train(args: argparse.Namespace) -> int:
    from nmrl.runs import checkpoint, driver as run, errors, preflight, store

    def check() -> tuple[dict, object]:
        store.out_path(args.out)
        given, cfg = given_options(args), config_from_args(args)
        preflight.check_config(cfg)
        if not args.resume:
            check_iteration_budget(cfg)
        if args.step is not None and args.step < 0:
            raise ValueError(f"--step={args.step} is invalid: a checkpoint step is >= 0")
        return given, cfg

    prologue = ready(args, check)
    if isinstance(prologue, int):
        return prologue
    (given, cfg), n_dev = prologue
    status = 0
    try:
        run.train(cfg, args.out, resume=args.resume, progress=not args.quiet, devices=n_dev,
                  given=given if args.resume else None, step=args.step)
    except errors.Diverged as e:
        print(f"nmrl: {e}", file=sys.stderr)
        return _exits.DIVERGED
    except errors.Stopped as e:
        status = e.exit_status
    except Exception as e:  # noqa: BLE001 - bad input, the disk, another writer, memory; several processes: a peer gone
        return exit_status(args, e, (errors.RunError, checkpoint.CheckpointError))
    try:
        rows = store.read_metrics(args.out)  # the run's, not only this session's
    except Exception:  # noqa: BLE001 - nothing of the run was written (stopped before its first chunk)
        rows = []
    if rows and is_process_zero(args):
        first, last = rows[0], rows[-1]
        print(json.dumps({"out": args.out, "step": last["step"], "trials": last["trials"],
                          "avg_reward_first_chunk": first["avg_reward"], "avg_reward": last["avg_reward"],
                          "forward_speed": last["forward_speed"]}))
    return status


def check_iteration_budget(cfg) -> None:
    """A learner that learns in whole iterations (PPO: ``iteration_steps`` control steps per
    environment) refuses a budget below one: ValueError naming the iteration's size and the options
    that make it smaller."""
    it = getattr(cfg, "iteration_steps", None)
    if it is None or cfg.budget.steps is None or cfg.budget.steps >= it:
        return
    raise ValueError(f"--steps {cfg.budget.steps} is below one iteration of {it} control steps per environment (batch "
                     f"{cfg.batch_size} x {cfg.num_minibatches} minibatches / {cfg.budget.num_envs} environments = "
                     f"{cfg.unrolls_per_env} unrolls of {cfg.unroll_length} steps): give --steps {it} or more, or a "
                     f"smaller iteration with --batch-size, --num-minibatches or --unroll-s")


def cmd_eval(args: argparse.Namespace) -> int:
    from nmrl.options import MAX_EVAL_SECONDS

    s = args.seconds
    if not (math.isfinite(s) and 0 < s <= MAX_EVAL_SECONDS):
        return fail(f"--seconds={s!r} is invalid: must be a finite number of simulated seconds in "
                             f"(0, {MAX_EVAL_SECONDS:g}]")
    from nmrl import options

    try:
        options.check_seed(args.seed, "--seed")
    except ValueError as e:
        return fail(str(e))
    if args.step is not None and args.step < 0:
        return fail(f"--step={args.step} is invalid: a checkpoint step is >= 0")
    from nmrl.runs import checkpoint, io_errors, lock, store

    try:
        store.out_path(args.run, "RUN")
        if args.out is not None:
            store.out_path(args.out)
    except ValueError as e:
        return fail(str(e))
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
    except Exception as e:  # noqa: BLE001 - a bad checkpoint, the disk, another writer, memory
        return exit_status(args, e, (checkpoint.CheckpointError,))
    finally:
        if held is not None:
            held.release(remove_if_empty=True)
    print(json.dumps(result, indent=2))
    return 0


def cmd_sweep(args: argparse.Namespace) -> int:
    from nmrl.experiments import sweep
    from nmrl import options
    from nmrl.runs import checkpoint, errors, store

    learner = get_learner(args.learner)
    field = learner.sweep_field

    def check() -> "sweep.SweepSpec":
        spec = points()
        if not args.resume:
            check_iteration_budget(spec.base.resolved())
        if args.checkpoint_every < 1:
            raise ValueError(f"--checkpoint-every={args.checkpoint_every} is invalid: must be >= 1")
        if args.group < 1:
            raise ValueError(f"--group={args.group} is invalid: points vmapped together must be >= 1")
        return spec

    def points() -> "sweep.SweepSpec":  # the points: listed (--points), a traced field (--vary), or l x seeds
        store.out_path(args.out)
        if field is not None and getattr(args, "period_s", None) is not None:
            raise ValueError(f"give the swept period lengths as --{field}, not --period-s")
        base = config_from_args(args, skip=sweep_skip(learner))
        if args.points is not None:
            return listed_spec(args, learner, base)
        if args.vary is not None:
            return varied_spec(args, learner, base)
        values = getattr(args, field, None) if field is not None else None
        plain = options.build(learner.config, **given_options(args, skip=sweep_skip(learner)))
        if field is not None and values is not None and options.value(plain, field) != options.value(base, field):
            raise ValueError(f"--exploration {args.exploration or ''} sets {field}={options.value(base, field)!r}, "
                             f"which the sweep varies (--{field} {' '.join(map(str, values))}): give one of the two")
        if field is not None and values is None and not args.resume:
            raise ValueError(f"--{field} is required (the values of the sweep, e.g. --l 1 2 3 5 10 15 20 30)")
        spec = sweep.SweepSpec(ls=tuple(values or (1,)) if field is not None else (None,), seeds=args.seeds,
                               base=base, first=tuple(args.first or ()), field=field, seed0=args.seed0)
        spec.validate()
        return spec

    prologue = ready(args, check)
    if isinstance(prologue, int):
        return prologue
    spec, n_dev = prologue
    try:
        sweep.run_sweep(spec, args.out, resume=args.resume, progress=not args.quiet,
                        checkpoint_every=args.checkpoint_every, group=args.group, devices=n_dev,
                        given=given_options(args, skip=sweep_skip(learner)) if args.resume else None)
    except errors.Stopped as e:
        if e.rows or args.resume:
            print(f"nmrl: sweep stopped by signal {e.signum}; every active point was saved. Continue with: nmrl "
                  f"sweep --resume --out {args.out}", file=sys.stderr)
        return e.exit_status
    except Exception as e:  # noqa: BLE001 - bad input, the disk, another writer, memory; several processes: a peer gone
        return exit_status(args, e, (sweep.SweepError, errors.RunError, checkpoint.CheckpointError, ValueError))
    if is_process_zero(args):
        out = pathlib.Path(args.out)
        wrote = [str(out / f) for f in (sweep.RESULTS_FILE, "fig3.png") if (out / f).is_file()]
        if wrote:
            print(f"sweep: wrote {' and '.join(wrote)}; each point's run is in {out / 'points'}", file=sys.stderr)
    return 0


def sweep_skip(learner) -> set[str]:
    """The config fields that are not options of ``nmrl sweep`` (the seed, the swept field)."""
    return {_SWEEP_SEED} | ({learner.sweep_field} if learner.sweep_field else set())


def listed_spec(args: argparse.Namespace, learner, base):
    """The spec of ``nmrl sweep --points FILE``: the points the file lists (nmrl/cli/points_file.py),
    each its own seed; the options that make points otherwise are refused beside it."""
    from nmrl import options
    from nmrl.cli.points_file import read_points
    from nmrl.experiments import sweep

    argv = getattr(args, "argv", None) or []
    other = [o for o in ("--resume", "--vary", "--first", "--seeds", "--seed0",
                         *(["--" + learner.sweep_field] if learner.sweep_field else []))
             if any(a == o or a.startswith(o + "=") for a in argv)]
    if other:
        raise ValueError(f"--points lists every point (its seed among its fields): give it without {', '.join(other)}"
                         + (" (a resume continues the saved points)" if "--resume" in other else ""))
    overrides = read_points(args.points, learner.config)
    given = {n: getattr(args, n) for n in options.leaves(learner.config) if getattr(args, n, None) is not None}
    both = [(p["name"], k, p[k]) for p in overrides for k in p
            if k in given and k not in ("name", "seed", *sweep.BUDGET_FIELDS)]  # the budget: its own message
    if both:
        name, k, v = both[0]
        raise ValueError(f"--{k.replace('_', '-')} {given[k]!r} is given and the points file sets {k} too (point "
                         f"{name!r}: {v!r}): give each field in one place, the command line (every point) or "
                         f"the file")
    spec = sweep.SweepSpec(ls=(None,), seeds=1, base=base, field=None, overrides=overrides)
    spec.validate()
    return spec


def varied_spec(args: argparse.Namespace, learner, base):
    """The spec of ``nmrl sweep --vary FIELD V1 V2 ...``: one point per value of the traced field and seed."""
    from nmrl import options
    from nmrl.experiments import sweep

    name, *raw = args.vary
    if name not in learner.hyper_fields:
        raise ValueError(f"--vary {name} is invalid: the learner {learner.name!r} varies one of its traced "
                         f"hyperparameters: {', '.join(learner.hyper_fields)}")
    if not raw:
        raise ValueError(f"--vary {name} needs values, e.g. --vary {name} V1 V2")
    t = field_type(learner.config, name)
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
        base = options.replace(base, **{sf: one[0]})
    first = tuple(t(x) for x in (args.first or ()))
    spec = sweep.SweepSpec(ls=values, seeds=args.seeds, base=base, first=first, field=name, seed0=args.seed0)
    spec.validate()
    return spec
