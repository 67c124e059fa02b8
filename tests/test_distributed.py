"""Several processes as one run (nmrl/runs/distributed.py, nmrl/runs/launch.py), on 127.0.0.1.

Every test starts real ``nmrl`` processes (``python -m nmrl.cli``), each with one CPU device and
gloo collectives, the way a user starts them on a cluster. Against independent runs:

* (a) a 2-process ``train`` equals a 1-process 2-device ``train`` (same mesh size, the psum of
  the summed update spanning the processes) to float rounding, chunk by chunk;
* (b) a 2-process ``sweep`` gives the 1-process sweep's metrics and results.csv;
* (c) a process killed mid-run takes the other down within a timeout, with a clear error
  (exit 4), and the run's newest checkpoint still resumes;
* (d) a checkpoint written by 2 processes resumes in 1 process and continues as the
  1-process run does;
* bad input (a wrong process id, an unreachable coordinator, processes started with different
  commands) exits 2 with a message naming it, within the timeout, and writes nothing.

The runs share a persistent compilation cache. The tests that compile a training chunk take
minutes on 2 cores and are marked ``slow`` (``pytest -m slow tests/test_distributed.py``); the
default suite runs the ones that need no compile.
"""

from __future__ import annotations

import json
import os
import pathlib
import shutil
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

TINY = ["--num-envs", "8", "--chunk-steps", "25", "--hidden-actor", "8", "--hidden-critic", "8", "--quiet"]
SWEEP = ["--l", "1", "3", "--seeds", "1", "--num-envs", "4", "--chunk-steps", "25", "--hidden-actor", "8",
         "--hidden-critic", "8", "--quiet"]
SKIP_KEYS = {"wall_s", "steps_per_s"}  # the only fields that may differ between two runs


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    """The subprocesses' environment: one compilation cache for the whole module."""
    e = dict(os.environ)
    e.pop("XLA_FLAGS", None)
    e["JAX_PLATFORMS"] = "cpu"
    e.setdefault("JAX_COMPILATION_CACHE_DIR", str(tmp_path_factory.mktemp("jax_cache")))
    return e


def nmrl(args: list[str], env: dict, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "nmrl.cli", *args], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kw)


def dist_args(port: int, pid: int, n: int = 2, timeout: int = 60) -> list[str]:
    return ["--coordinator", f"127.0.0.1:{port}", "--num-processes", str(n), "--process-id", str(pid),
            "--dist-timeout", str(timeout), "--devices", "1"]


def run_processes(cmd: list[str], env: dict, n: int = 2, timeout: int = 60, limit_s: float = 900,
                  extra: dict[int, list[str]] | None = None) -> list[tuple[int, str, str]]:
    """Start ``nmrl <cmd>`` as processes 0..n-1 of one run; (rc, stdout, stderr) of each."""
    port = free_port()
    ps = [nmrl(cmd + dist_args(port, i, n, timeout) + (extra or {}).get(i, []), env) for i in range(n)]
    out = []
    for p in ps:
        try:
            so, se = p.communicate(timeout=limit_s)
        except subprocess.TimeoutExpired:
            for q in ps:
                q.kill()
            raise
        out.append((p.returncode, so, se))
    return out


def metrics(run: pathlib.Path) -> list[dict]:
    return [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]


def assert_rows_close(a: list[dict], b: list[dict], rtol: float = 1e-5, atol: float = 1e-6) -> None:
    assert len(a) == len(b) and a
    for ra, rb in zip(a, b):
        assert set(ra) == set(rb)
        for k in ra:
            if k in SKIP_KEYS:
                continue
            if isinstance(ra[k], float) or isinstance(rb[k], float):
                assert np.isclose(ra[k], rb[k], rtol=rtol, atol=atol), (k, ra[k], rb[k])
            else:
                assert ra[k] == rb[k], (k, ra[k], rb[k])


def single(args: list[str], env: dict, limit_s: float = 900) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "nmrl.cli", *args], env=env, capture_output=True, text=True,
                          timeout=limit_s)


