"""JSON-lines files of a run (``metrics.jsonl``, ``resumes.jsonl``) read back after a crash.

A row is appended as one ``write`` of the JSON object and its newline, then flushed to disk
(nmrl/runs/store.py), so a process killed while appending leaves at most one partial row: the
last line, without its newline. Its chunk's checkpoint is written after the row (the driver), so
it was never written, and a resume runs that chunk again from the checkpoint before (the driver
resumes from the newest checkpoint the complete rows reach): :func:`read` drops the fragment
with one warning naming the file and its size. Anything else that is not a JSON
object per line -- a bad line in the middle, or a last line that ends with its newline and still
does not parse -- is not the trace of an interrupted append: :class:`Corrupt`, one line naming the
file and the line.
"""

from __future__ import annotations

import json
import os
import pathlib
from typing import Callable


class Corrupt(ValueError):
    """A JSON-lines file holds something other than one JSON object per line (message: file, line)."""


def partial_tail(text: str) -> str | None:
    """The unfinished last line of ``text`` (no newline after it and not a JSON object), else None."""
    if not text or text.endswith("\n"):
        return None
    last = text.rsplit("\n", 1)[-1]
    if not last.strip():
        return None
    try:
        return None if isinstance(json.loads(last), dict) else last
    except ValueError:
        return last


def parse(text: str, name: str = "<text>", warn: Callable[[str], None] | None = None) -> list[dict]:
    """The JSON objects of ``text``, one per non-empty line; a partial last line (:func:`partial_tail`)
    is dropped with one ``warn`` call; any other bad line raises :class:`Corrupt`."""
    tail = partial_tail(text)
    if tail is not None:
        text = text[: len(text) - len(tail)]
        if warn is not None:
            n = text.count("\n") + 1
            warn(f"{name}: dropped the unfinished last line {n} ({len(tail)} bytes without a newline: the "
                 f"process stopped while appending it); a resume runs its chunk again")
    rows = []
    for i, line in enumerate(text.split("\n"), 1):
        if not line.strip():
            continue
        try:
            row = json.loads(line)
        except ValueError as e:
            raise Corrupt(f"{name}: line {i} is not valid JSON ({e.msg} at column {e.colno}): "
                          f"{line[:80]!r}; the file is damaged, not cut by a crash: repair or move it") from None
        if not isinstance(row, dict):
            raise Corrupt(f"{name}: line {i} is not a JSON object ({type(row).__name__}): {line[:80]!r}; "
                          f"repair or move the file")
        rows.append(row)
    return rows


def read(path: str | os.PathLike, warn: Callable[[str], None] | None = None) -> list[dict]:
    """The JSON objects of the file ``path`` ([] when there is no file), as :func:`parse` reads them."""
    p = pathlib.Path(path)
    try:
        text = p.read_text()
    except FileNotFoundError:
        return []
    except UnicodeDecodeError as e:
        raise Corrupt(f"{p}: not UTF-8 text at byte {e.start}; the file is damaged: repair or move it") from None
    return parse(text, str(p), warn)


def has_partial_tail(path: str | os.PathLike) -> bool:
    """Whether the file ends in an unfinished line (a rewrite without it is due before appending)."""
    try:
        text = pathlib.Path(path).read_text(errors="replace")
    except FileNotFoundError:
        return False
    return partial_tail(text) is not None


def complete_tail(path: str | os.PathLike) -> bool:
    """Make the file end with a whole line before a row is appended: a complete last object missing
    its newline gets it, an unfinished last line (:func:`partial_tail`) is cut off (the file is
    rewritten through a temporary file and a rename). Returns whether the file was changed."""
    p = pathlib.Path(path)
    try:
        text = p.read_text(errors="surrogateescape")
    except FileNotFoundError:
        return False
    if not text or text.endswith("\n"):
        return False
    tail = partial_tail(text)
    if tail is None:
        with open(p, "a") as f:
            f.write("\n")
            f.flush()
            os.fsync(f.fileno())
        return True
    tmp = p.with_name(f".{p.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "w", errors="surrogateescape") as f:
            f.write(text[: len(text) - len(tail)])
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, p)
    finally:
        tmp.unlink(missing_ok=True)
    return True
