"""The command line of a study on the kit (nmrl/experiments/kit.py), one for every study:

    python -m nmrl.experiments.<study> run --out DIR [--published DIR] [--only PREFIX ...]
    python -m nmrl.experiments.<study> publish --out DIR --dest DIR
    python -m nmrl.experiments.<study> progress --out DIR
    python -m nmrl.experiments.<study> rows --out DIR
"""

from __future__ import annotations

import argparse
import pathlib
import sys

from nmrl.experiments import kit, kit_progress


def main(study: kit.Study, argv: list[str] | None, prog: str, description: str) -> int:
    """``run`` brings the study's cells to their budgets (a stopped sweep: its status, and a line
    saying to run again), ``publish`` copies what continues into ``--dest``, ``progress`` prints each
    cell's state and time left, ``rows`` writes ``rows.csv``."""
    ap = argparse.ArgumentParser(prog=prog, description=description)
    ap.add_argument("action", choices=("run", "publish", "rows", "progress"))
    ap.add_argument("--out", required=True, help="the study's run directory")
    ap.add_argument("--published", default=None, help="a published copy: cells missing in --out start from it")
    ap.add_argument("--dest", default=None, help="publish: where the copy goes")
    ap.add_argument("--only", nargs="*", default=(), help="cells whose names start with one of these")
    a = ap.parse_args(argv)
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
