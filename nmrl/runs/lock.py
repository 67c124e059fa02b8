"""One writer per run directory: an advisory lock held for the life of the command that writes it.

Two commands writing one run directory mix their data silently (two ``nmrl train`` on one
``--out`` append every chunk twice and leave the config of whichever wrote last). Every command
that writes a run -- ``train``, ``sweep`` (the sweep directory and each of its points), ``study``,
``eval``'s outputs -- holds :func:`hold` on the directory for as long as it runs:

* the lock is ``fcntl.flock(LOCK_EX | LOCK_NB)`` on ``DIR/.nmrl.lock``; the kernel releases it when
  the holding process ends in any way (exit, a signal, SIGKILL, out of memory), so a crash never
  leaves a stale lock behind, and a directory that moved keeps its lock;
* the holder writes who it is into the file (pid, command line, start time, host); a second
  writer is refused at once with :class:`Locked`, one line naming the holder;
* one process may hold the same directory several times (a sweep holds its points while a
  nested call asks again): the holds are counted and the lock is released with the last;
* readers (``nmrl eval`` of a finished run without writing into it, the publish scripts) take no lock.

The holder removes the lock file before it unlocks, so a command that ends normally leaves the
directory as it found it (a refusal after the lock changes nothing); a process that opened the old
file meanwhile sees that the path no longer names the file it locked and tries again. A killed
holder leaves the file unlocked, which is as good as none; it is not one of the files that make a
directory a run (nmrl/runs/store.py ``RUN_FILES``). A directory the command created itself is
removed on release when it is empty (``remove_if_empty``): a failed start leaves nothing.
``flock`` is local to one machine (on NFS it is emulated by POSIX locks, which also end with the
process); processes of a distributed run lock only on process 0, the one writer.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import fcntl
import json
import os
import pathlib
import shlex
import socket
import sys
import time

#: The lock file inside a locked directory.
LOCK_FILE = ".nmrl.lock"


class Locked(Exception):
    """Another process holds the directory's lock (the message names it); nothing was written."""

    def __init__(self, path: pathlib.Path, holder: dict | None):
        self.path, self.holder = path, holder or {}
        super().__init__(f"{path} is being written by another nmrl process ({describe(self.holder)}); "
                         f"wait for it to end, stop it, or choose another --out")


def describe(holder: dict) -> str:
    """``pid 123, started 2026-12-03 10:05:01 UTC on host, `nmrl train ...``` (what is known of it)."""
    if not holder.get("pid"):
        return "which one is not recorded yet"
    parts = [f"pid {holder['pid']}"]
    if holder.get("unix_time"):
        parts.append("started " + time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(holder["unix_time"])))
    if holder.get("host") and holder["host"] != socket.gethostname():
        parts.append(f"on {holder['host']}")
    if holder.get("command"):
        cmd = holder["command"]
        parts.append(f"`{cmd if len(cmd) <= 200 else cmd[:197] + '...'}`")
    return ", ".join(parts)


def holder_of(directory: str | os.PathLike) -> dict | None:
    """Who holds ``directory``'s lock now (pid, command, unix_time, host), or None when no one does.
    Reads only (a probe lock on a separate descriptor, released at once)."""
    path = pathlib.Path(directory) / LOCK_FILE
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return _read_holder(fd)
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


def _read_holder(fd: int) -> dict:
    try:
        text = os.pread(fd, 4096, 0).decode(errors="replace")
        d = json.loads(text) if text.strip() else {}
        return d if isinstance(d, dict) else {}
    except (OSError, ValueError):
        return {}


def _command() -> str:
    argv = list(sys.argv)
    if argv and os.path.basename(argv[0]) in ("nmrl", "__main__.py"):
        argv[0] = "nmrl"
    return " ".join(shlex.quote(a) for a in argv)


@dataclasses.dataclass
class _Held:
    fd: int
    count: int
    created: bool


_HELD: dict[str, _Held] = {}  # real path of the directory -> this process's hold


@dataclasses.dataclass
class Hold:
    """One :func:`hold` of a directory; :meth:`release` (or the ``with`` block's end) gives it back."""

    directory: pathlib.Path
    _key: str
    _released: bool = False

    def release(self, remove_if_empty: bool = False) -> None:
        """Give this hold back; the lock ends with the process's last hold of the directory. With
        ``remove_if_empty``, a directory this process created is removed when it is left empty."""
        if self._released:
            return
        self._released = True
        h = _HELD.get(self._key)
        if h is None:
            return
        h.count -= 1
        if h.count > 0:
            return
        del _HELD[self._key]
        try:
            with contextlib.suppress(OSError):
                (self.directory / LOCK_FILE).unlink()
            if remove_if_empty and h.created:
                with contextlib.suppress(OSError):
                    self.directory.rmdir()  # only when empty
        finally:
            os.close(h.fd)  # closing the last descriptor ends the flock

    def __enter__(self) -> "Hold":
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def hold(directory: str | os.PathLike, *, create: bool = True) -> Hold:
    """Take the one-writer lock of ``directory`` (created with its parents when ``create``); returns
    a :class:`Hold`. Raises :class:`Locked` naming the holder when another process has it, and an
    OSError when the directory or its lock file cannot be created (the caller names the cause:
    nmrl/runs/io_errors.py). The lock lasts until the last hold is released or the process ends."""
    d = pathlib.Path(directory)
    made: list[pathlib.Path] = []  # the directories made here, deepest first
    if create and not d.is_dir():
        p = d
        while not p.exists() and p != p.parent:
            made.append(p)
            p = p.parent
        d.mkdir(parents=True, exist_ok=True)
    key = os.path.realpath(d)
    h = _HELD.get(key)
    if h is not None:
        h.count += 1
        return Hold(d, key)
    path = d / LOCK_FILE
    try:
        return _take(d, key, path, existed=path.exists(), created=bool(made))
    except OSError as e:
        for m in made:  # a failed hold leaves nothing behind (the lock file went in _take)
            with contextlib.suppress(OSError):
                m.rmdir()
        if e.filename is None:  # a write to a descriptor names no file: name the lock file
            raise OSError(e.errno, e.strerror, str(path)) from None
        raise


def _take(d: pathlib.Path, key: str, path: pathlib.Path, existed: bool, created: bool) -> Hold:
    """Lock ``path`` (created unless it ``existed``; removed again when writing it fails) and write
    the holder into it."""
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            holder = _read_holder(fd)
            os.close(fd)
            if e.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise Locked(d, holder) from None
            raise
        try:  # the file may have been replaced between open and flock: lock the one at the path
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    try:
        info = json.dumps({"pid": os.getpid(), "command": _command(), "unix_time": time.time(),
                           "host": socket.gethostname()}) + "\n"
        os.ftruncate(fd, 0)
        os.pwrite(fd, info.encode(), 0)
    except OSError:
        os.close(fd)
        if not existed:
            with contextlib.suppress(OSError):
                path.unlink()
        raise
    _HELD[key] = _Held(fd, 1, created)
    return Hold(d, key)


def held(directory: str | os.PathLike) -> bool:
    """Whether this process holds ``directory``'s lock."""
    return os.path.realpath(pathlib.Path(directory)) in _HELD
