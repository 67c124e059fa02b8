"""The exceptions of a training run: why it cannot start or continue, why it stopped.

:mod:`nmrl.runs.driver` re-exports them; they sit in a module of their own so that every part of
the driver (preflight.py, resume.py, layout.py, loop.py) raises them without importing the driver.
A command turns each into its one line and exit status (nmrl/runs/command.py, nmrl/runs/exits.py).
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
