"""The ``nmrl`` command run in-process (``cli.main``) with its stdout and stderr captured, as the
black-box reliability tests run it where one process is enough."""

from __future__ import annotations

import contextlib
import io

from nmrl import cli


def run_main(argv: list[str]) -> tuple[int, str, str]:
    """(exit status, stdout, stderr) of ``nmrl <argv>``; argparse's own exit gives its status."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = cli.main(argv)
        except SystemExit as e:  # argparse
            rc = e.code
    return rc, out.getvalue(), err.getvalue()
