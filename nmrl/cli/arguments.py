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
was saved, ``--resume`` continues it; when the chunk is not saved within ``--grace-s`` seconds
(``NMRL_GRACE_S``, default 25), with the last saved chunk kept; or before the first chunk, nothing
of the run written).

Several processes (``--coordinator HOST:PORT --num-processes P --process-id I``, or
``--coordinator auto`` under SLURM/Open MPI): every process runs the same command; each is watched
by nmrl/runs/launch.py, which reports JAX's aborts (an unreachable coordinator, a dead peer) as
clear errors.

The benchmarks are not a command: they live in the checkout (``python -m benchmarks``, which
writes its measurements into results/benchmarks/), not in the installed package.
"""

from __future__ import annotations

import argparse

from nmrl.cli.cluster_options import add_distributed_options
from nmrl.cli.commands import cmd_eval, cmd_sweep, cmd_train, sweep_skip
from nmrl.cli.config_options import add_config_options, field_type, get_learner, learner_names
from nmrl.cli.exploration_options import add_exploration_options
from nmrl.runs import devices as _devices
from nmrl.runs.parser import OneLineParser, add_grace_option


def _learner_option(p: argparse.ArgumentParser, learner) -> None:
    p.add_argument("--learner", default=learner.name, metavar="NAME",
                   help=f"the learner (nmrl/learners/): {', '.join(learner_names())} (default: ac, the paper's "
                        f"actor-critic; with --resume: the run's own); its options are listed below")


def _devices_option(p: argparse.ArgumentParser) -> None:
    """``--devices``: how many host devices ``train`` and ``sweep`` split their work over (nmrl/runs/devices.py)."""
    p.add_argument("--devices", default=_devices.AUTO,
                   help="host (CPU) devices to split the work over: 'auto' = every core (default), 1 = off")


def version() -> str:
    """The installed package's version (pyproject.toml)."""
    from importlib import metadata

    try:
        return metadata.version("nmrl")
    except metadata.PackageNotFoundError:
        return "unknown (not installed)"


def build_parser(learner=None) -> argparse.ArgumentParser:
    """The command line; ``train`` and ``sweep`` take the options of ``learner`` (default: ac)."""
    from nmrl.options import MAX_EVAL_SECONDS

    learner = learner or get_learner()
    ap = OneLineParser(prog="nmrl", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--version", action="version", version=f"nmrl {version()}")
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
    _devices_option(p)
    p.add_argument("--quiet", action="store_true", help="no progress display")
    add_grace_option(p)
    add_distributed_options(p)
    p.set_defaults(func=cmd_train)

    field = learner.sweep_field
    p = sub.add_parser("sweep", help="points of a learner (the actor-critic: over l and seeds, Fig. 3) as one "
                                     "compiled program")
    _learner_option(p, learner)
    add_config_options(p, skip=sweep_skip(learner), learner=learner)
    if learner.explorations:
        add_exploration_options(p, learner)
    if field is not None:
        t = field_type(learner.config, field)
        p.add_argument("--" + field.replace("_", "-"), dest=field, type=t, nargs="+", default=None,
                       help=f"the values of {field} (one point per value and seed), e.g. 1 2 3 5 10 15 20 30 "
                            f"(with --resume: the saved ones)")
    p.add_argument("--vary", nargs="+", default=None, metavar="FIELD_OR_VALUE",
                   help=f"--vary FIELD V1 V2 ...: sweep one traced hyperparameter of the learner "
                        f"({', '.join(learner.hyper_fields)}) instead" +
                        (f" of --{field}" if field else " of the seeds alone"))
    p.add_argument("--points", default=None, metavar="FILE",
                   help="a JSON list of points instead: [{\"name\": ..., FIELD: VALUE, ...}, ...], each setting "
                        "fields of the config the options give (the points differing only in traced "
                        "hyperparameters and the seed; nmrl/cli/points_file.py)")
    p.add_argument("--seeds", type=int, default=3, help="seeds per value (seed0..seed0+seeds-1)")
    p.add_argument("--seed0", type=int, default=0, help="the first seed (default 0)")
    p.add_argument("--checkpoint-every", type=int, default=1, help="checkpoint the points every K chunks")
    p.add_argument("--first", type=field_type(learner.config, field) if field else int,
                   nargs="+", default=None,
                   help=f"{field or 'the'} values whose points (all seeds) run to the budget before the others start")
    p.add_argument("--group", type=int, default=1,
                   help="points vmapped together on one device (default 1: one after another)")
    _devices_option(p)
    p.add_argument("--out", required=True)
    p.add_argument("--resume", action="store_true")
    p.add_argument("--quiet", action="store_true")
    add_grace_option(p)
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
