"""``nmrl --help``, ``nmrl train --help`` and ``nmrl sweep --help`` (of every learner) are made from the
declarations alone: no JAX, Flax, optax or MuJoCo is imported to build them (a subprocess starts
clean), and the help is the same as the one built in a process that has imported them all."""

from __future__ import annotations

import contextlib
import io
import json
import pathlib
import subprocess
import sys

import pytest

from nmrl import cli

REPO = pathlib.Path(__file__).resolve().parents[1]
HEAVY = ("jax", "jaxlib", "flax", "optax", "mujoco")
ARGVS = [["--help"], ["train", "--help"], ["sweep", "--help"], ["train", "--learner", "ppo", "--help"],
         ["sweep", "--learner", "ppo", "--help"]]
_SCRIPT = """
import contextlib, io, json, sys
from nmrl import cli
out = {}
for argv in json.loads(sys.argv[1]):
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        try:
            cli.main(argv)
        except SystemExit:
            pass
    out[" ".join(argv)] = buf.getvalue()
print(json.dumps({"help": out, "imported": sorted({m.split(".")[0] for m in sys.modules} & set(json.loads(sys.argv[2])))}))
"""


def _help(argv: list[str]) -> str:
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), pytest.raises(SystemExit):
        cli.main(argv)
    return buf.getvalue()


def test_help_imports_no_jax_and_reads_as_in_a_process_with_jax():
    p = subprocess.run([sys.executable, "-c", _SCRIPT, json.dumps(ARGVS), json.dumps(HEAVY)], cwd=REPO,
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    got = json.loads(p.stdout)
    assert got["imported"] == [], got["imported"]
    import jax  # noqa: F401 - this process has JAX and every learner's program: the help must not depend on it
    from nmrl.learners import ac, ppo  # noqa: F401

    for argv in ARGVS:
        text = got["help"][" ".join(argv)]
        assert text.startswith("usage: nmrl") and text == _help(argv), argv
