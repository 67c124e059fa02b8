"""Values, paths and directories that must not slip through, as a user meets them on the command line.

Black-box: each case runs the ``nmrl`` command (in-process through ``cli.main``, or as a real
process where the case is about processes or memory) and checks its exit status, its one line
and the files of the directories involved. A refusal writes nothing.
"""

from __future__ import annotations

import os
import pathlib
import subprocess
import sys
import time

import pytest

from tests.cli_in_process import run_main as _main
from nmrl import options
from nmrl.runs import exits

T = ["--preset", "fast", "--num-envs", "4", "--chunk-steps", "100", "--hidden-actor", "8", "--hidden-critic", "8"]




#: ``python -c`` that runs ``nmrl <its arguments>`` with its address space capped at 8 GiB: a run that
#: enumerates billions of points fails there instead of taking the machine (set in the child itself,
#: since a ``preexec_fn`` would fork this process, which runs JAX's threads)
_LIMITED_MEMORY = ("import resource, runpy, sys; resource.setrlimit(resource.RLIMIT_AS, (8 << 30, 8 << 30)); "
                   "sys.argv = ['nmrl', *sys.argv[1:]]; runpy.run_module('nmrl.cli', run_name='__main__')")


def _run(argv: list[str], timeout: float = 300, cwd: str | None = None) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env.pop("XLA_FLAGS", None)
    return subprocess.run([sys.executable, "-m", "nmrl.cli", *argv], env=env, capture_output=True, text=True,
                          timeout=timeout, cwd=cwd)


def one_line(err: str, prefix: str = "nmrl: error: ") -> str:
    lines = [x for x in err.splitlines() if x.strip()]
    assert len(lines) == 1 and lines[0].startswith(prefix), err[-3000:]
    return lines[0]


# ----------------------------------------------------------------------------- sweep values within bounds


@pytest.mark.parametrize("opts, needle", [
    (["--vary", "sigma", "1", "11", "--l", "10"], "sigma=11.0 is invalid: must be in (0, 10]"),
    (["--vary", "sigma", "1e300", "--l", "10"], "sigma=1e+300 is invalid: must be a finite number in float32"),
    (["--vary", "beta_theta", "2", "--l", "10"], "beta_theta=2.0 is invalid: must be in [0, 1]"),
    (["--sigma", "11", "--l", "10"], "sigma=11.0 is invalid: must be in (0, 10]"),
    (["--l", "10", "--seeds", "99999999999"], "seeds=99999999999 is invalid"),
])
def test_sweep_values_are_held_to_the_bounds_of_train(tmp_path, opts, needle):
    out = tmp_path / "S"
    rc, _, err = _main(["sweep", *T, "--steps", "100", "--quiet", *opts, "--out", str(out)])
    line = one_line(err)
    assert rc == exits.BAD_INPUT and needle in line, line
    assert not out.exists()


def test_a_sweep_of_billions_of_points_is_refused_by_the_memory_estimate(tmp_path):
    out = tmp_path / "S"
    t0 = time.time()
    env = dict(os.environ)
    env.pop("XLA_FLAGS", None)
    p = subprocess.run([sys.executable, "-c", _LIMITED_MEMORY, "sweep", *T, "--steps", "100", "--quiet", "--l", "10",
                        "--seeds", str(2**32), "--out", str(out)], env=env, capture_output=True, text=True,
                       timeout=300)
    line = one_line(p.stderr)
    assert p.returncode == exits.BAD_INPUT and "4294967296 points" in line and "GiB" in line, line
    assert time.time() - t0 < 120
    assert not out.exists()


# ----------------------------------------------------------------------------- paths a command may write


def _listing(d: pathlib.Path) -> list[str]:
    return sorted(p.relative_to(d).as_posix() for p in d.rglob("*"))


@pytest.mark.parametrize("cmd", [["train", *T, "--steps", "100"], ["sweep", *T, "--steps", "100", "--l", "10",
                                                                    "--seeds", "1"],
                                 ["study", "--phases", "plot"]])
@pytest.mark.parametrize("out, needle", [("", "--out='' is invalid: give a directory path"),
                                         ("/", "--out='/' is invalid: it is the file system's root")])
def test_an_empty_out_and_the_root_are_refused(tmp_path, monkeypatch, cmd, out, needle):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine.txt").write_text("a user's file\n")
    root = set(os.listdir("/"))
    rc, _, err = _main([*cmd, "--quiet", "--out", out])
    line = one_line(err, prefix="nmrl")
    assert rc == exits.BAD_INPUT and needle in line, line
    assert _listing(tmp_path) == ["mine.txt"] and set(os.listdir("/")) == root


