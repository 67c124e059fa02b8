"""SIGINT/SIGTERM at any moment of a command: one clean stop, never an exception inside XLA.

Python runs a signal handler only between two bytecodes of the main thread. While XLA compiles
(tens of seconds) or a chunk runs, the main thread is inside C++, so a Ctrl-C is acted on only when
that call returns; Python's default handler then raises KeyboardInterrupt at whatever Python line
comes next -- inside JAX's tracing or lowering, between two files of a save -- and an exit from
there can crash in the runtime's teardown (a segfault), after a message meant for another moment.

:class:`Guard` replaces that for the life of a command:

* the Python handlers only record the signal (nothing is raised); the command checks
  :attr:`Guard.signal` where stopping is safe: after the compile (nothing of the run written yet:
  :meth:`Guard.raise_if_stopped`), after each chunk's saves (the driver's loop), after a save;
* a watcher thread reads the signal numbers C's handler writes to a pipe (``signal.set_wakeup_fd``),
  so it sees a signal at once even while the main thread is inside C++: it prints the message that
  fits the :attr:`Guard.moment` (compiling, training, saving, ...) and, on a second signal, stops the
  process at once with ``os._exit(128 + signal)`` -- no Python teardown, no exception in XLA; what
  is on disk stays consistent (config and checkpoints are replaced atomically, a partial metrics row
  is dropped on resume: nmrl/runs/jsonl.py);
* the exit status is the shell's ``128 + signal``: 130 for SIGINT, 143 for SIGTERM.

Only the main thread may install it (``signal.signal``); :meth:`Guard.restore` puts the previous
handlers and wakeup descriptor back.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from typing import Callable

SIGNALS = (signal.SIGINT, signal.SIGTERM)

#: moment -> what a first signal does then (printed at once)
MOMENTS = {
    "starting": "the command stops before anything of the run is written",
    "compiling": "the command stops when the compile returns, before anything of the run is written",
    "training": "stopping after the chunk in flight is saved",
    "saving": "stopping once the save in flight is complete",
    "finishing": "stopping once the results in flight are written",
}


_ACTIVE: list = [None]  # the installed Guard (the command's), else None


def active() -> "Guard | None":
    """The Guard installed now (a command installs one for its whole life; the driver's chunk loop
    uses it, or installs its own when called as a library)."""
    return _ACTIVE[0]


class Interrupted(Exception):
    """A signal stopped the command at a safe point (``signum``; ``moment`` names where)."""

    def __init__(self, signum: int, moment: str, message: str = ""):
        super().__init__(message or f"stopped by signal {signum} while {moment}")
        self.signum, self.moment = signum, moment

    @property
    def exit_status(self) -> int:
        return 128 + self.signum


class Guard:
    """The signal handling of one command (see the module docstring); a context manager.

    ``on_second`` gives the line printed before the immediate exit of a second signal (default: one
    naming the moment); ``write`` prints a line (default: stderr)."""

    def __init__(self, on_second: Callable[[int, str], str] | None = None,
                 write: Callable[[str], None] | None = None):
        self.signal: int | None = None
        self.moment = "starting"
        self.count = 0
        self._printed = False
        self._lock = threading.Lock()
        self._on_second = on_second
        self._write = write
        self._old: dict = {}
        self._old_fd = -1
        self._pipe: tuple[int, int] | None = None
        self._thread: threading.Thread | None = None
        self._outer: Guard | None = None
        #: called (best effort, from the watcher thread) just before a second signal's immediate exit
        self.on_exit: list[Callable[[], None]] = []

    # ---------------------------------------------------------------- messages
    def _say(self, line: str) -> None:
        if self._write is not None:
            self._write(line)
            return
        try:
            sys.stderr.write(line + "\n")
            sys.stderr.flush()
        except Exception:  # noqa: BLE001 - stderr closed: the exit status still tells
            pass

    def first_message(self, signum: int) -> str:
        return f"\nsignal {signum}: {MOMENTS.get(self.moment, 'stopping at the next safe point')} (again to stop now)"

    def second_message(self, signum: int) -> str:
        if self._on_second is not None:
            return self._on_second(signum, self.moment)
        return (f"nmrl: stopped at once by a second signal {signum} while {self.moment}; files are replaced "
                f"atomically, so what was saved before is intact")

    # ---------------------------------------------------------------- delivery
    def _note(self, signum: int) -> None:
        """Record ``signum`` and print the first signal's message (once, whoever sees it first)."""
        with self._lock:
            if self.signal is None:
                self.signal = signum
            if not self._printed:
                self._printed = True
                self._say(self.first_message(signum))

    def _got(self, signum: int) -> None:
        """One delivered signal, counted once (by the watcher thread; by the Python handler when
        there is no watcher). A second one stops the process at once."""
        self._note(signum)
        with self._lock:
            self.count += 1
            n = self.count
        if n >= 2:
            self._say(self.second_message(signum))
            for fn in list(self.on_exit):  # e.g. remove a directory made for a run not yet written
                try:
                    fn()
                except Exception:  # noqa: BLE001 - exiting anyway
                    pass
            os._exit(128 + signum)

    def _handler(self, signum, _frame) -> None:
        if self._thread is None:  # no watcher (no pipe): count here, between bytecodes
            self._got(signum)
        else:  # the watcher counts; record it here too, so a check right after sees it
            self._note(signum)

    def _watch(self) -> None:
        r = self._pipe[0]
        while True:
            try:
                data = os.read(r, 64)
            except OSError:
                return
            if not data:
                return
            for b in data:
                if b in (int(s) for s in SIGNALS):
                    self._got(b)

    # ---------------------------------------------------------------- install / restore
    def install(self) -> "Guard":
        """Install the handlers and the watcher (main thread only); :func:`active` returns it until
        :meth:`restore`."""
        self._old = {s: signal.signal(s, self._handler) for s in SIGNALS}
        self._outer = _ACTIVE[0]
        _ACTIVE[0] = self
        try:
            r, w = os.pipe()
            os.set_blocking(w, False)
            self._old_fd = signal.set_wakeup_fd(w, warn_on_full_buffer=False)
            self._pipe = (r, w)
            self._thread = threading.Thread(target=self._watch, name="nmrl-signals", daemon=True)
            self._thread.start()
        except (OSError, ValueError):  # no pipe: the Python handler acts (between bytecodes)
            self._pipe, self._thread = None, None
        return self

    def reclaim(self) -> None:
        """Install the handlers again after a library took the signals over: ``jax.distributed``
        installs a C handler for SIGTERM (its preemption notice), which would swallow the signal
        this guard is to see."""
        if self._old:
            for s in SIGNALS:
                signal.signal(s, self._handler)

    def restore(self) -> None:
        """Put back the handlers and wakeup descriptor that were there before :meth:`install`."""
        if self._pipe is not None:
            signal.set_wakeup_fd(self._old_fd)
            os.close(self._pipe[1])  # the watcher's read returns b"" and it ends
            if self._thread is not None:
                self._thread.join(timeout=5)
            os.close(self._pipe[0])
            self._pipe, self._thread = None, None
        for s, h in self._old.items():
            signal.signal(s, h)
        self._old = {}
        if _ACTIVE[0] is self:
            _ACTIVE[0] = self._outer

    def __enter__(self) -> "Guard":
        return self.install()

    def __exit__(self, *exc) -> None:
        self.restore()

    # ---------------------------------------------------------------- the command's side
    def at(self, moment: str) -> None:
        """The command enters ``moment`` (a key of :data:`MOMENTS`): a first signal says what it does then."""
        self.moment = moment

    def raise_if_stopped(self, message: Callable[[int], str] | None = None) -> None:
        """Raise :class:`Interrupted` when a signal came (``message(signum)`` its text)."""
        if self.signal is not None:
            raise Interrupted(self.signal, self.moment, message(self.signal) if message else "")
