"""The options of a run over several processes: ``--coordinator HOST:PORT --num-processes P
--process-id I`` (or ``--coordinator auto`` under SLURM/Open MPI), ``--dist-timeout``.

Every process runs the same command; each is watched by nmrl/runs/launch.py, which reports JAX's
aborts (an unreachable coordinator, a dead peer) as clear errors (nmrl/runs/distributed.py joins
the run). Nothing here imports JAX until a command asks which process it is.
"""

from __future__ import annotations

import argparse

from nmrl.runs import launch as _launch


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


def cluster_of(args: argparse.Namespace) -> "_launch.Cluster | None":
    """The processes of the command (None: one process); ValueError naming a bad option."""
    if args.coordinator is None:
        for o in ("num_processes", "process_id"):
            if getattr(args, o) is not None:
                raise ValueError(f"--{o.replace('_', '-')} needs --coordinator (HOST:PORT or auto)")
        return None
    c = _launch.Cluster(args.coordinator, args.num_processes, args.process_id, args.dist_timeout)
    c.validate()
    return c


def is_process_zero(args: argparse.Namespace) -> bool:
    """Whether this process reports for the run: the only one, or process 0 of several."""
    if getattr(args, "coordinator", None) is None:
        return True
    import jax

    return jax.process_index() == 0
