"""Signals as a supervisor sends them: a grace for the chunk in flight, set-up stopped within seconds.

Black-box: real ``nmrl`` processes get real signals (SLURM's SIGTERM, then SIGKILL after KillWait);
what is checked is the exit status, how long the process took to exit, what is on disk and that
the last saved chunk continues. A full disk at the lock stage is simulated in-process (the lock
file's write fails with ENOSPC) and must name the path and leave nothing behind.
"""

from __future__ import annotations

import errno
import json
import os
import pathlib
import signal
import subprocess
import sys
import threading
import time

import pytest

from tests.cli_in_process import run_main as _main
from nmrl import options
from nmrl.runs import checkpoint, exits, lock, signals, store

#: a chunk of 10-20 s on a 2-core machine (8 environments, 10,000 control steps): longer than the grace
LONG_CHUNK = ["--preset", "fast", "--num-envs", "8", "--chunk-steps", "10000", "--hidden-actor", "8",
              "--hidden-critic", "8", "--devices", "1"]


def _env(**extra: str) -> dict:
    env = dict(os.environ, **extra)
    env.pop("XLA_FLAGS", None)
    env.pop(signals.GRACE_ENV, None)
    env.update(extra)
    return env


def _proc(argv: list[str], **env: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "nmrl.cli", *argv], env=_env(**env), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


class _Lines:
    """The process's stderr lines as they come (a reader thread), each with its arrival time."""

    def __init__(self, p: subprocess.Popen):
        self.lines: list[tuple[float, str]] = []
        self._t = threading.Thread(target=self._read, args=(p,), daemon=True)
        self._t.start()

    def _read(self, p):
        for line in p.stderr:
            self.lines.append((time.monotonic(), line))

    def wait_for(self, p: subprocess.Popen, prefix: str, timeout: float) -> float:
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            for t, line in list(self.lines):
                if line.startswith(prefix):
                    return t
            assert p.poll() is None, self.text()
            time.sleep(0.05)
        raise AssertionError(f"no line starting with {prefix!r} within {timeout} s:\n{self.text()}")

    def text(self) -> str:
        self._t.join(timeout=5)
        return "".join(line for _, line in self.lines)


def _stop(p: subprocess.Popen) -> None:
    if p.poll() is None:
        p.kill()
        p.wait()


# ----------------------------------------------------------------------------- the grace


@pytest.mark.slow  # a compile and three chunks of ~15 s, about 2 minutes on 2 cores
def test_a_sigterm_stops_a_long_chunk_within_the_grace_and_the_last_saved_chunk_resumes(tmp_path):
    out = tmp_path / "R"
    p = _proc(["train", *LONG_CHUNK, "--steps", "100000", "--grace-s", "2", "--out", str(out)])
    try:
        t0 = time.time()
        while not (out / "checkpoints" / "10000").is_dir():
            assert p.poll() is None and time.time() - t0 < 600, p.communicate()[1][-3000:]
            time.sleep(0.05)
        time.sleep(1.5)  # the first chunk's save is over: the second chunk is in flight
        t_sig = time.monotonic()
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=120)
        took = time.monotonic() - t_sig
    finally:
        _stop(p)
    assert p.returncode == 143, err[-3000:]
    assert 1.5 < took < 2 + 5, (took, err[-3000:])  # the grace, then seconds to exit; not the chunk's end
    assert "Traceback" not in err
    assert checkpoint.latest_step(out) == store.read_metrics(out)[-1]["step"] == 10000
    assert not [x for x in (out / "checkpoints").iterdir() if "tmp" in x.name]
    rc, _, err = _main(["train", "--resume", "--steps", "20000", "--quiet", "--out", str(out)])
    assert rc == 0, err
    assert [r["step"] for r in store.read_metrics(out)] == [10000, 20000]


_SAVE = """
import os, signal, sys, time
from nmrl.runs import signals
g = signals.Guard().install()
g.grace_s = 1.0
g.at("saving")
os.kill(os.getpid(), signal.SIGTERM)
time.sleep(3)  # a save that outlasts the grace
print("saved", flush=True)
g.at("training")
print("went on", flush=True)
"""


def test_a_grace_that_runs_out_during_a_save_lets_the_save_finish():
    t0 = time.monotonic()
    q = subprocess.run([sys.executable, "-c", _SAVE], env=_env(), capture_output=True, text=True, timeout=60)
    assert q.returncode == 143, q.stderr
    assert q.stdout.splitlines() == ["saved"]
    assert time.monotonic() - t0 >= 3


