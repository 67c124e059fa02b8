"""Run directories hold under concurrency, full disks, signals at any moment and hostile values.

Black-box: every case runs the ``nmrl`` command (in-process through ``cli.main`` where one process
is enough, as real processes where the case is about processes: two writers, signals, a killed
peer) and compares the sha256 of every file of the directories involved before and after. A
refusal changes nothing and says why in one line with its documented exit status
(nmrl/runs/exits.py): 2 bad input, 5 a disk or file system failure, 6 another writer.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import pathlib
import shutil
import signal
import subprocess
import sys
import time

import pytest

from tests.cli_in_process import run_main as _main
from nmrl.runs import exits, lock, store

T = ["--preset", "fast", "--num-envs", "8", "--chunk-steps", "100", "--hidden-actor", "8", "--hidden-critic", "8"]




def _proc(argv: list[str], **kw) -> subprocess.Popen:
    env = dict(os.environ)
    env.pop("XLA_FLAGS", None)
    return subprocess.Popen([sys.executable, "-m", "nmrl.cli", *argv], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kw)


def snapshot(d: pathlib.Path) -> dict[str, str]:
    """relative path -> sha256 of every file ("dir" for every directory) under ``d``."""
    if not d.exists():
        return {}
    return {p.relative_to(d).as_posix(): "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(d.rglob("*"))}


def one_line(err: str, prefix: str = "nmrl: error: ") -> str:
    lines = [x for x in err.splitlines() if x.strip()]
    assert len(lines) == 1 and lines[0].startswith(prefix), err[-3000:]
    return lines[0]


def _rows(d: pathlib.Path) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in ("wall_s", "steps_per_s")} for r in store.read_metrics(d)]


@pytest.fixture(scope="module")
def run4(tmp_path_factory) -> pathlib.Path:
    """A finished run: 4 chunks of 100 steps (checkpoints 200, 300, 400 kept)."""
    d = tmp_path_factory.mktemp("run4") / "R"
    rc, _, err = _main(["train", *T, "--steps", "400", "--quiet", "--out", str(d)])
    assert rc == 0, err
    return d


def _copy(src: pathlib.Path, dst: pathlib.Path) -> pathlib.Path:
    shutil.copytree(src, dst)
    return dst


# ----------------------------------------------------------------------------- 1. a sweep over foreign points


def test_a_sweep_refuses_points_its_spec_does_not_account_for(run4, tmp_path):
    s = tmp_path / "S"
    _copy(run4, s / "points" / "l10_s0")
    before = snapshot(s)
    rc, _, err = _main(["sweep", *T, "--steps", "200", "--l", "10", "--seeds", "1", "--quiet", "--out", str(s)])
    line = one_line(err)
    assert rc == exits.BAD_INPUT and str(s / "points" / "l10_s0") in line and "sweep.json" in line
    assert snapshot(s) == before


@pytest.mark.slow  # ~35 s cold; by default the same refusal on a first start (test_a_sweep_refuses_points_its_spec_does_not_account_for)
def test_a_sweep_resume_refuses_a_point_outside_its_spec(run4, tmp_path):
    s = tmp_path / "S"
    rc, _, err = _main(["sweep", *T, "--steps", "100", "--l", "10", "--seeds", "1", "--quiet", "--out", str(s)])
    assert rc == 0, err
    _copy(run4, s / "points" / "l20_s0")
    before = snapshot(s)
    rc, _, err = _main(["sweep", "--resume", "--steps", "200", "--quiet", "--out", str(s)])
    line = one_line(err)
    assert rc == exits.BAD_INPUT and "l20_s0" in line
    assert snapshot(s) == before


# ----------------------------------------------------------------------------- 2. one writer per directory


@pytest.mark.slow  # two real training processes (~60 s cold); by default test_reliability starts writers at the same moment on the lock itself
def test_two_writers_started_together_one_is_refused_naming_the_other(tmp_path):
    out = tmp_path / "R"
    ps = [_proc(["train", *T, "--steps", "200", "--seed", str(s), "--quiet", "--out", str(out)]) for s in (0, 1)]
    res = [(p.wait(timeout=900), *p.communicate()) for p in ps]
    rcs = sorted(r[0] for r in res)
    assert rcs == [0, exits.LOCKED], res
    winner = next(i for i, r in enumerate(res) if r[0] == 0)
    loser = res[1 - winner]
    line = one_line(loser[2])
    assert f"pid {ps[winner].pid}" in line and "is being written by another nmrl process" in line
    assert json.loads((out / "config.json").read_text())["seed"] == winner
    assert [r["step"] for r in store.read_metrics(out)] == [100, 200]


def test_a_resume_while_another_process_writes_is_refused(run4, tmp_path):
    d = _copy(run4, tmp_path / "R")
    holder = subprocess.Popen([sys.executable, "-c", "import sys, time\nfrom nmrl.runs import lock\n"
                               "h = lock.hold(sys.argv[1]); print('held', flush=True); time.sleep(600)", str(d)],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        before = snapshot(d)
        rc, _, err = _main(["train", "--resume", "--steps", "500", "--quiet", "--out", str(d)])
        assert rc == exits.LOCKED and f"pid {holder.pid}" in one_line(err)
        assert snapshot(d) == before
    finally:
        holder.kill()
        holder.wait()
    rc, _, err = _main(["train", "--resume", "--steps", "500", "--quiet", "--out", str(d)])
    assert rc == 0, err
    assert not (d / lock.LOCK_FILE).exists()


# ----------------------------------------------------------------------------- 3. signals before the first chunk


@pytest.mark.slow  # a cold compile (a network size no other test uses), about a minute on 2 cores
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_during_compile_exits_cleanly_and_leaves_nothing(tmp_path, sig):
    out = tmp_path / "R"
    argv = ["train", "--preset", "fast", "--num-envs", "8", "--chunk-steps", "100", "--hidden-actor", "7",
            "--hidden-critic", str(7 + int(sig)), "--steps", "200", "--out", str(out)]
    env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=str(tmp_path / "cold-cache"))
    env.pop("XLA_FLAGS", None)
    p = subprocess.Popen([sys.executable, "-m", "nmrl.cli", *argv], env=env, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    lines = []
    for line in p.stderr:
        lines.append(line)
        if line.startswith("train:"):
            break
    time.sleep(3)
    p.send_signal(sig)
    rest_out, rest_err = p.communicate(timeout=900)
    err = "".join(lines) + rest_err
    assert p.returncode == 128 + sig, err
    assert "Traceback" not in err and "Fatal Python error" not in err
    assert f"signal {int(sig)}: the command stops when the compile returns" in err
    assert f"stopped by signal {int(sig)} before the first chunk; nothing of the run was written" in err
    assert not out.exists()
    q = subprocess.run([sys.executable, "-m", "nmrl.cli", *argv, "--quiet"], env=env, capture_output=True,
                       text=True, timeout=900)
    assert q.returncode == 0, q.stderr
    assert [r["step"] for r in store.read_metrics(out)] == [100, 200]


# ----------------------------------------------------------------------------- 4, 10. absurd sizes, failed starts


@pytest.mark.parametrize("opt, value", [("--hidden-actor", "1000000000"), ("--num-envs", "100000000")])
def test_absurd_sizes_are_refused_before_anything_is_allocated(tmp_path, opt, value):
    out = tmp_path / "R"
    argv = ["train", *T, "--steps", "200", opt, value, "--quiet", "--out", str(out)]
    t0 = time.time()
    rc, _, err = _main(argv)
    line = one_line(err)
    assert rc == exits.BAD_INPUT and time.time() - t0 < 120
    assert f"{opt[2:].replace('-', '_')}={value}" in line and "GiB" in line and "this machine's" in line
    assert not out.exists()
    rc, _, err = _main(["train", *T, "--steps", "100", "--quiet", "--out", str(out)])  # the next attempt starts
    assert rc == 0, err


# ----------------------------------------------------------------------------- 5. a truncated last metrics row


def test_a_truncated_last_metrics_row_is_dropped_with_a_warning_and_the_run_continues(run4, tmp_path):
    d = _copy(run4, tmp_path / "R")
    m = d / "metrics.jsonl"
    text = m.read_text()
    m.write_text(text[:-40])  # a crash while appending the row of chunk 4 (its checkpoint, 400, is there)
    rc, _, err = _main(["train", "--resume", "--steps", "500", "--quiet", "--out", str(d)])
    assert rc == 0, err
    warn = [x for x in err.splitlines() if x.strip()]
    assert len(warn) == 1 and warn[0].startswith("nmrl: warning: ") and str(m) in warn[0], err
    ref = _copy(run4, tmp_path / "ref")
    rc, _, err = _main(["train", "--resume", "--steps", "500", "--quiet", "--out", str(ref)])
    assert rc == 0, err
    # the lost row's chunk ran again from checkpoint 300: the metrics equal the intact run's, row for row
    assert [r["step"] for r in _rows(d)] == [100, 200, 300, 400, 500] and _rows(d) == _rows(ref)
    assert json.loads((d / "resumes.jsonl").read_text().splitlines()[-1])["from_step"] == 300


def test_other_metrics_damage_is_one_line(run4, tmp_path):
    d = _copy(run4, tmp_path / "R")
    lines = (d / "metrics.jsonl").read_text().splitlines(True)
    lines[1] = lines[1][:30] + "\n"
    (d / "metrics.jsonl").write_text("".join(lines))
    before = snapshot(d)
    rc, _, err = _main(["train", "--resume", "--steps", "500", "--quiet", "--out", str(d)])
    line = one_line(err)
    assert rc == exits.BAD_INPUT and "metrics.jsonl: line 2 is not valid JSON" in line
    assert snapshot(d) == before


# ----------------------------------------------------------------------------- 6, 7. disk and file system failures


def _mount(*args: str) -> bool:
    return os.geteuid() == 0 and shutil.which("mount") is not None and \
        subprocess.run(["mount", *args], capture_output=True).returncode == 0


@pytest.fixture
def tmpfs(tmp_path):
    d = tmp_path / "fs"
    d.mkdir()
    if not _mount("-t", "tmpfs", "-o", "size=48m", "tmpfs", str(d)):
        pytest.skip("needs root with CAP_SYS_ADMIN to mount a tmpfs")
    yield d
    subprocess.run(["umount", "-l", str(d)], capture_output=True)


def test_a_full_disk_during_a_save_is_one_line_and_loses_nothing(tmpfs):
    out = tmpfs / "R"
    p = _proc(["train", *T, "--steps", "5000", "--quiet", "--devices", "1", "--out", str(out)])
    try:
        t0 = time.time()
        while not (out / "checkpoints" / "100").is_dir():
            assert p.poll() is None and time.time() - t0 < 600, p.communicate()[1][-3000:]
            time.sleep(0.1)
        filler = tmpfs / "filler"
        with open(filler, "wb") as f:  # fill the disk
            with contextlib.suppress(OSError):
                while True:
                    f.write(b"\0" * (1 << 20))
        _, err = p.communicate(timeout=600)
    finally:
        if p.poll() is None:
            p.kill()
    line = one_line(err)
    assert p.returncode == exits.IO_FAILED and "the disk is full" in line and str(out) in line
    assert not [x for x in (out / "checkpoints").iterdir() if "tmp" in x.name]
    good = max(int(x.name) for x in (out / "checkpoints").iterdir())
    filler.unlink()
    rc, _, err = _main(["train", "--resume", "--steps", str(good + 100), "--quiet", "--out", str(out)])
    assert rc == 0, err
    assert [r["step"] for r in store.read_metrics(out)][-1] == good + 100


@pytest.fixture
def read_only(run4, tmp_path):
    src = _copy(run4, tmp_path / "R")
    ro = tmp_path / "ro"
    ro.mkdir()
    if not _mount("--bind", str(src), str(ro)):
        pytest.skip("needs root with CAP_SYS_ADMIN for a read-only bind mount")
    if not _mount("-o", "remount,ro,bind", str(ro)):
        subprocess.run(["umount", "-l", str(ro)])
        pytest.skip("cannot remount read-only")
    yield ro
    subprocess.run(["umount", "-l", str(ro)], capture_output=True)


def test_a_read_only_run_is_refused_in_one_line(read_only):
    before = snapshot(read_only)
    rc, _, err = _main(["train", "--resume", "--steps", "500", "--quiet", "--out", str(read_only)])
    line = one_line(err)
    assert rc == exits.IO_FAILED and "read-only" in line and str(read_only) in line
    t0 = time.time()
    rc, _, err = _main(["eval", str(read_only), "--seconds", "5"])
    line = one_line(err)
    assert rc == exits.IO_FAILED and "read-only" in line and str(read_only / "eval") in line
    assert time.time() - t0 < 30  # refused before the rollouts (and their compile)
    assert snapshot(read_only) == before


def test_an_immutable_run_is_refused_in_one_line(run4, tmp_path):
    d = _copy(run4, tmp_path / "R")
    if subprocess.run(["chattr", "+i", str(d)], capture_output=True).returncode != 0:
        pytest.skip("chattr +i is not available here")
    try:
        before = snapshot(d)
        rc, _, err = _main(["train", "--resume", "--steps", "500", "--quiet", "--out", str(d)])
        line = one_line(err)
        assert rc == exits.IO_FAILED and "immutable" in line and str(d) in line
        assert snapshot(d) == before
    finally:
        subprocess.run(["chattr", "-i", str(d)], capture_output=True)


# ----------------------------------------------------------------------------- 8, 9, 11. hostile values


@pytest.mark.parametrize("argv, needle", [
    (["train", *T, "--l", "nan"], "--l='nan' is invalid: must be an integer"),
    (["train", *T, "--num-envs", "1.5"], "--num-envs='1.5' is invalid: must be an integer"),
    (["train", *T, "--seed", "1e300"], "--seed='1e300' is invalid: must be an integer"),
    (["sweep", *T, "--l", "1", "nan", "--seeds", "1"], "--l='nan' is invalid: must be an integer"),
    (["study", "--seeds", "1.5"], "--seeds='1.5' is invalid: must be an integer"),
    (["study", "--trials", "-5"], "unknown option(s) --trials -5"),
    (["train", *T, "--sigma", "1e300"], "sigma=1e+300 is invalid: must be a finite number in float32"),
    (["train", *T, "--beta-theta", "1e300"], "beta_theta=1e+300 is invalid: must be a finite number in float32"),
    (["train", *T, "--control-dt", "1e300"], "control_dt=1e+300 is invalid: must be a finite number in float32"),
    (["train", *T, "--control-dt", "2"], "control_dt=2.0 is invalid: must be in (0, 1]"),
])
def test_hostile_values_are_one_line_and_write_nothing(tmp_path, argv, needle):
    out = tmp_path / "X"
    rc, _, err = _main([*argv, "--out", str(out)])
    line = one_line(err, prefix="nmrl")
    assert rc == exits.BAD_INPUT and needle in line and ": error: " in line
    assert not out.exists()


def test_a_study_into_a_file_is_one_line(tmp_path):
    f = tmp_path / "F"
    f.write_text("x")
    rc, _, err = _main(["study", "--out", str(f), "--dt", "0.02", "--periods", "stationary"])
    assert rc == exits.BAD_INPUT and "exists and is not a directory" in one_line(err, prefix="nmrl study: error: ")
    assert f.read_text() == "x"


# ----------------------------------------------------------------------------- 13. an edited config.json


def test_an_edited_config_names_no_checkpoint_with_the_same_mismatch(run4, tmp_path):
    d = _copy(run4, tmp_path / "R")
    cfg = json.loads((d / "config.json").read_text())
    cfg["seed"] = 7
    (d / "config.json").write_text(json.dumps(cfg, indent=2))
    before = snapshot(d)
    rc, _, err = _main(["train", "--resume", "--steps", "500", "--quiet", "--out", str(d)])
    line = one_line(err)
    assert rc == exits.BAD_INPUT and "seed=0 in the checkpoint but 7" in line
    assert "--step" not in line and "config.json" in line
    assert snapshot(d) == before


# ----------------------------------------------------------------------------- 12. a distributed peer killed


@pytest.mark.slow  # two processes, a compile each (minutes on 2 cores)
def test_a_killed_peer_gives_the_documented_message_without_native_logs(tmp_path):
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    out = tmp_path / "R"
    ps = [_proc(["train", *T, "--steps", "100000", "--quiet", "--devices", "1", "--coordinator",
                 f"127.0.0.1:{port}", "--num-processes", "2", "--process-id", str(i), "--dist-timeout", "30",
                 "--out", str(out)]) for i in range(2)]
    try:
        t0 = time.time()
        while not (out / "checkpoints" / "200").is_dir():
            assert time.time() - t0 < 900 and all(p.poll() is None for p in ps)
            time.sleep(0.5)
        with open(f"/proc/{ps[1].pid}/task/{ps[1].pid}/children") as f:
            os.kill(int(f.read().split()[0]), signal.SIGKILL)
        _, err = ps[0].communicate(timeout=120)
    finally:
        for p in ps:
            if p.poll() is None:
                p.kill()
    assert ps[0].returncode == exits.PEER_FAILED, err
    lines = [x for x in err.splitlines() if x.strip() and not x.startswith("nmrl: distributed: connected")]
    assert len(lines) == 1 and "another process of this distributed run stopped or died" in lines[0], err


# ----------------------------------------------------------------------------- the documented statuses


def test_the_exit_status_table_lists_every_status():
    doc = (pathlib.Path(__file__).resolve().parents[1] / "docs" / "runs.md").read_text()
    rows = {int(line.split("|")[1]) for line in doc.splitlines() if line.startswith("| ") and
            line.split("|")[1].strip().isdigit()}
    assert rows == set(exits.TABLE), sorted(rows ^ set(exits.TABLE))
