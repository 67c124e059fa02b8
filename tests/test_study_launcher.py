"""scripts/run/study.sh, the one launcher of every pre-registered study, on a stand-in study: start
runs `python -m nmrl.experiments.NAME run --out runs/NAME --published PUB` in its own session and a
second start leaves it alone; stop signals that session, waits for it to end and publishes to PUB;
the sweeps' grace is stop's wait; a bad NAME or command is refused with status 2. The stand-in's name is unique to this test, so the
project's real studies (if any are going) are never signalled."""

from __future__ import annotations

import os
import pathlib
import shutil
import subprocess
import time
import uuid

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(shutil.which("setsid") is None or shutil.which("pgrep") is None,
                                reason="needs setsid and pgrep (util-linux, procps)")


@pytest.fixture
def study(tmp_path):
    name = f"standin_{uuid.uuid4().hex[:10]}"
    (tmp_path / "scripts" / "run").mkdir(parents=True)
    for f in ("study.sh", "lower_priority.sh"):
        shutil.copy(REPO / "scripts" / "run" / f, tmp_path / "scripts" / "run" / f)
    calls = tmp_path / "calls.txt"
    fake_py = tmp_path / "python"  # records its arguments; `run` runs until SIGTERM
    fake_py.write_text("#!/usr/bin/env bash\n"
                       f'echo "$*" >> {calls}\n'
                       f'if [ "$3" = run ]; then echo "grace=$NMRL_GRACE_S" >> {calls}; trap "echo saved >> ' + str(calls) + '; exit 143" TERM\n'
                       "  while true; do sleep 0.1; done\nfi\n")
    fake_py.chmod(0o755)
    env = {**os.environ, "PY": str(fake_py), "STOP_TIMEOUT": "20"}
    yield tmp_path, name, env, calls
    subprocess.run(["pkill", "-KILL", "-f", f"nmrl.experiments.{name} run"], check=False)


def _sh(root, env, *args):
    return subprocess.run(["bash", "scripts/run/study.sh", *args], cwd=root, env=env, capture_output=True,
                          text=True, timeout=60)


def _wait_for(calls, text, timeout=20.0):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if calls.exists() and text in calls.read_text():
            return
        time.sleep(0.1)
    raise AssertionError(f"{text!r} not in {calls.read_text() if calls.exists() else '(none)'}")


def test_start_once_then_stop_saves_and_publishes(study):
    root, name, env, calls = study
    assert "started" in _sh(root, env, name, "start").stdout
    _wait_for(calls, f"-m nmrl.experiments.{name} run --out runs/{name} --published results/{name}")
    assert "already running" in _sh(root, env, name, "start").stdout
    (root / "runs" / name).mkdir(parents=True)
    stop = _sh(root, env, name, "stop")
    assert stop.returncode == 0, stop.stdout + stop.stderr
    lines = calls.read_text().splitlines()
    assert lines[-2:] == ["saved", f"-m nmrl.experiments.{name} publish --out runs/{name} --dest results/{name}"]
    assert sum("run --out" in line for line in lines) == 1  # the second start ran nothing
    assert "grace=20" in lines  # the sweeps' grace is stop's wait (STOP_TIMEOUT), so stop keeps their chunk


@pytest.mark.parametrize("args", [(), ("Bad-Name", "start"), ("thesis_ac", "restart")])
def test_bad_name_or_command_is_refused(study, args):
    root, _, env, calls = study
    out = _sh(root, env, *args)
    assert out.returncode == 2 and "usage:" in out.stderr and not calls.exists()
