"""Publish the finer-delta study (nmrl/experiments/study.py) into results/ and print its tables as Markdown.

    .venv/bin/python scripts/publish/publish_timescale.py runs/timescale results/timescale   # copy, draw, print
    .venv/bin/python scripts/publish/publish_timescale.py results/timescale                  # draw, print from the record

What is copied, drawn and tabulated is nmrl/analysis/publish_timescale.py's (``publish``,
``figures``, ``tables``); this script reads the command line.
"""

from __future__ import annotations

import pathlib
import sys

from nmrl.analysis import publish_timescale as pub
from nmrl.runs import parser


def main(argv: list[str] | None = None) -> int:
    ap = parser.OneLineParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dirs", nargs="+", metavar="DIR", help="STUDY_DIR RESULTS_DIR, or a RESULTS_DIR alone")
    a = ap.parse_args(argv)
    if len(a.dirs) > 2:
        ap.error(f"DIR={' '.join(a.dirs)!r} is invalid: give STUDY_DIR RESULTS_DIR, or a RESULTS_DIR alone")
    src = pathlib.Path(a.dirs[0])
    for f in ("grid.csv", "final.csv"):
        if not (src / f).is_file():
            ap.error(f"DIR={a.dirs[0]!r} is invalid: it holds no {f} (give a finished study or its record)")
    if len(a.dirs) == 2:
        pub.publish(src, pathlib.Path(a.dirs[1]))
    else:
        pub.figures(src)
    print(pub.tables(pathlib.Path(a.dirs[-1])), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
