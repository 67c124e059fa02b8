"""SIGINT/SIGTERM at any moment of a command: one clean stop, never an exception inside XLA.

Python runs a signal handler only between two bytecodes of the main thread. While XLA compiles
(tens of seconds) or a chunk runs, the main thread is inside C++, so a Ctrl-C is acted on only when
that call returns; Python's default handler then raises KeyboardInterrupt at whatever Python line
comes next -- inside JAX's tracing or lowering, between two files of a save -- and an exit from
there can crash in the runtime's teardown (a segfault), after a message meant for another moment.

:class:`Guard` replaces that for the life of a command:

* the Python handlers only record the signal (nothing is raised); the command checks
  :attr:`Guard.signal` where stopping is safe: during set-up, between the steps of its loops over
  points (:func:`setting_up`, :func:`stop_setup`: nothing of the run written yet; a long set-up
  also says how far it is), after the compile (:meth:`Guard.raise_if_stopped`), after each chunk's
  saves (the driver's loop), after a save;
* a watcher thread reads the signal numbers C's handler writes to a pipe (``signal.set_wakeup_fd``),
  so it sees a signal at once even while the main thread is inside C++: it prints the message that
  fits the :attr:`Guard.moment` (compiling, training, saving, ...) and, on a second signal, stops the
  process at once with ``os._exit(128 + signal)`` -- no Python teardown, no exception in XLA; what
  is on disk stays consistent (config and checkpoints are replaced atomically, a partial metrics row
  is dropped on resume: nmrl/runs/jsonl.py);
* a supervisor's grace (:attr:`Guard.grace_s`, ``--grace-s`` or ``NMRL_GRACE_S``: :func:`grace_of`):
  SLURM and most schedulers send SIGTERM and, a fixed time later, SIGKILL (KillWait, 30 s by
  default), so waiting for a long chunk would lose it all to the SIGKILL with no clean stop. When
  the first signal came during training and the chunk in flight (:meth:`Guard.chunk`) is still
  computing at the grace's end, the process stops at once (``os._exit``) with the last completed
  chunk's checkpoint on disk; what is written is never cut: a chunk that has returned goes on to
  its clean stop, and a grace that runs out during a save ends the process when that save is
  complete;
* the exit status is the shell's ``128 + signal``: 130 for SIGINT, 143 for SIGTERM.

Only the main thread may install it (``signal.signal``); :meth:`Guard.restore` puts the previous
handlers and wakeup descriptor back.
"""

from __future__ import annotations

import contextlib
import math
import os
import signal
import sys
import threading
import time
from typing import Callable, Iterable, Iterator, Mapping, TypeVar

SIGNALS = (signal.SIGINT, signal.SIGTERM)
T = TypeVar("T")

#: the environment variable a batch script sets the grace with (``--grace-s`` wins over it)
GRACE_ENV = "NMRL_GRACE_S"
#: seconds between a first signal during training and the stop that keeps the last saved chunk:
#: 25 s fits inside SLURM's default KillWait of 30 s (SIGTERM, then SIGKILL 30 s later) with 5 s
#: left for the process to exit
DEFAULT_GRACE_S = 25.0
#: the moments during which a grace that ran out stops the process at once (a chunk in flight)
GRACE_MOMENTS = ("training",)
#: a set-up that has taken this long says how far it is, at most once per this many seconds
SETUP_EVERY_S = 5.0

#: moment -> what a first signal does then (printed at once)
MOMENTS = {
    "starting": "the command stops before anything of the run is written",
    "compiling": "the command stops when the compile returns, before anything of the run is written",
    "training": "stopping after the chunk in flight is saved",
    "saving": "stopping once the save in flight is complete",
    "finishing": "stopping once the results in flight are written",
}


_ACTIVE: list = [None]  # the installed Guard (the command's), else None


