"""Publish the first exploration study: results/exploration/ made again from its own record.

    .venv/bin/python scripts/publish/publish_exploration.py [--record results/exploration] [--dest DIR]

Writes summary.json, answers.md and the figures of the record into DEST (default: the record
itself). What is written and how it is computed is nmrl/analysis/publish_exploration.py's
(:func:`nmrl.analysis.publish_exploration.publish`); this script reads the command line.
"""

from __future__ import annotations

import pathlib
import sys

from nmrl.analysis import publish_exploration as pub
from nmrl.runs import parser


def main(argv: list[str] | None = None) -> int:
    ap = parser.OneLineParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--record", default=str(pub.RECORD), help="the study's record (default: results/exploration)")
    ap.add_argument("--dest", default=None, help="where the files go (default: the record itself)")
    a = ap.parse_args(argv)
    record = pathlib.Path(a.record)
    if not (record / "study.json").is_file():
        ap.error(f"--record={a.record!r} is invalid: it holds no study.json (give the study's record, "
                 f"results/exploration)")
    written = pub.publish(record, None if a.dest is None else pathlib.Path(a.dest))
    print(f"{len(written)} files under {a.dest or record}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
