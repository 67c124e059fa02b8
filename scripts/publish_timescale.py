"""Publish the finer-delta study (nmrl/experiments/study.py) into results/ and print its tables as Markdown.

    .venv/bin/python scripts/publish_timescale.py runs/timescale results/timescale   # copy, draw, print
    .venv/bin/python scripts/publish_timescale.py results/timescale                  # draw, print from the record

The publisher is nmrl/analysis/publish_timescale.py (``python -m nmrl.analysis.publish_timescale``,
the same arguments).
"""

import sys

from nmrl.analysis.publish_timescale import main

if __name__ == "__main__":
    sys.exit(main())