# ----------------------------------------------------------------------------- bad input (default suite)


def test_wrong_process_id_is_refused_at_once(tmp_path, env):
    out = tmp_path / "run"
    t0 = time.time()
    p = single(["train", *TINY, "--steps", "25", "--out", str(out), *dist_args(free_port(), 2, 2)], env, 120)
    assert p.returncode == 2, p.stderr
    assert "--process-id=2 is invalid with --num-processes 2: the ids are 0..1" in p.stderr
    assert not out.exists()
    assert time.time() - t0 < 60


@pytest.mark.parametrize("bad, why", [
    (["--coordinator", "localhost"], "--coordinator='localhost' is invalid: give HOST:PORT"),
    (["--coordinator", "h:70000", "--num-processes", "2", "--process-id", "0"], "a port in 1..65535"),
    (["--coordinator", "h:1234", "--num-processes", "2"], "needs --process-id"),
    (["--num-processes", "2", "--process-id", "0"], "--num-processes needs --coordinator"),
    (["--coordinator", "h:1234", "--num-processes", "0", "--process-id", "0"], "--num-processes=0 is invalid"),
    (["--coordinator", "h:1234", "--num-processes", "2", "--process-id", "0", "--dist-timeout", "0"],
     "--dist-timeout=0 is invalid"),
])
def test_bad_distributed_options(tmp_path, env, bad, why):
    out = tmp_path / "run"
    p = single(["sweep", *SWEEP, "--steps", "25", "--out", str(out), *bad], env, 120)
    assert p.returncode == 2, p.stderr
    assert why in p.stderr
    assert not out.exists()


def test_unreachable_coordinator_fails_within_the_timeout(tmp_path, env):
    """Process 1 alone: nobody listens on the coordinator's port. JAX's runtime aborts the process
    after --dist-timeout; the watcher reports it plainly (exit 2) and nothing is written."""
    out = tmp_path / "run"
    t0 = time.time()
    p = single(["train", *TINY, "--steps", "25", "--out", str(out), *dist_args(free_port(), 1, 2, timeout=5)], env,
               120)
    took = time.time() - t0
    assert p.returncode == 2, p.stderr
    assert "process 1 of 2 could not join the run through the coordinator 127.0.0.1:" in p.stderr
    assert "within --dist-timeout 5 s" in p.stderr and "nothing was written" in p.stderr
    assert "    @ " not in p.stderr  # the C++ stack trace is not passed on
    assert not out.exists()
    assert took < 60, took


def test_processes_with_different_commands_refuse_together(tmp_path, env):
    """Two processes that connect but were given different configs (or counts) must not train."""
    out = tmp_path / "run"
    res = run_processes(["train", *TINY, "--steps", "25", "--out", str(out)], env, timeout=30, limit_s=180,
                        extra={1: ["--seed", "5"]})
    for rc, _, se in res:
        assert rc == 2, se
        assert "the processes were not started with the same command line" in se
        assert "--seed 5" in se and "nothing was written" in se
    assert not out.exists()


@pytest.mark.parametrize("counts", [(2, 3), (3, 2)])
def test_processes_with_different_counts_refuse(tmp_path, env, counts):
    """--num-processes differs: (2, 3) both connect to a 2-process run and refuse the differing
    command lines; (3, 2) process 0 waits for a third process that never comes, so both give up
    after --dist-timeout. Either way exit 2, a message that says why, nothing written."""
    out = tmp_path / "run"
    port = free_port()
    ps = [nmrl(["train", *TINY, "--steps", "25", "--out", str(out)] + dist_args(port, i, n, timeout=10), env)
          for i, n in enumerate(counts)]
    res = [p.communicate(timeout=180) for p in ps]
    for p, (_, se) in zip(ps, res):
        assert p.returncode == 2, se
        if counts == (2, 3):
            assert "not started with the same command line" in se and "--num-processes 3" in se
        else:
            assert "could not join the run through the coordinator" in se
    assert not out.exists()


