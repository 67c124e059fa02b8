"""Several processes as one run: JAX's multi-process runtime (``jax.distributed``) for nmrl.

``nmrl train`` and ``nmrl sweep`` take ``--coordinator HOST:PORT --num-processes P --process-id I``
(or ``--coordinator auto``: JAX's own detection of the cluster, e.g. SLURM or Open MPI). Each of
the P processes runs the same command; together they hold the devices of every process
(``jax.devices()``) and run one program over them:

* ``train``: the N environments are split over all devices of all processes; the summed update
  (Table II summed over the environments with the paper's beta) is one ``psum`` across them,
  so a 2-process run equals a 1-process 2-device run to float rounding (tests/test_distributed.py).
* ``sweep``: the points are split over all devices; the chunk program has no communication at
  all. Between chunks the points' metrics (a few numbers each) are gathered to write them.

Only process 0 touches the run directory: it writes configs, metrics, results and checkpoints
(every process reads the run directory before anything is written, then they meet at a barrier).
Checkpoints hold plain host arrays, gathered from every process, in the format of a 1-process
run: any number of processes (1 included) resumes them.

Between two chunks the processes agree on one small vector (a signal received by any of them,
which points process 0 checkpoints), so a SIGTERM that reaches one process stops all of them after
the same chunk. A process that dies takes the others down: JAX's runtime aborts them
(nmrl.runs.launch turns that into a clear message), or a collective fails (:class:`PeerFailed`).

CPU collectives go through gloo (``jax_cpu_collectives_implementation``), set before the backend
starts. This module is imported only by code that already runs JAX.
"""

from __future__ import annotations

import hashlib
import os
import sys
from typing import Any

import jax
import numpy as np

from nmrl.runs.launch import AUTO, CONNECTED, DEFAULT_TIMEOUT_S, Cluster  # noqa: F401

_TIMEOUT_S = [DEFAULT_TIMEOUT_S]  # the run's --dist-timeout, set by initialize()


class DistributedError(Exception):
    """The processes of a distributed run cannot work together (message says why); nothing written."""


class PeerFailed(Exception):
    """A collective failed because another process of the run stopped or died."""


def initialize(cluster: Cluster) -> None:
    """Join the run (``jax.distributed.initialize``) before JAX computes anything.

    A coordinator that cannot be reached, or processes that never come, make JAX's runtime abort
    this process after ``timeout_s`` (nmrl.runs.launch reports it). Prints :data:`CONNECTED`.
    """
    cluster.validate()
    _TIMEOUT_S[0] = cluster.timeout_s
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    kw: dict[str, Any] = dict(initialization_timeout=cluster.timeout_s, heartbeat_timeout_seconds=cluster.timeout_s,
                              shutdown_timeout_seconds=cluster.timeout_s)
    if cluster.coordinator != AUTO:
        kw.update(coordinator_address=cluster.coordinator)
    if cluster.num_processes is not None:
        kw.update(num_processes=cluster.num_processes)
    if cluster.process_id is not None:
        kw.update(process_id=cluster.process_id)
    try:
        jax.distributed.initialize(**kw)
    except (ValueError, TypeError, RuntimeError) as e:  # auto-detection found no cluster, a bad value, ...
        raise DistributedError(f"jax.distributed.initialize failed: {e}") from e
    # Uncommitted values (MJX's model data, the initial states) go to this process's own first device
    # (JAX's default would be global device 0, which belongs to process 0).
    jax.config.update("jax_default_device", jax.local_devices()[0])
    print(f"{CONNECTED} (process {jax.process_index()} of {jax.process_count()}, pid {os.getpid()}, "
          f"{len(jax.local_devices())} local and {len(jax.devices())} global device(s))", file=sys.stderr, flush=True)


def leave() -> None:
    """Leave the run together with the others (``jax.distributed.shutdown``: a barrier of every
    process, so no process is aborted because another one left first). For an exit every process
    makes at the same point: the end, a signal, a refusal all of them made."""
    if jax.distributed.is_initialized():
        try:
            jax.distributed.shutdown()
        except Exception:  # noqa: BLE001 - a peer already gone: nothing left to wait for
            pass


def active() -> bool:
    """Whether this process is one of several (``jax.process_count() > 1``)."""
    return jax.process_count() > 1


def is_writer() -> bool:
    """Only process 0 writes the run directory."""
    return jax.process_index() == 0


def _client():
    from jax._src import distributed as _d

    return _d.global_state.client