@pytest.mark.parametrize("cmd", [["train", *T, "--steps", "100"], ["sweep", *T, "--steps", "100", "--l", "10",
                                                                    "--seeds", "1"]])
def test_a_fresh_start_refuses_a_directory_holding_other_files(tmp_path, cmd):
    out = tmp_path / "photos"
    out.mkdir()
    (out / "holiday.jpg").write_bytes(b"\xff\xd8")
    rc, _, err = _main([*cmd, "--quiet", "--out", str(out)])
    line = one_line(err)
    assert rc == exits.BAD_INPUT and "holiday.jpg" in line and "new or empty directory" in line, line
    assert _listing(out) == ["holiday.jpg"]


@pytest.mark.parametrize("argv", [
    ["train", *T, "--steps", "100", "--out", "{tmp}/" + "d/" * 2500],
    ["train", *T, "--steps", "100", "--out", "{tmp}/" + "n" * 300],
    ["sweep", *T, "--steps", "100", "--l", "10", "--seeds", "1", "--out", "{tmp}/" + "n" * 300],
    ["eval", "{tmp}/" + "n" * 300],
    ["eval", "{tmp}", "--out", "{tmp}/" + "n" * 300],
    ["study", "--phases", "plot", "--out", "{tmp}/file/sub"],
])
def test_paths_the_file_system_cannot_take_are_one_line(tmp_path, argv):
    (tmp_path / "file").write_text("a file\n")
    rc, _, err = _main([a.replace("{tmp}", str(tmp_path)) for a in argv])
    line = one_line(err, prefix="nmrl")
    assert rc == exits.BAD_INPUT and "is invalid" in line and len(line) < 400, line
    assert _listing(tmp_path) == ["file"]


# ----------------------------------------------------------------------------- a run of another learner


def _started(d: pathlib.Path, cfg) -> pathlib.Path:
    """A run directory as a start killed before its first chunk leaves it: config.json alone."""
    from nmrl.runs import store

    store.write_config(d, cfg.resolved())
    return d


