"""The command line of a study on the kit (nmrl/experiments/kit.py), one for every study:

    python -m nmrl.experiments.<study> run --out DIR [--published DIR] [--only PREFIX ...]
    python -m nmrl.experiments.<study> publish --out DIR --dest DIR
    python -m nmrl.experiments.<study> progress --out DIR
    python -m nmrl.experiments.<study> rows --out DIR
    python -m nmrl.experiments.<study> table --dest DIR
"""

from __future__ import annotations

import argparse
import pathlib
import sys

from nmrl.experiments import kit, kit_progress
from nmrl.runs import store

#: analysis.csv's columns that :func:`table` shows, and the interval columns it joins
_INTERVALS = {"estimate": ("lo", "hi"), "bootstrap": ("boot_lo", "boot_hi")}
_SHOWN = ("family", "endpoint", "contrast", "n", "walking", "estimate", "bootstrap", "p_holm", "tost_p_holm",
          "decision")


def _number(v, p_value: bool = False) -> str:
    if v is None or v == "":
        return ""
    if isinstance(v, str):
        return v
    return f"{v:.2g}" if p_value else f"{v:.1f}"


def table(analysis: list[dict]) -> str:
    """A study's ``analysis.csv`` as a markdown table: per contrast its cells' sizes, the estimate
    with its 95% Welch interval, the stratified bootstrap interval where there is one, the Holm p of
    the test and of TOST, and the decision (estimates to 0.1, p to 2 significant digits)."""
    cols = [c for c in _SHOWN if any(c in r or c in _INTERVALS and _INTERVALS[c][0] in r for r in analysis)]
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in analysis:
        cells = []
        for c in cols:
            if c in _INTERVALS:
                lo, hi = (r.get(k) for k in _INTERVALS[c])
                parts = [_number(r.get("estimate")) if c == "estimate" else ""]
                parts.append(f"[{_number(lo)}, {_number(hi)}]" if lo is not None and hi is not None else "")
                cells.append(" ".join(x for x in parts if x))
            else:
                cells.append(_number(r.get(c), c.startswith(("p_", "tost_p"))))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(study: kit.Study, argv: list[str] | None, prog: str, description: str) -> int:
    """``run`` brings the study's cells to their budgets (a stopped sweep: its status, and a line
    saying to run again), ``publish`` copies what continues into ``--dest``, ``progress`` prints each
    cell's state and time left, ``rows`` writes ``rows.csv``, ``table`` prints ``--dest``'s (else
    ``--out``'s) ``analysis.csv`` as markdown (:func:`table`)."""
    ap = argparse.ArgumentParser(prog=prog, description=description)
    ap.add_argument("action", choices=("run", "publish", "rows", "progress", "table"))
    ap.add_argument("--out", default=None, help="the study's run directory (every action but table)")
    ap.add_argument("--published", default=None, help="a published copy: cells missing in --out start from it")
    ap.add_argument("--dest", default=None, help="publish: where the copy goes")
    ap.add_argument("--only", nargs="*", default=(), help="cells whose names start with one of these")
    a = ap.parse_args(argv)
    if a.action == "table":
        folder = a.dest or a.out
        if folder is None or not (pathlib.Path(folder) / kit.ANALYSIS).is_file():
            ap.error(f"table needs --dest (or --out) holding {kit.ANALYSIS}; got {folder}")
        print(table(store.read_csv(pathlib.Path(folder) / kit.ANALYSIS)))
        return 0
    if a.out is None:
        ap.error(f"{a.action} needs --out")
    if a.action == "run":
        try:
            kit.run(study, a.out, published=a.published, only=a.only or None)
        except kit.StudyStopped as e:
            print(f"{study.name}: {e}; run again to continue", file=sys.stderr)
            return e.status
    elif a.action == "publish":
        if not a.dest:
            ap.error("publish needs --dest")
        kit.publish(study, a.out, a.dest)
    elif a.action == "progress":
        print(kit_progress.progress_text(kit_progress.progress(study, pathlib.Path(a.out))))
    else:
        kit.write_rows(study, pathlib.Path(a.out))
    return 0
