"""``python -m nmrl.cli ...``: the ``nmrl`` command (:func:`nmrl.cli.main`) run as a module."""

import sys

from nmrl.cli import main

sys.exit(main())