# ----------------------------------------------------------------------------- runs (slow: they compile)


@pytest.fixture(scope="module")
def train_runs(tmp_path_factory, env):
    """A 2-process run and a 1-process 2-device run of 2 chunks each."""
    d = tmp_path_factory.mktemp("dist_train")
    two, one = d / "two", d / "one"
    res = run_processes(["train", *TINY, "--steps", "50", "--out", str(two)], env, timeout=120)
    assert [rc for rc, _, _ in res] == [0, 0], "\n".join(se for _, _, se in res)
    p = single(["train", *TINY, "--steps", "50", "--devices", "2", "--out", str(one)], env)
    assert p.returncode == 0, p.stderr
    return two, one, res


@pytest.mark.slow
def test_two_process_train_equals_two_devices(train_runs):
    """(a) Equal to float rounding, chunk by chunk; only process 0 wrote the run and printed the summary."""
    two, one, res = train_runs
    assert_rows_close(metrics(two), metrics(one))
    assert len(metrics(two)) == 2
    assert res[0][1].strip() and not res[1][1].strip()  # the JSON summary: process 0 only
    assert "2 processes" not in res[1][2]  # process 1 shows no progress either
    cfg_two = json.loads((two / "config.json").read_text())
    cfg_one = json.loads((one / "config.json").read_text())
    assert cfg_two == cfg_one


@pytest.mark.slow
def test_two_process_checkpoint_resumes_in_one_process(train_runs, tmp_path, env):
    """(d) The 2-process run continued by 1 process (2 devices) equals the 1-process run continued."""
    two, one, _ = train_runs
    a, b = tmp_path / "two", tmp_path / "one"
    shutil.copytree(two, a)
    shutil.copytree(one, b)
    for run in (a, b):
        p = single(["train", "--resume", "--steps", "75", "--devices", "2", "--quiet", "--out", str(run)], env)
        assert p.returncode == 0, p.stderr
    assert len(metrics(a)) == 3
    assert_rows_close(metrics(a), metrics(b))


@pytest.mark.slow
def test_two_process_sweep_equals_one_process(tmp_path, env):
    """(b) The points split over two processes give the 1-process sweep's metrics and results."""
    two, one = tmp_path / "two", tmp_path / "one"
    res = run_processes(["sweep", *SWEEP, "--steps", "50", "--out", str(two)], env, timeout=120)
    assert [rc for rc, _, _ in res] == [0, 0], "\n".join(se for _, _, se in res)
    p = single(["sweep", *SWEEP, "--steps", "50", "--devices", "2", "--out", str(one)], env)
    assert p.returncode == 0, p.stderr
    for name in ("l1_s0", "l3_s0"):
        assert_rows_close(metrics(two / "points" / name), metrics(one / "points" / name))
    from nmrl.runs import store

    ra, rb = store.read_csv(two / "results.csv"), store.read_csv(one / "results.csv")
    assert [(r["l"], r["seed"], r["trials"], r["steps"]) for r in ra] == [(r["l"], r["seed"], r["trials"], r["steps"])
                                                                          for r in rb]
    for x, y in zip(ra, rb):
        assert np.isclose(x["avg_reward"], y["avg_reward"], rtol=1e-5, atol=1e-6)


def start_long_run(out: pathlib.Path, env: dict, timeout: int, rows: int) -> list[subprocess.Popen]:
    """A 2-process ``train`` with a budget it will not reach, once it has written ``rows`` chunks."""
    port = free_port()
    ps = [nmrl(["train", *TINY, "--steps", "100000", "--out", str(out)] + dist_args(port, i, 2, timeout), env)
          for i in range(2)]
    t_end = time.time() + 600
    while time.time() < t_end and not ((out / "metrics.jsonl").exists() and len(metrics(out)) >= rows):
        if not all(p.poll() is None for p in ps):
            for p in ps:
                p.kill()
            raise AssertionError([p.communicate() for p in ps])
        time.sleep(0.5)
    if not (out / "metrics.jsonl").exists() or len(metrics(out)) < rows:
        for p in ps:
            p.kill()
        raise AssertionError(f"no {rows} chunks within 600 s")
    return ps