def grace_of(option: str | float | None, environ: Mapping[str, str] | None = None) -> float:
    """The grace in seconds: ``option`` (``--grace-s``) when given, else :data:`GRACE_ENV` from
    ``environ`` (default: the process's), else :data:`DEFAULT_GRACE_S`. A value that is not a
    positive finite number raises ValueError, one line naming it and what is allowed."""
    environ = os.environ if environ is None else environ
    if option is not None:
        where, raw = "--grace-s", option
    elif environ.get(GRACE_ENV, "").strip():
        where, raw = GRACE_ENV, environ[GRACE_ENV]
    else:
        return DEFAULT_GRACE_S
    try:
        value = float(raw)
    except (TypeError, ValueError):
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{where}={str(raw)!r} is invalid: the grace is a positive, finite number of seconds (the "
                         f"time a first SIGTERM/SIGINT leaves the chunk in flight before the run stops with its "
                         f"last saved chunk; default {DEFAULT_GRACE_S:g})")
    return value


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
    naming the moment); ``on_grace(signum, grace_s)`` the line printed when the grace runs out;
    ``write`` prints a line (default: stderr)."""

    def __init__(self, on_second: Callable[[int, str], str] | None = None,
                 write: Callable[[str], None] | None = None,
                 on_grace: Callable[[int, float], str] | None = None):
        #: the grace in seconds (module docstring); None: a first signal waits for the chunk in flight
        self.grace_s: float | None = None
        self._on_grace = on_grace
        self._since: float | None = None  # time.monotonic() of the first signal
        self._expired = False  # the grace ran out during a save: stop when it is complete
        self._in_chunk = False  # a chunk is computing (:meth:`chunk`): what a grace that ran out cuts
        self._grace_thread: threading.Thread | None = None
        #: one process (not one of a distributed run's, which stop together at agreed points): a
        #: signal during set-up stops the command there (:meth:`stop_setup`)
        self.alone = True
        #: print a line at most every :data:`SETUP_EVERY_S` s during a long set-up (:func:`setting_up`)
        self.show_setup = False
        self._t0 = time.monotonic()
        self._last_setup_line: float | None = None
        self.signal: int | None = None
        self.moment = "starting"
        self.count = 0
        self._printed = False
        self._lock = threading.RLock()  # the Python handler may run while the main thread holds it
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
        what = MOMENTS.get(self.moment, "stopping at the next safe point")
        if self.grace_s is not None and self.moment in GRACE_MOMENTS:
            what += f", or in {self.grace_s:g} s with the last saved chunk kept"
        return f"\nsignal {signum}: {what} (again to stop now)"

    def grace_message(self, signum: int) -> str:
        if self._on_grace is not None:
            return self._on_grace(signum, self.grace_s)
        return (f"nmrl: stopped by signal {signum}: the chunk in flight was not saved within the grace of "
                f"{self.grace_s:g} s; the last saved chunk is kept (saves are atomic)")

    def second_message(self, signum: int) -> str:
        if self._on_second is not None:
            return self._on_second(signum, self.moment)
        return (f"nmrl: stopped at once by a second signal {signum} while {self.moment}; files are replaced "
                f"atomically, so what was saved before is intact")

    # ---------------------------------------------------------------- delivery
    def _note(self, signum: int) -> None:
        """Record ``signum`` and print the first signal's message (once, whoever sees it first); the
        first one starts the grace's clock."""
        with self._lock:
            if self.signal is None:
                self.signal = signum
            if not self._printed:
                self._printed = True
                self._since = time.monotonic()
                self._say(self.first_message(signum))
                if self._grace_thread is None and self._old:
                    self._grace_thread = threading.Thread(target=self._grace, name="nmrl-grace", daemon=True)
                    self._grace_thread.start()

    def _exit(self, signum: int, line: str) -> None:
        """Print ``line``, run :attr:`on_exit` and end the process with ``128 + signum`` at once."""
        self._say(line)
        for fn in list(self.on_exit):  # e.g. remove a directory made for a run not yet written
            try:
                fn()
            except Exception:  # noqa: BLE001 - exiting anyway
                pass
        os._exit(128 + signum)

    def _grace(self) -> None:
        """Watch the grace after the first signal (while installed): when it has run out, stop at
        once during training, or mark it so that the save in flight ends the process (:meth:`at`)."""
        while self._old:
            time.sleep(0.1)
            with self._lock:
                if self.grace_s is None or self._since is None or time.monotonic() < self._since + self.grace_s:
                    continue
                if self.moment in GRACE_MOMENTS and self._in_chunk:
                    self._exit(self.signal, self.grace_message(self.signal))
                if self.moment == "saving":
                    self._expired = True

    def _got(self, signum: int) -> None:
        """One delivered signal, counted once (by the watcher thread; by the Python handler when
        there is no watcher). A second one stops the process at once."""
        self._note(signum)
        with self._lock:
            self.count += 1
            n = self.count
        if n >= 2:
            self._exit(signum, self.second_message(signum))

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
        self._old = {}  # the grace's watcher ends with it
        if self._grace_thread is not None:
            self._grace_thread.join(timeout=5)
            self._grace_thread = None
        if _ACTIVE[0] is self:
            _ACTIVE[0] = self._outer

    def __enter__(self) -> "Guard":
        return self.install()

    def __exit__(self, *exc) -> None:
        self.restore()

    # ---------------------------------------------------------------- the command's side
    def at(self, moment: str) -> None:
        """The command enters ``moment`` (a key of :data:`MOMENTS`): a first signal says what it does
        then. Leaving a save after the grace ran out during it ends the process (module docstring)."""
        with self._lock:
            if self._expired and self.moment == "saving" and moment != "saving":
                self._exit(self.signal, self.grace_message(self.signal))
            self.moment = moment

    @contextlib.contextmanager
    def chunk(self) -> Iterator[None]:
        """The block computes a chunk: what a grace that ran out cuts (nothing is written meanwhile;
        the bookkeeping after it, its metrics row, saves and results, runs to the stop)."""
        with self._lock:
            self._in_chunk = True
        try:
            yield
        finally:
            with self._lock:
                self._in_chunk = False

    def raise_if_stopped(self, message: Callable[[int], str] | None = None) -> None:
        """Raise :class:`Interrupted` when a signal came (``message(signum)`` its text)."""
        if self.signal is not None:
            raise Interrupted(self.signal, self.moment, message(self.signal) if message else "")

    def stop_setup(self) -> None:
        """During set-up (one process, moment ``starting``, before the run's files are written), a
        pending signal stops the command here: one line, then :class:`Interrupted`."""
        if self.signal is None or not self.alone or self.moment != "starting":
            return
        self._say(f"stopped by signal {self.signal} during set-up, before the first chunk; nothing of the run was "
                  f"written")
        raise Interrupted(self.signal, "setting up")

    def setup_line(self, what: str, total: int, done: int, step: str = "") -> None:
        """``setting up TOTAL WHAT: STEP, DONE done`` on stderr once the set-up has taken
        :data:`SETUP_EVERY_S` seconds, then at most once per that time (with :attr:`show_setup`)."""
        if not self.show_setup:
            return
        now = time.monotonic()
        if now - (self._last_setup_line or self._t0) < SETUP_EVERY_S:
            return
        self._last_setup_line = now
        self._say(f"setting up {total:,} {what}: {step + ', ' if step else ''}{done:,} done")


def setting_up(items: Iterable[T], total: int, what: str = "points", step: str = "") -> Iterator[T]:
    """Yield ``items`` (``total`` of them), one step of a set-up before the first chunk: before each,
    a pending signal stops the command (:meth:`Guard.stop_setup`) and a long set-up says how far it
    is (:meth:`Guard.setup_line`: ``setting up 2,000 points: STEP, 1,200 done``). Without an
    active guard, just ``items``."""
    guard = active()
    if guard is None:
        yield from items
        return
    for i, x in enumerate(items):
        guard.stop_setup()
        guard.setup_line(what, total, i, step)
        yield x
    guard.stop_setup()


def stop_setup() -> None:
    """:meth:`Guard.stop_setup` of the active guard, if any: a set-up's check between two steps."""
    guard = active()
    if guard is not None:
        guard.stop_setup()
