"""The exceptions of a training run: why it cannot start or continue, why it stopped, why a
checkpoint cannot be used.

:mod:`nmrl.runs.driver` re-exports the run's, :mod:`nmrl.runs.checkpoint` the checkpoints'; they sit
in a module of their own, without JAX, so that every part of the driver (preflight.py, resume.py,
layout.py, loop.py) and of the checkpoints raises them without importing the driver, and a command
turns each into its one line and exit status before JAX is imported (nmrl/runs/command.py,
nmrl/runs/exits.py).
"""

from __future__ import annotations


class RunError(Exception):
    """A run cannot start or continue (message says why); nothing was written."""


class Diverged(Exception):
    """Training diverged; the last good checkpoint is kept."""


class OutOfMemory(Exception):
    """The machine ran out of memory allocating the run (its sizes passed the estimate); nothing of
    the run is left."""


class Stopped(Exception):
    """SIGINT/SIGTERM stopped the run after the chunk in flight was saved; ``rows`` were written."""

    def __init__(self, signum: int, step: int, rows: list[dict]):
        super().__init__(f"stopped by signal {signum} at step {step}")
        self.signum, self.step, self.rows = signum, step, rows

    @property
    def exit_status(self) -> int:
        """The shell's convention for a process ended by a signal: 128 + the signal (130, 143)."""
        return 128 + self.signum


class CheckpointError(Exception):
    """A checkpoint cannot be written, found, read or used; the message names the path and why."""


class CorruptCheckpoint(CheckpointError):
    """The checkpoint's files cannot be read, are truncated, or do not match their digest."""


class ForeignCheckpoint(CheckpointError):
    """The checkpoint belongs to another run: its config or model differs from the run's."""
