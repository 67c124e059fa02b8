"""scripts/run/lower_priority.sh: a script that leads its own session (a background launch with setsid)
lowers its session's autogroup nice value, read back from the kernel; any other caller's session
is left as it was."""

from __future__ import annotations

import os
import pathlib
import shutil
import subprocess

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
AUTOGROUP = pathlib.Path("/proc/self/autogroup")

pytestmark = pytest.mark.skipif(not AUTOGROUP.exists() or not os.access(AUTOGROUP, os.W_OK)
                                or shutil.which("setsid") is None,
                                reason="needs Linux autogroup scheduling (/proc/self/autogroup) and setsid")

SCRIPT = 'source scripts/run/lower_priority.sh; lower_priority; cat /proc/self/autogroup'


def _nice(text: str) -> int:
    return int(text.split("nice")[1])  # "/autogroup-123 nice 19"


@pytest.mark.parametrize("nice", [None, "7"])
def test_a_session_leader_lowers_its_whole_session(nice):
    env = {k: v for k, v in os.environ.items() if k != "NICE"}
    if nice is not None:
        env["NICE"] = nice
    out = subprocess.run(["setsid", "bash", "-c", SCRIPT], cwd=REPO, env=env, capture_output=True, text=True,
                         timeout=30, check=True).stdout
    assert _nice(out) == int(nice or 19)
    # its own group, not this one; a process in the kernel's root group reads an empty file
    assert out.split()[0] != (AUTOGROUP.read_text().split() or ["root group"])[0]


def test_a_script_inside_another_session_leaves_that_session_alone():
    before = AUTOGROUP.read_text()
    out = subprocess.run(["bash", "-c", SCRIPT], cwd=REPO, capture_output=True, text=True, timeout=30,
                         check=True).stdout
    assert out == before == AUTOGROUP.read_text()