@pytest.mark.parametrize("option, env", [(["--grace-s", "0"], None), (["--grace-s", "-5"], None),
                                         (["--grace-s", "soon"], None), (["--grace-s", "inf"], None),
                                         (["--grace-s", "nan"], None), ([], "abc"), ([], "0")])
def test_a_bad_grace_is_one_line_and_writes_nothing(tmp_path, monkeypatch, option, env):
    if env is not None:
        monkeypatch.setenv(signals.GRACE_ENV, env)
    out = tmp_path / "R"
    for cmd in (["train"], ["sweep", "--l", "1", "--seeds", "1"]):
        rc, _, err = _main([*cmd, "--preset", "fast", "--num-envs", "8", "--steps", "100", *option, "--quiet",
                            "--out", str(out)])
        lines = [x for x in err.splitlines() if x.strip()]
        assert rc == 2 and len(lines) == 1, err
        assert (option[1] if option else env) in lines[0] and ("--grace-s" if option else signals.GRACE_ENV) in lines[0]
        assert "positive" in lines[0]  # what is allowed
        assert not out.exists()


def test_a_study_refuses_a_bad_grace_in_the_environment_in_one_line(tmp_path, monkeypatch):
    monkeypatch.setenv(signals.GRACE_ENV, "later")
    rc, _, err = _main(["study", "--dt", "0.02", "--out", str(tmp_path / "S")])
    lines = [x for x in err.splitlines() if x.strip()]
    assert rc == 2 and len(lines) == 1 and signals.GRACE_ENV in lines[0] and "later" in lines[0], err
    assert not (tmp_path / "S").exists()


def test_the_grace_option_wins_over_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv(signals.GRACE_ENV, "abc")
    rc, _, err = _main(["train", "--num-envs", "0", "--grace-s", "5", "--quiet", "--out", str(tmp_path / "R")])
    assert rc == 2 and "num_envs" in err and signals.GRACE_ENV not in err


def test_the_progress_line_says_when_the_next_save_is_due(capsys):
    from nmrl.learners.ac_config import TrainConfig
    from nmrl.runs import loop

    bar = loop.Progress(options.build(TrainConfig, num_envs=8, chunk_steps=25, steps=100), True, every=2)
    bar.update({"step": 25, "trials": 3, "total_steps": 200, "steps_per_s": 60.0, "avg_reward": -0.5,
                "forward_speed": 0.0, "wall_s": 7.0})
    bar.close()
    line = capsys.readouterr().err.strip()
    assert len(line.splitlines()) == 1 and "save" in line and "step 50 " in line and "~7 s" in line, line


# ----------------------------------------------------------------------------- set-up


@pytest.mark.slow  # 10,000 points: about 15 s of set-up on the reference machine
def test_a_long_set_up_says_how_far_it_is_and_a_sigterm_stops_it_within_seconds(tmp_path):
    pts = tmp_path / "points.json"
    pts.write_text(json.dumps([{"name": f"p{i}", "l": 1 + i % 5, "seed": i} for i in range(10_000)]))
    out = tmp_path / "S"
    p = _proc(["sweep", "--points", str(pts), "--preset", "fast", "--num-envs", "8", "--chunk-steps", "100",
               "--hidden-actor", "8", "--hidden-critic", "8", "--steps", "200", "--devices", "1", "--out", str(out)])
    lines = _Lines(p)
    try:
        lines.wait_for(p, "setting up 10,000 points: ", timeout=120)
        t_sig = time.monotonic()
        p.send_signal(signal.SIGTERM)
        p.wait(timeout=60)
        took = time.monotonic() - t_sig
    finally:
        _stop(p)
    err = lines.text()
    assert p.returncode == 143, err[-3000:]
    assert took < 6, (took, err[-3000:])
    assert "Traceback" not in err
    assert not out.exists()


# ----------------------------------------------------------------------------- a full disk at the lock


@pytest.mark.parametrize("cmd", [["train", "--preset", "fast", "--num-envs", "8", "--steps", "100", "--quiet"],
                                 ["study", "--dt", "0.02"]], ids=["train", "study"])
def test_no_space_for_the_lock_file_names_the_path_and_leaves_nothing(tmp_path, monkeypatch, cmd):
    def full(fd, data, offset):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))  # as os.pwrite says it: no file named

    monkeypatch.setattr(lock.os, "pwrite", full)
    out = tmp_path / "new" / "R"
    rc, _, err = _main([*cmd, "--out", str(out)])
    lines = [x for x in err.splitlines() if x.strip()]
    assert rc == exits.IO_FAILED and len(lines) == 1, err
    assert str(out) in lines[0] and "the disk is full" in lines[0]
    assert not (tmp_path / "new").exists()
    assert not lock.held(out)