@pytest.mark.slow
@pytest.mark.parametrize("victim", [1, 0])
def test_killed_process_stops_the_other(train_runs, tmp_path, env, victim):
    """(c) SIGKILL one process's worker mid-run: the other exits 4 with a clear error well within
    the timeout (no hang), and the newest checkpoint resumes in 1 process."""
    out = tmp_path / "run"
    # the program of train_runs' 2-process run: a compilation-cache hit
    ps = start_long_run(out, env, timeout=30, rows=2)
    try:
        # the worker's pid is on its "connected" line; the watcher (ps[victim]) would forward signals
        with open(f"/proc/{ps[victim].pid}/task/{ps[victim].pid}/children") as f:
            child = int(f.read().split()[0])
        t0 = time.time()
        os.kill(child, signal.SIGKILL)
        survivor = ps[1 - victim]
        _, se = survivor.communicate(timeout=120)
        took = time.time() - t0
        ps[victim].communicate(timeout=60)
    finally:
        for p in ps:
            if p.poll() is None:
                p.kill()
    assert survivor.returncode == 4, se
    assert "another process of this distributed run stopped or died" in se
    assert f"process {1 - victim} of 2 was stopped too" in se and "continue with --resume" in se
    assert took < 60, took
    p = single(["train", "--resume", "--steps", str(int(metrics(out)[-1]["step"]) + 25), "--devices", "2",
                "--quiet", "--out", str(out)], env)
    assert p.returncode == 0, p.stderr


@pytest.mark.slow
def test_sigterm_to_one_process_stops_both_after_the_same_chunk(train_runs, tmp_path, env):
    """A signal that reaches only process 1 stops both after one chunk, every process saved (143)."""
    out = tmp_path / "run"
    ps = start_long_run(out, env, timeout=60, rows=1)
    try:
        ps[1].send_signal(signal.SIGTERM)  # the watcher passes it on to its worker
        res = [p.communicate(timeout=120) for p in ps]
    finally:
        for p in ps:
            if p.poll() is None:
                p.kill()
    assert [p.returncode for p in ps] == [143, 143], res
    from nmrl.runs import checkpoint

    assert checkpoint.latest_step(out) == metrics(out)[-1]["step"]


def test_auto_detects_a_slurm_job(tmp_path, env):
    """``--coordinator auto`` under SLURM: JAX reads the job's variables (here faked for a 2-task
    job on this host); both processes connect (ids from SLURM_PROCID) and then refuse together an
    --out that already holds a run (exit 2, nothing changed) -- no compile needed."""
    out = tmp_path / "run"
    out.mkdir()
    (out / "config.json").write_text("{}")
    rng = np.random.default_rng()
    for _ in range(100):  # JAX picks the port 61440 + job id % 4096: a job id whose port is free
        job = int(rng.integers(10**5, 10**6))
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", 61440 + job % 4096))
                break
            except OSError:
                continue
    ps = []
    for i in range(2):
        e = dict(env, SLURM_JOB_ID=str(job), SLURM_STEP_NODELIST="localhost", SLURM_NTASKS="2",
                 SLURM_PROCID=str(i), SLURM_LOCALID=str(i))
        ps.append(nmrl(["train", *TINY, "--steps", "25", "--out", str(out), "--coordinator", "auto",
                        "--dist-timeout", "30", "--devices", "1"], e))
    res = [p.communicate(timeout=180) for p in ps]
    for i, (p, (_, se)) in enumerate(zip(ps, res)):
        assert p.returncode == 2, se
        assert f"nmrl: distributed: connected (process {i} of 2" in se
        assert "already holds a run" in se
    assert sorted(x.name for x in out.iterdir()) == ["config.json"]