def _snapshot(d: pathlib.Path) -> dict[str, bytes]:
    return {p.relative_to(d).as_posix(): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("run, opts", [("ppo", ["--learner", "ac", "--l", "5"]),
                                       ("ac", ["--learner", "ppo", "--epochs", "2"])])
def test_a_resume_with_another_learners_options_is_one_line(tmp_path, run, opts):
    from nmrl.learners.ppo_config import PPOConfig
    from nmrl.learners.ac_config import TrainConfig

    d = _started(tmp_path / run, options.build(PPOConfig, num_envs=4) if run == "ppo"
                 else options.build(TrainConfig, preset="fast", num_envs=4))
    before = _snapshot(d)
    rc, _, err = _main(["train", "--resume", *opts, "--quiet", "--out", str(d)])
    line = one_line(err)
    assert rc == exits.BAD_INPUT and f"its own learner {run!r}" in line, line
    assert _snapshot(d) == before


def test_a_sweep_resume_with_a_point_of_another_learner_is_one_line(tmp_path):
    from nmrl.learners.ppo_config import PPOConfig

    s = tmp_path / "S"
    rc, _, err = _main(["sweep", *T, "--steps", "100", "--l", "10", "--seeds", "1", "--quiet", "--out", str(s)])
    assert rc == 0, err
    point = s / "points" / "l10_s0"
    for f in point.iterdir():
        if f.is_file():
            f.unlink()
        else:
            import shutil

            shutil.rmtree(f)
    _started(point, options.build(PPOConfig, num_envs=4))
    before = _snapshot(s)
    rc, _, err = _main(["sweep", "--resume", "--steps", "200", "--quiet", "--out", str(s)])
    line = one_line(err)
    assert rc == exits.BAD_INPUT and str(point) in line and "'ppo'" in line, line
    assert _snapshot(s) == before


# ----------------------------------------------------------------------------- directories that can be continued


def test_a_run_killed_during_its_first_save_is_continued_by_resume_from_the_start(tmp_path):
    out = tmp_path / "R"
    rc, _, err = _main(["train", *T, "--steps", "100", "--quiet", "--out", str(out)])
    assert rc == 0, err
    first = (out / "metrics.jsonl").read_text().splitlines()
    # what a kill during the first save leaves: config.json, the chunk's row, orbax's unfinished step
    (out / "checkpoints" / "100").rename(out / "checkpoints" / "100.orbax-checkpoint-tmp")
    rc, _, err = _main(["train", *T, "--steps", "100", "--quiet", "--out", str(out)])
    assert rc == exits.BAD_INPUT and "--resume" in one_line(err)
    rc, _, err = _main(["train", "--resume", "--steps", "200", "--quiet", "--out", str(out)])
    assert rc == 0, err
    assert "no checkpoint yet" in err and "starts again from step 0" in err
    rows = (out / "metrics.jsonl").read_text().splitlines()
    assert len(rows) == 2 and _drop_times(rows[0]) == _drop_times(first[0])  # the same first chunk, again
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == ["100", "200"]


def _drop_times(line: str) -> dict:
    import json

    return {k: v for k, v in json.loads(line).items() if k not in ("wall_s", "steps_per_s")}


def test_a_sweep_resume_starts_a_deleted_point_fresh_and_continues_the_others(tmp_path):
    import json
    import shutil

    s = tmp_path / "S"
    rc, _, err = _main(["sweep", *T, "--steps", "100", "--l", "10", "--seeds", "2", "--quiet", "--out", str(s)])
    assert rc == 0, err
    kept = (s / "points" / "l10_s0" / "metrics.jsonl").read_text()
    gone = (s / "points" / "l10_s1" / "metrics.jsonl").read_text().splitlines()
    shutil.rmtree(s / "points" / "l10_s1")
    rc, _, err = _main(["sweep", "--resume", "--steps", "200", "--quiet", "--out", str(s)])
    assert rc == 0, err
    assert "l10_s1" in err and "starts fresh" in err
    assert (s / "points" / "l10_s0" / "metrics.jsonl").read_text().startswith(kept)
    again = (s / "points" / "l10_s1" / "metrics.jsonl").read_text().splitlines()
    assert [json.loads(r)["step"] for r in again] == [100, 200]
    assert _drop_times(again[0]) == _drop_times(gone[0])


# ----------------------------------------------------------------------------- one eval, one set of outputs

SET = ["eval.json", "gait.gif", "strobe.png", "trajectory.npz"]


@pytest.fixture(scope="module")
def run2(tmp_path_factory) -> pathlib.Path:
    """A finished run with checkpoints at steps 100 and 200."""
    d = tmp_path_factory.mktemp("run2") / "R"
    rc, _, err = _main(["train", *T, "--steps", "200", "--quiet", "--out", str(d)])
    assert rc == 0, err
    return d


def _eval_set(d: pathlib.Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(d.iterdir()) if p.is_file()}


def test_an_eval_without_pictures_leaves_no_pictures_of_an_earlier_eval(run2, tmp_path):
    import shutil

    run = tmp_path / "R"
    shutil.copytree(run2, run)
    rc, _, err = _main(["eval", str(run), "--step", "100", "--seconds", "1"])
    assert rc == 0, err
    assert sorted(os.listdir(run / "eval")) == SET
    rc, _, err = _main(["eval", str(run), "--step", "200", "--seconds", "1", "--no-render"])
    assert rc == 0, err
    assert sorted(os.listdir(run / "eval")) == ["eval.json"]


@pytest.mark.slow  # three evals, one of them a real process killed while it writes (~1 min)
def test_an_eval_killed_while_it_writes_leaves_one_set_and_the_next_eval_cleans_up(run2, tmp_path):
    import json
    import shutil
    import signal

    run = tmp_path / "R"
    shutil.copytree(run2, run)
    ev = run / "eval"
    rc, _, err = _main(["eval", str(run), "--step", "100", "--seconds", "2"])
    assert rc == 0, err
    old = _eval_set(ev)
    env = dict(os.environ)
    env.pop("XLA_FLAGS", None)
    p = subprocess.Popen([sys.executable, "-m", "nmrl.cli", "eval", str(run), "--step", "200", "--seconds", "2"],
                         env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        t0 = time.time()
        while not [n for n in os.listdir(ev) if n.startswith(".") and n != ".nmrl.lock"]:  # it writes
            assert p.poll() is None and time.time() - t0 < 300
            time.sleep(0.005)
        time.sleep(0.05)
        p.send_signal(signal.SIGKILL)
    finally:
        p.kill()
        p.wait()
    left = _eval_set(ev)
    if "eval.json" in left:  # the old set, whole
        assert {k: v for k, v in left.items() if k in SET} == old
    rc, _, err = _main(["eval", str(run), "--step", "200", "--seconds", "2"])
    assert rc == 0, err
    assert sorted(os.listdir(ev)) == SET
    assert json.loads((ev / "eval.json").read_text())["step"] == 200


# ----------------------------------------------------------------------------- a signal in the first seconds


def _signalled(argv: list[str], delays: list[float], sig: int) -> tuple[int, str, float]:
    """Start ``nmrl argv`` and send ``sig`` after each of ``delays`` seconds (from the start);
    returns the exit status, stderr and the seconds from the last signal to the exit."""
    import signal as _  # noqa: F401

    env = dict(os.environ)
    env.pop("XLA_FLAGS", None)
    t0 = time.time()
    p = subprocess.Popen([sys.executable, "-m", "nmrl.cli", *argv], env=env, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    for d in delays:
        time.sleep(max(0.0, t0 + d - time.time()))
        p.send_signal(sig)
    t1 = time.time()
    _, err = p.communicate(timeout=300)
    return p.returncode, err, time.time() - t1


def _check_stopped_early(rc: int, err: str, out: pathlib.Path, sig: int) -> None:
    assert rc == 128 + sig, err
    assert "Traceback" not in err and "Exception ignored" not in err, err
    assert len([x for x in err.splitlines() if x.strip()]) <= 4, err
    assert "nothing" in err.splitlines()[-1] and "was written" in err.splitlines()[-1], err
    assert not out.exists()


@pytest.mark.parametrize("cmd", [["train"], ["sweep", "--l", "10", "--seeds", "1"]])
def test_a_signal_in_the_first_second_stops_the_command_at_once(tmp_path, cmd):
    import signal

    out = tmp_path / "R"
    rc, err, took = _signalled([*cmd, *T, "--steps", "100", "--out", str(out)], [1.0], signal.SIGINT)
    _check_stopped_early(rc, err, out, signal.SIGINT)
    assert took < 30  # not after a compile


@pytest.mark.slow  # ten starts stopped early, and one stopped twice during its compile (~1-2 min)
def test_signals_at_any_moment_of_the_start_never_train_and_never_print_a_traceback(tmp_path):
    import signal

    for i, (d, sig) in enumerate([(0.2, signal.SIGINT), (0.5, signal.SIGTERM), (0.8, signal.SIGINT),
                                  (1.2, signal.SIGINT), (1.6, signal.SIGTERM), (2.0, signal.SIGINT),
                                  (2.5, signal.SIGINT), (3.0, signal.SIGTERM), (4.0, signal.SIGINT),
                                  (6.0, signal.SIGINT)]):
        out = tmp_path / f"R{i}"
        rc, err, _ = _signalled(["train", *T, "--steps", "100", "--out", str(out)], [d], sig)
        _check_stopped_early(rc, err, out, sig)
    out = tmp_path / "twice"
    argv = ["train", "--preset", "fast", "--num-envs", "4", "--chunk-steps", "100", "--hidden-actor", "5",
            "--hidden-critic", "11", "--steps", "100", "--out", str(out)]  # sizes no other test compiles
    env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=str(tmp_path / "cold-cache"))
    env.pop("XLA_FLAGS", None)
    p = subprocess.Popen([sys.executable, "-m", "nmrl.cli", *argv], env=env, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    for line in p.stderr:
        if line.startswith("train:"):
            break
    time.sleep(1)
    p.send_signal(signal.SIGINT)
    time.sleep(1)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=300)
    assert p.returncode == 130, err
    assert "second signal 2 while compiling; nothing of the run was written" in err and "checkpoint" not in err
    assert not out.exists()


# ----------------------------------------------------------------------------- thousands of environments on 2 devices


@pytest.mark.slow  # 4,096 environments on each physics (~2 min)
@pytest.mark.parametrize("physics", ["mjx", "c"])
def test_thousands_of_environments_on_two_devices_train_to_the_end(tmp_path, physics):
    """4,096 environments on the CLI's default layout (one device per core) finish their chunk and
    save it; they used to wait for ever after compiling (MJX: the batched Cholesky, C: the
    callback's operands), every worker idle."""
    out = tmp_path / "R"
    p = _run(["train", "--preset", "fast", "--hidden-actor", "8", "--hidden-critic", "8", "--steps", "100",
              "--chunk-steps", "100", "--num-envs", "4096", "--physics", physics, "--out", str(out)], timeout=400)
    assert p.returncode == 0, p.stderr[-3000:]
    assert "4096 environments on 2 device(s)" in p.stderr or os.cpu_count() < 2, p.stderr[-2000:]
    rows = [ln for ln in (out / "metrics.jsonl").read_text().splitlines() if ln.strip()]
    assert len(rows) == 1 and '"step": 100' in rows[0]
