"""The run store: what a run directory holds and the one way each file is written and read.

A run directory (one ``nmrl train`` run, or one point of a sweep or study)::

    RUN_DIR/
        config.json      the config the run was created with ({"learner": name, **fields}; no name: the
                         actor-critic); a resume may change only its budget
        metrics.jsonl    one JSON object per chunk (append-only; a resume drops rows after its step)
        resumes.jsonl    one JSON object per resume: from which step/checkpoint, the budgets
        checkpoints/     orbax step directories (nmrl/runs/checkpoint.py)
        compact.npz      the compact continuation state (nmrl/runs/compact.py)

Every file that is replaced (config.json, CSV tables, figures, compact states, JSON summaries) is
written through :func:`atomic_path`: into a temporary file beside it, flushed to disk, then
renamed over the old one, so a reader (or a crash) never sees half a file. CSV tables are written
by :func:`write_csv` and read back by :func:`read_csv` with their types: booleans as ``bool``,
numbers as ``int``/``float``, empty cells as ``None``.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import io
import json
import os
import pathlib
import re
import shutil
import sys
from typing import Any, Iterator, Sequence

import numpy as np

from nmrl import learners
from nmrl.runs import jsonl

CONFIG_FILE = "config.json"
METRICS_FILE = "metrics.jsonl"
#: One JSON object per resume: the step and checkpoint it continued from, the budget before and after.
RESUMES_FILE = "resumes.jsonl"
CHECKPOINTS = "checkpoints"
COMPACT_FILE = "compact.npz"
#: Any of these in a directory makes it a run: a fresh run refuses to start there.
RUN_FILES = (CONFIG_FILE, METRICS_FILE, CHECKPOINTS, COMPACT_FILE, RESUMES_FILE)


# ----------------------------------------------------------------------------- the directory a command writes

#: Entries a directory may hold and still count as empty for a fresh start: the lock (nmrl/runs/lock.py).
IGNORED_ENTRIES = (".nmrl.lock",)


def _short(value: str, n: int = 200) -> str:
    return value if len(value) <= n else value[:n - 1] + "…"


def _exists(p: pathlib.Path) -> bool:
    try:
        return p.exists()
    except OSError:  # a name too long, a loop of links
        return False


def out_path(value: str | os.PathLike, option: str = "--out") -> pathlib.Path:
    """``value`` as the directory a command writes, or a one-line ValueError naming it and what is
    allowed: an empty path (it would be the current directory), one that resolves to the file
    system's root, a name or path longer than the file system takes (checked by length, before
    anything is created), an existing file, or a path below a file. Nothing is created."""
    text = os.fspath(value)
    if text == "":
        raise ValueError(f"{option}='' is invalid: give a directory path, e.g. runs/l10 (an empty path would "
                         f"write into the current directory)")
    if os.path.realpath(text) == os.path.realpath(os.sep):
        raise ValueError(f"{option}={text!r} is invalid: it is the file system's root; give a directory of its own, "
                         f"e.g. runs/l10")
    path = pathlib.Path(text)
    anchor = path.absolute()  # the nearest existing directory above (or at) the path
    while not _exists(anchor) and anchor != anchor.parent:
        anchor = anchor.parent
    name_max, path_max = 255, 4096
    with contextlib.suppress(OSError, ValueError):
        name_max = os.pathconf(anchor, "PC_NAME_MAX")
        path_max = os.pathconf(anchor, "PC_PATH_MAX")
    long = next((c for c in path.parts if len(os.fsencode(c)) > name_max), None)
    if long is not None:
        raise ValueError(f"{option}={_short(text)!r} is invalid: its name {_short(long, 40)!r} is "
                         f"{len(os.fsencode(long))} bytes long; the file system takes at most {name_max}")
    if len(os.fsencode(os.path.abspath(text))) >= path_max:
        raise ValueError(f"{option}={_short(text)!r} is invalid: the path is {len(os.fsencode(os.path.abspath(text)))} "
                         f"bytes long; the file system takes at most {path_max - 1}")
    if anchor == path.absolute() and not path.is_dir():
        raise ValueError(f"{option}={_short(text)!r} is invalid: it exists and is not a directory")
    if not anchor.is_dir():
        raise ValueError(f"{option}={_short(text)!r} is invalid: {anchor} is not a directory")
    return path


def foreign_entries(d: str | os.PathLike, allowed: Sequence[str] = ()) -> list[str]:
    """The entries of the directory ``d`` (sorted) that are neither ``allowed`` nor ignored
    (:data:`IGNORED_ENTRIES`); [] when ``d`` does not exist."""
    try:
        names = os.listdir(d)
    except (FileNotFoundError, NotADirectoryError):
        return []
    return sorted(n for n in names if n not in IGNORED_ENTRIES and n not in allowed)


# ----------------------------------------------------------------------------- atomic files


def fsync_path(path: str | os.PathLike) -> None:
    """Flush a file's data or a directory's entries to disk (best effort: an OSError is ignored)."""
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)



@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[pathlib.Path]:
    """``with atomic_path(p) as tmp: write(tmp)``: ``tmp`` (same directory and suffix: matplotlib,
    imageio and numpy choose the format from it) is flushed to disk and renamed to ``p`` when the
    block ends without an error; on an error it is removed and ``p`` is left as it was."""
    path = pathlib.Path(path)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    try:
        yield tmp
        fsync_path(tmp)
        os.replace(tmp, path)
        fsync_path(path.parent)
    finally:
        tmp.unlink(missing_ok=True)


def atomic_copy(src: str | os.PathLike, dst: str | os.PathLike) -> None:
    """Copy the file ``src`` to ``dst`` (parents created) atomically: ``dst`` is the old or the new file."""
    dst = pathlib.Path(dst)
    dst.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(dst) as tmp:
        shutil.copy2(src, tmp)


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def atomic_write_json(path: str | os.PathLike, obj: Any, indent: int | None = 2) -> None:
    atomic_write_text(path, json.dumps(obj, indent=indent) + "\n")


# ----------------------------------------------------------------------------- config.json


def write_config(run_dir: str | os.PathLike, cfg: Any) -> pathlib.Path:
    """Write ``RUN_DIR/config.json`` (the directory is created): a learner's config with the learner's
    name (``{"learner": name, **fields}``, nmrl/learners/contract.py), any other dataclass as its fields."""
    run_dir = pathlib.Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    path = run_dir / CONFIG_FILE
    try:
        d = learners.config_dict(cfg)
    except TypeError:  # not a learner's config
        d = dataclasses.asdict(cfg)
    atomic_write_json(path, d)
    return path


def append_resume(run_dir: str | os.PathLike, record: dict) -> None:
    _append_line(pathlib.Path(run_dir) / RESUMES_FILE, json.dumps(record))


# ----------------------------------------------------------------------------- metrics.jsonl


def _append_line(path: pathlib.Path, line: str) -> None:
    """Append one line (one ``write``, flushed to disk); a file that does not end with a whole line
    (a crash while appending) is completed first (:func:`nmrl.runs.jsonl.complete_tail`)."""
    try:
        with open(path, "rb") as f:
            f.seek(-1, os.SEEK_END)
            whole = f.read(1) == b"\n"
    except (FileNotFoundError, OSError):
        whole = True  # no file, or an empty one
    if not whole:
        jsonl.complete_tail(path)
    with open(path, "a") as f:
        f.write(line + "\n")
        f.flush()
        os.fsync(f.fileno())


def to_python(m: dict) -> dict:
    """A chunk's metrics (numpy/JAX scalars) as plain Python bool/int/float."""
    out = {}
    for k, v in m.items():
        v = np.asarray(v)
        out[k] = bool(v) if v.dtype == bool else (int(v) if np.issubdtype(v.dtype, np.integer) else float(v))
    return out


