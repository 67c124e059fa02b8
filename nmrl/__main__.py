"""``python -m nmrl``: the ``nmrl`` command (nmrl/cli) without the console script on PATH, with its
exit status (2 for bad input, nmrl/runs/exits.py)."""

import sys

from nmrl.cli import main

if __name__ == "__main__":
    sys.exit(main())
