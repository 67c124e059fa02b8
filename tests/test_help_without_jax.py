"""``nmrl --help``, ``nmrl train --help`` and ``nmrl sweep --help`` (of every learner) are made from the
declarations alone: no JAX, Flax, optax or MuJoCo is imported to build them (a subprocess starts
clean), and the help is the same as the one built in a process that has imported them all."""

from __future__ import annotations

import json
import pathlib
import subprocess
import sys


REPO = pathlib.Path(__file__).resolve().parents[1]
HEAVY = ("jax", "jaxlib", "flax", "optax", "mujoco")
ARGVS = [["--help"], ["train", "--help"], ["sweep", "--help"], ["train", "--learner", "ppo", "--help"],
         ["sweep", "--learner", "ppo", "--help"]]
_SCRIPT = """
import contextlib, io, json, sys
if sys.argv[3] == "heavy":  # JAX and every learner's program imported first
    import jax, flax, optax, mujoco
    from nmrl.learners import ac, ppo
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


def _helps(mode: str) -> dict:
    """The help texts of :data:`ARGVS` built in a clean process (``mode`` "heavy": with JAX and every
    learner's program imported first; this test's own process may hold learners other tests register)."""
    p = subprocess.run([sys.executable, "-c", _SCRIPT, json.dumps(ARGVS), json.dumps(HEAVY), mode], cwd=REPO,
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    return json.loads(p.stdout)


def test_help_imports_no_jax_and_reads_as_in_a_process_with_jax():
    got, heavy = _helps("light"), _helps("heavy")
    assert got["imported"] == [], got["imported"]
    assert {"jax", "mujoco"} <= set(heavy["imported"])  # the reference really had them
    for argv in ARGVS:
        text = got["help"][" ".join(argv)]
        assert text.startswith("usage: nmrl") and text == heavy["help"][" ".join(argv)], argv