def barrier_timeout_s() -> int:
    """How long a barrier waits: the processes may arrive minutes apart (one compiles while another
    finds the program in the compile cache; process 0 saves), so ``max(600, 5 * --dist-timeout)``.
    A peer that dies is noticed much sooner, by JAX's heartbeats (``--dist-timeout``)."""
    return max(600, 5 * _TIMEOUT_S[0])


def barrier(name: str, timeout_s: int | None = None) -> None:
    """Every process waits here until all have arrived (no-op in a 1-process run)."""
    if not active():
        return
    timeout_s = barrier_timeout_s() if timeout_s is None else timeout_s
    try:
        _client().wait_at_barrier(f"nmrl/{name}", 1000 * timeout_s)
    except Exception as e:  # noqa: BLE001 - XlaRuntimeError: timeout or a dead peer
        raise PeerFailed(f"not every process reached {name!r} within {timeout_s} s: {e}") from e


def agree(name: str, value: str, timeout_s: int | None = None) -> None:
    """DistributedError unless every process passes the same ``value`` (e.g. its command line).

    Each process publishes a digest of its value; every process compares all of them, so all
    refuse together, naming the processes that differ from process 0.
    """
    if not active():
        return
    timeout_s = _TIMEOUT_S[0] if timeout_s is None else timeout_s
    c = _client()
    me = hashlib.sha256(value.encode()).hexdigest()
    c.key_value_set(f"nmrl/agree/{name}/{jax.process_index()}", me + " " + value)
    got = {}
    for p in range(jax.process_count()):
        try:
            got[p] = c.blocking_key_value_get(f"nmrl/agree/{name}/{p}", 1000 * timeout_s)
        except Exception as e:  # noqa: BLE001
            raise PeerFailed(f"process {p} did not report its {name} within {timeout_s} s: {e}") from e
    barrier(f"agree-{name}", timeout_s)  # every process has every value before any of them leaves
    d0, v0 = got[0].split(" ", 1)
    bad = {p: g.split(" ", 1)[1] for p, g in got.items() if g.split(" ", 1)[0] != d0}
    if bad:
        lines = "; ".join(f"process {p}: {v!r}" for p, v in sorted(bad.items()))
        raise DistributedError(f"the processes were not started with the same {name}: process 0 has {v0!r}, {lines}; "
                               f"start every process with the same command (only --process-id differs)")


def host(tree: Any) -> Any:
    """Host (numpy) copies of a pytree of arrays that may span processes.

    A fully replicated array is read from this process's own copy; an array split over the
    processes is gathered from all of them (a collective: every process must call this at the
    same point). A 1-process run only copies to the host.
    """
    if not active():
        return jax.device_get(tree)
    from jax.experimental import multihost_utils

    def one(x):
        if not isinstance(x, jax.Array):
            return np.asarray(x)
        if x.is_fully_addressable:
            return np.asarray(x)
        if x.is_fully_replicated:
            return np.asarray(x.addressable_data(0))
        return np.asarray(multihost_utils.process_allgather(x, tiled=True))

    try:
        return jax.tree.map(one, tree)
    except Exception as e:  # noqa: BLE001 - gloo: "Connection closed by peer", ...
        raise PeerFailed(f"gathering the state from the other processes failed: {e}") from e


def exchange(vec: np.ndarray) -> np.ndarray:
    """Every process's int32 vector, stacked in process order (one small collective); 1 process: ``vec[None]``."""
    vec = np.asarray(vec, np.int32)
    if not active():
        return vec[None]
    from jax.experimental import multihost_utils

    try:
        return np.asarray(multihost_utils.process_allgather(vec)).reshape(jax.process_count(), -1)
    except Exception as e:  # noqa: BLE001
        raise PeerFailed(f"exchanging the chunk's decisions with the other processes failed: {e}") from e


def is_peer_failure(e: BaseException) -> bool:
    """Whether a JAX runtime error means another process is gone (a collective lost its peer)."""
    text = str(e)
    return any(s in text for s in ("Gloo", "gloo", "Connection closed by peer", "Connection reset by peer",
                                   "coordination service", "heartbeat"))


def fingerprint(argv: list[str]) -> str:
    """A command line without its ``--process-id`` (what every process of a run must share)."""
    out, skip = [], False
    for a in argv:
        if skip:
            skip = False
            continue
        if a == "--process-id":
            skip = True
            continue
        if a.startswith("--process-id="):
            continue
        out.append(a)
    return " ".join(out)
