"""Failures of the disk and the file system, named in one line: which path, and why.

A command that cannot write (the disk is full, the file system is read-only, permission is
denied, the directory is immutable) is not given bad input: it exits with its own status,
:data:`IO_FAILED`, after one line ``nmrl: error: cannot write PATH: CAUSE; ...``. The failure
reaches the command in many shapes: an ``OSError`` with its ``errno``, or one wrapped by orbax or
tensorstore (whose messages keep only the text, e.g. ``"No space left on device"``), raised in a
worker thread and re-raised later. :func:`find` looks through an exception, its causes and
contexts and their messages; :func:`describe` names the cause. Root passes every permission check
(``os.access`` says yes), so :func:`check_writable` creates and removes a file to know.
:func:`immutable` reads the inode flags (``chattr +i``/``+a``), the one cause that root's
``EPERM`` has on a local file system.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import fcntl
import os
import pathlib
import re
import struct
import sys

#: Exit status of a command stopped by a disk or file system failure (see the module docstring).
IO_FAILED = 5

#: errno -> the cause in words
CAUSES = {
    errno.ENOSPC: "the disk is full (no space left on device)",
    errno.EDQUOT: "the disk quota is exceeded",
    errno.EROFS: "the file system is read-only",
    errno.EACCES: "permission denied",
    errno.EPERM: "the operation is not permitted",
    errno.EFBIG: "the file is too large for the file system",
    errno.EIO: "an input/output error of the device",
    errno.EMFILE: "too many open files",
    errno.ENFILE: "too many open files in the system",
}
#: messages of wrapped errors that lost their errno (orbax, tensorstore, absl::Status)
_TEXT = [(re.compile(p, re.I), e) for p, e in (
    (r"no space left on device|\benospc\b|\[errno 28\]", errno.ENOSPC),
    (r"disk quota exceeded|\[errno 122\]", errno.EDQUOT),
    (r"read-only file system|\[errno 30\]", errno.EROFS),
    (r"permission denied|\[errno 13\]", errno.EACCES),
    (r"operation not permitted|\[errno 1\]", errno.EPERM),
    (r"file too large|\[errno 27\]", errno.EFBIG),
    (r"input/output error|\[errno 5\]", errno.EIO),
)]
_PATH = re.compile(r"""['"](/[^'"]+)['"]""")
_FS_IOC_GETFLAGS = 0x80086601
_FS_IMMUTABLE_FL, _FS_APPEND_FL = 0x10, 0x20


@dataclasses.dataclass(frozen=True)
class Failure:
    """One disk or file system failure: the ``errno``, the path (None: unknown) and the cause in words."""

    errno: int
    path: str | None
    cause: str

    def line(self, what: str = "cannot write") -> str:
        """``cannot write PATH: CAUSE`` (the text after ``nmrl: error:``)."""
        where = f" {self.path}" if self.path else ""
        return f"{what}{where}: {self.cause}"


class IOFailure(Exception):
    """A disk or file system failure, the message one line naming the path and the cause."""

    def __init__(self, failure: Failure, what: str = "cannot write", hint: str = ""):
        self.failure = failure
        super().__init__(failure.line(what) + (f"; {hint}" if hint else ""))


#: whether :func:`report` mutes stderr after its line; the process's entry point (nmrl/cli/__init__.py's
#: ``main`` run as the ``nmrl`` command) sets it, in-process callers leave their stderr alone
mute_after_report = False


def report(line: str) -> None:
    """Print a disk failure's one ``line`` on stderr, and then (with :data:`mute_after_report`)
    point file descriptor 2 at the null device for the rest of the process.

    orbax's worker threads of the failed write finish after the command has caught the failure:
    they re-raise the same exception and log it with its traceback, some only while the interpreter
    shuts down. The command has already named the path and the cause; that noise would bury it."""
    print(line, file=sys.stderr, flush=True)
    if mute_after_report:
        with contextlib.suppress(OSError, ValueError):
            fd = os.open(os.devnull, os.O_WRONLY)
            os.dup2(fd, 2)
            os.close(fd)


def immutable(path: str | os.PathLike) -> str | None:
    """``"immutable"`` or ``"append-only"`` when ``path`` (or its nearest existing parent) has that
    inode flag (``chattr +i``/``+a``), else None (also where the flags cannot be read)."""
    p = pathlib.Path(path)
    while not p.exists() and p != p.parent:
        p = p.parent
    try:
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK)
    except OSError:
        return None
    try:
        buf = fcntl.ioctl(fd, _FS_IOC_GETFLAGS, struct.pack("l", 0))
        flags = struct.unpack("l", buf)[0]
    except OSError:
        return None
    finally:
        os.close(fd)
    if flags & _FS_IMMUTABLE_FL:
        return "immutable"
    if flags & _FS_APPEND_FL:
        return "append-only"
    return None


def _cause(code: int, path: str | None) -> str:
    cause = CAUSES.get(code, os.strerror(code).lower())
    if code in (errno.EPERM, errno.EACCES) and path:
        flag = immutable(path)
        if flag == "immutable":
            return "the directory or file is immutable (chattr +i; `chattr -i` lifts it)"
        if flag == "append-only":
            return "the directory or file is append-only (chattr +a)"
    return cause


def _chain(e: BaseException):
    seen = set()
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        yield e
        e = e.__cause__ or e.__context__


def _all(e: BaseException):
    """``e``'s chain and, inside exception groups (asyncio's, in orbax), every member's."""
    for x in _chain(e):
        yield x
        for sub in getattr(x, "exceptions", ()) or ():
            if isinstance(sub, BaseException):
                yield from _all(sub)


