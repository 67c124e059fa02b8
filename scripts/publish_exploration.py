"""Publish the first exploration study: results/exploration/ made again from its own record.

    .venv/bin/python scripts/publish_exploration.py [--record results/exploration] [--dest DIR]

The publisher is nmrl/analysis/publish_exploration.py (``python -m nmrl.analysis.publish_exploration``,
the same options); this is its name in results/exploration/answers.md.
"""

import sys

from nmrl.analysis.publish_exploration import main

if __name__ == "__main__":
    sys.exit(main())