_WARNED: set[str] = set()


def _warn_once(message: str) -> None:
    """A partial last row is reported once per file and process (it is read many times)."""
    key = message.split(": ", 1)[0]
    if key not in _WARNED:
        _WARNED.add(key)
        print(f"nmrl: warning: {message}", file=sys.stderr, flush=True)


def read_jsonl(path: str | os.PathLike) -> list[dict]:
    """The JSON objects of a JSON-lines file, one per non-empty line ([] if there is no file). An
    unfinished last line (a crash while appending) is dropped with one warning; any other damage
    raises :class:`nmrl.runs.jsonl.Corrupt` naming the file and line (nmrl/runs/jsonl.py)."""
    return jsonl.read(path, _warn_once)


def read_metrics(run_dir: str | os.PathLike) -> list[dict]:
    return read_jsonl(pathlib.Path(run_dir) / METRICS_FILE)


def append_metrics(run_dir: str | os.PathLike, row: dict) -> None:
    _append_line(pathlib.Path(run_dir) / METRICS_FILE, json.dumps(row))


def truncate_metrics(run_dir: str | os.PathLike, step: int) -> None:
    """Keep only the metrics of chunks up to ``step`` (the restored checkpoint: a resumed run's file
    equals an uninterrupted run's); the file is not rewritten when it has no later rows."""
    run_dir = pathlib.Path(run_dir)
    rows = read_metrics(run_dir)
    keep = [r for r in rows if r["step"] <= step]
    path = run_dir / METRICS_FILE
    if len(keep) == len(rows) and path.exists() and not jsonl.has_partial_tail(path):
        return
    atomic_write_text(run_dir / METRICS_FILE, "".join(json.dumps(r) + "\n" for r in keep))


def remove_metrics(run_dir: str | os.PathLike) -> None:
    (pathlib.Path(run_dir) / METRICS_FILE).unlink(missing_ok=True)


def is_diverged(m: dict) -> bool:
    """A metrics row of a diverged chunk (the flag, or a non-finite parameter norm: a metric whose
    name ends in ``_norm``, nmrl/learners/contract.py)."""
    return learners.is_diverged(m)


# ----------------------------------------------------------------------------- CSV tables

_INT = re.compile(r"[+-]?\d+")


def _cell(v: Any) -> Any:
    return "" if v is None else v


def write_csv(path: str | os.PathLike, columns: Sequence[str], rows: list[dict]) -> None:
    """Write ``rows`` (dicts with exactly ``columns``) as a CSV table, atomically."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(columns))
    w.writeheader()
    w.writerows({k: _cell(v) for k, v in r.items()} for r in rows)
    atomic_write_text(path, buf.getvalue())


def parse_cell(s: str) -> Any:
    """One CSV cell back to its value: ``True``/``False`` -> bool, integers -> int, other numbers
    (also ``nan``, ``inf``) -> float, empty -> None, anything else stays a string."""
    if s == "":
        return None
    if s in ("True", "False"):
        return s == "True"
    if _INT.fullmatch(s):
        return int(s)
    try:
        return float(s)
    except ValueError:
        return s


def read_csv(path: str | os.PathLike) -> list[dict]:
    """The rows of a table written by :func:`write_csv`, with their types (:func:`parse_cell`)."""
    with open(path, newline="") as f:
        return [{k: parse_cell(v) for k, v in r.items()} for r in csv.DictReader(f)]