def find(e: BaseException, path: str | os.PathLike | None = None) -> Failure | None:
    """The disk or file system failure behind ``e`` (its causes, contexts, exception groups and their
    messages), or None when it is something else. ``path`` is named when the error names none."""
    for x in _all(e):
        if isinstance(x, OSError) and x.errno in CAUSES:
            p = x.filename or (str(path) if path is not None else None)
            return Failure(x.errno, str(p) if p is not None else None, _cause(x.errno, str(p) if p else None))
    for x in _all(e):
        text = str(x)
        for pat, code in _TEXT:
            if pat.search(text):
                m = _PATH.search(text)
                p = m.group(1) if m else (str(path) if path is not None else None)
                return Failure(code, p, _cause(code, p))
    return None


def check_writable(directory: str | os.PathLike) -> None:
    """Raise :class:`IOFailure` unless a file can be created in ``directory`` (made with its parents
    if missing; a directory made here is removed again). Creates and removes a file: root passes
    ``os.access`` on a read-only mount or an immutable directory, but not this."""
    d = pathlib.Path(directory)
    made = []
    p = d
    while not p.exists() and p != p.parent:
        made.append(p)
        p = p.parent
    try:
        for m in reversed(made):
            m.mkdir()
        probe = d / f".nmrl-write-check.{os.getpid()}"
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        os.close(fd)
        probe.unlink()
    except OSError as e:
        f = find(e, d) or Failure(e.errno or 0, str(d), (e.strerror or str(e)).lower())
        raise IOFailure(f) from None
    finally:
        for m in made:
            with contextlib.suppress(OSError):
                m.rmdir()


def remove_partial_saves(checkpoints: str | os.PathLike, settle_s: float = 10.0,
                         quiet_s: float = 1.0) -> list[pathlib.Path]:
    """Remove the unfinished step directories a failed save left (orbax's
    ``<step>.orbax-checkpoint-tmp*``; readers ignore them, but they take disk space); returns them.

    tensorstore's writer threads of the failed save (not Python threads: nothing to join) may still
    put a file into a directory while it is being removed, and its file store creates the parent
    directories of what it writes, so a removed directory can come back. The directory is scanned and
    cleared until none has been seen for ``quiet_s`` seconds, for at most ``settle_s`` seconds in all."""
    import shutil
    import time

    d = pathlib.Path(checkpoints)
    gone: set[pathlib.Path] = set()
    start = last_seen = time.monotonic()
    while True:
        try:
            partial = [p for p in d.iterdir() if ".orbax-checkpoint-tmp" in p.name]
        except OSError:  # the directory is gone or unreadable: nothing left to remove
            break
        for p in partial:
            shutil.rmtree(p, ignore_errors=True)
            gone.add(p)
        now = time.monotonic()
        if partial:
            last_seen = now
        if now - last_seen >= quiet_s or now - start >= settle_s:
            break
        time.sleep(0.02)
    return sorted(gone)
