"""A run directory cannot be silently mixed, overwritten or crashed.

Every case runs the ``nmrl`` command in-process (``cli.main``) on a copy of one small real run
(8 environments, 25-step chunks, 3 chunks: checkpoints 25, 50, 75) and compares the sha256 of every
file of the run directory before and after: a refusal changes nothing, a resume changes only what
it says it changes. Refusals exit with status 2 and exactly one line ``nmrl: error: ...`` on
stderr naming the value (no traceback, no library noise).
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import pathlib
import re
import shutil
import signal
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nmrl import cli, options
from nmrl.runs import checkpoint, driver as run, loop, signals
from nmrl.analysis import evaluate
from nmrl.learners.ac_config import TrainConfig
from nmrl.learners.ac_train import make_train

TINY = ["--num-envs", "8", "--chunk-steps", "25", "--hidden-actor", "8", "--hidden-critic", "8", "--quiet"]
EVAL = ["--seconds", "1", "--no-render"]


def _main(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = cli.main(argv)
    return rc, out.getvalue(), err.getvalue()


def snapshot(d: pathlib.Path, skip: tuple[str, ...] = ()) -> dict[str, str]:
    """relative path -> sha256 of every file ("dir" for every directory) under ``d``."""
    snap = {}
    for p in sorted(d.rglob("*")):
        rel = p.relative_to(d).as_posix()
        if rel.split("/")[0] in skip:
            continue
        snap[rel] = "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
    return snap


def one_error_line(err: str) -> str:
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("nmrl: error: "), err[-3000:]
    return lines[0]


def _without_timing(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in ("wall_s", "steps_per_s")} for r in rows]


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> dict:
    """The run A: ``--steps 70`` (rounded up to 3 chunks of 25: step 75)."""
    a = tmp_path_factory.mktemp("base") / "A"
    rc, out, err = _main(["train", *TINY, "--steps", "70", "--out", str(a)])
    assert rc == 0, err
    return {"dir": a, "stdout": out, "stderr": err}


@pytest.fixture(scope="module")
def foreign_same_shape(tmp_path_factory) -> pathlib.Path:
    """Another run with the same array shapes (l = 5, seed 1): restoring it would succeed silently."""
    b = tmp_path_factory.mktemp("foreign") / "B"
    rc, _, err = _main(["train", *TINY, "--steps", "75", "--l", "5", "--seed", "1", "--out", str(b)])
    assert rc == 0, err
    return b


@pytest.fixture(scope="module")
def foreign_16_envs(tmp_path_factory) -> pathlib.Path:
    """A checkpoint at step 75 of a 16-environment run with 1000-step chunks (the issue's case)."""
    c = tmp_path_factory.mktemp("foreign16") / "C"
    cfg = options.build(TrainConfig, num_envs=16, chunk_steps=1000, hidden_actor=8, hidden_critic=8, steps=2000).resolved()
    tr = make_train(cfg)
    ts = jax.jit(tr.init)(jax.random.PRNGKey(0))
    checkpoint.save(c, ts.replace(step=jnp.int32(75)), cfg)
    return c


def _copy(base: dict, tmp_path: pathlib.Path) -> pathlib.Path:
    d = tmp_path / "D"
    shutil.copytree(base["dir"], d)
    return d


# ----------------------------------------------------------------------------- the run itself


def test_budget_rounding_is_said_and_rows_agree_with_config(base):
    a = base["dir"]
    note = ("note: the budget of 70 steps is not a whole number of chunks of 25: the run stops after whole "
            "chunks, at step 75")
    assert base["stderr"].splitlines() == [note]
    cfg = json.loads((a / "config.json").read_text())
    rows = run.read_metrics(a)
    assert [r["step"] for r in rows] == [25, 50, 75]
    assert all(r["total_steps"] == r["step"] * cfg["num_envs"] for r in rows)
    assert checkpoint.all_steps(a) == [25, 50, 75]
    meta = checkpoint.load_metadata(a)
    assert meta["identity"] == checkpoint.identity_digest(checkpoint.load_run_config(a), meta["model_sha256"])
    assert json.loads(base["stdout"])["avg_reward_first_chunk"] == rows[0]["avg_reward"]


# ----------------------------------------------------------------------------- 1. a foreign checkpoint


@pytest.mark.parametrize("which,needles", [
    ("foreign_same_shape", ["l=5 in the checkpoint but 10 in", "seed=1 in the checkpoint but 0 in"]),
    ("foreign_16_envs", ["num_envs=16 in the checkpoint but 8 in", "chunk_steps=1000 in the checkpoint but 25 in"]),
])
def test_foreign_checkpoint_is_refused_by_resume_and_eval(base, tmp_path, request, which, needles):
    d = _copy(base, tmp_path)
    shutil.rmtree(d / "checkpoints" / "75")
    shutil.copytree(request.getfixturevalue(which) / "checkpoints" / "75", d / "checkpoints" / "75")
    before = snapshot(d)
    for argv in (["train", "--resume", "--out", str(d), "--quiet"], ["eval", str(d), *EVAL]):
        rc, out, err = _main(argv)
        line = one_error_line(err)
        assert rc == 2 and out == "", argv
        assert f"{d}/checkpoints/75: checkpoint of another run" in line, line
        for n in needles:
            assert f"{n} {d}/config.json" in line, line
    assert snapshot(d) == before
    # the run's own older checkpoint is still usable, on request
    rc, out, err = _main(["eval", str(d), "--step", "50", *EVAL])
    assert rc == 0 and err == "" and json.loads(out)["step"] == 50
    assert snapshot(d, skip=("eval",)) == before


# ----------------------------------------------------------------------------- 2. options with --resume


def test_options_given_with_resume_are_refused_by_name(base, tmp_path):
    d = _copy(base, tmp_path)
    before = snapshot(d)
    rc, out, err = _main(["train", "--resume", "--out", str(d), "--l", "5", "--num-envs", "16",
                          "--beta-theta", "0.5", "--steps", "300", "--quiet"])
    line = one_error_line(err)
    assert rc == 2 and out == ""
    assert (f"--resume continues the run in {d} with its own config; these options would change it: "
            f"--l 5 (the run has 10), --beta-theta 0.5 (the run has 2e-06), --num-envs 16 (the run has 8); "
            f"only the budget (--steps or --trials) may change") in line, line
    assert snapshot(d) == before


def test_resume_extends_the_budget_records_it_and_reports_the_run(base, tmp_path):
    a = base["dir"]
    d = _copy(base, tmp_path)
    before = snapshot(d)
    # options equal to the run's own are accepted; the budget may change
    rc, out, err = _main(["train", "--resume", "--out", str(d), "--l", "10", "--num-envs", "8",
                          "--steps", "100", "--quiet"])
    assert rc == 0 and err == "", err
    after = snapshot(d)
    changed = {k for k in after if before.get(k) != after[k]}
    assert {k for k in changed if not k.startswith("checkpoints/100")} == {
        "config.json", "metrics.jsonl", "resumes.jsonl"}, changed
    assert all(after[k] == v for k, v in before.items() if k.startswith(("checkpoints/50", "checkpoints/75")))
    old_cfg, new_cfg = json.loads((a / "config.json").read_text()), json.loads((d / "config.json").read_text())
    assert {k for k in old_cfg if old_cfg[k] != new_cfg[k]} == {"steps"} and new_cfg["steps"] == 100
    (rec,) = [json.loads(x) for x in (d / "resumes.jsonl").read_text().splitlines()]
    assert rec["from_step"] == 75 and rec["from_checkpoint"] == str((d / "checkpoints" / "75").absolute())
    assert rec["previous_budget"] == {"steps": 70, "trials": None} and rec["budget"] == {"steps": 100, "trials": None}
    old_lines = (a / "metrics.jsonl").read_text().splitlines()
    new_lines = (d / "metrics.jsonl").read_text().splitlines()
    assert new_lines[:3] == old_lines and json.loads(new_lines[3])["step"] == 100
    summary = json.loads(out)
    assert summary["step"] == 100
    assert summary["avg_reward_first_chunk"] == json.loads(old_lines[0])["avg_reward"]  # the run's, not the session's
    # nothing left to do: says so, writes nothing
    before = snapshot(d)
    rc, out, err = _main(["train", "--resume", "--out", str(d), "--quiet"])
    assert rc == 0
    trials = run.read_metrics(d)[-1]["trials"]
    assert err.splitlines() == [f"{d}: nothing to do: the run is at step 100 ({trials} trials), its budget is "
                                f"steps=100; give a larger --steps or --trials to continue"]
    assert snapshot(d) == before


# ----------------------------------------------------------------------------- 3. no overwriting


@pytest.mark.parametrize("keep", [("metrics.jsonl", "config.json"), ("metrics.jsonl",), ("config.json",),
                                  ("checkpoints",)])
def test_fresh_run_never_overwrites_a_run(base, tmp_path, keep):
    d = tmp_path / "D"
    d.mkdir()
    for name in keep:
        src = base["dir"] / name
        (shutil.copytree if src.is_dir() else shutil.copy)(src, d / name)
    before = snapshot(d)
    rc, out, err = _main(["train", *TINY, "--steps", "25", "--out", str(d)])
    line = one_error_line(err)
    assert rc == 2
    held = ", ".join(n for n in run.RUN_FILES if n in keep)
    assert line == (f"nmrl: error: {d} already holds a run ({held}); continue it with --resume or choose "
                    f"another --out")
    assert snapshot(d) == before
    if keep == ("metrics.jsonl", "config.json"):  # no checkpoint to continue from: --resume starts it again
        rc, out, err = _main(["train", "--resume", "--out", str(d), "--quiet"])
        assert rc == 0, err
        assert "has no checkpoint yet" in err and "its 3 metrics row(s) are replaced" in err
        strip = lambda rows: [{k: v for k, v in r.items() if k not in ("wall_s", "steps_per_s")} for r in rows]
        assert strip(run.read_metrics(d)) == strip(run.read_metrics(base["dir"]))


def test_a_run_stopped_before_its_first_checkpoint_starts_again_on_resume(base, tmp_path):
    """config.json written, nothing else (stopped while compiling): --resume starts it from its seed."""
    a = base["dir"]
    d = tmp_path / "D"
    d.mkdir()
    cfg = json.loads((a / "config.json").read_text())
    (d / "config.json").write_text(json.dumps(dict(cfg, steps=25), indent=2) + "\n")
    rc, out, err = _main(["train", "--resume", "--out", str(d), "--quiet"])
    assert rc == 0 and err == "", err
    assert _without_timing(run.read_metrics(d)) == _without_timing(run.read_metrics(a)[:1])
    assert checkpoint.all_steps(d) == [25]
    (rec,) = [json.loads(x) for x in (d / "resumes.jsonl").read_text().splitlines()]
    assert rec["from_step"] == 0 and rec["from_checkpoint"] is None


# ----------------------------------------------------------------------------- 4. a corrupted newest checkpoint


def _corrupt(step_dir: pathlib.Path, how: str) -> None:
    data = [p for p in step_dir.rglob("*") if p.is_file() and p.parent.name == "d"]
    assert data
    for p in data:
        if how == "deleted":  # the case that made orbax/tensorstore print "Event loop is closed" tracebacks
            p.unlink()
        else:
            p.write_bytes(bytes(255 - b for b in p.read_bytes()))


@pytest.mark.parametrize("how", ["deleted", "garbage"])
def test_corrupted_newest_checkpoint(base, tmp_path, how):
    d = _copy(base, tmp_path)
    ck75 = d / "checkpoints" / "75"
    _corrupt(ck75, how)
    before = snapshot(d)
    # eval: one warning line naming the path, then the newest good checkpoint
    rc, out, err = _main(["eval", str(d), *EVAL])
    assert rc == 0, err
    (line,) = err.splitlines()
    assert line.startswith(f"nmrl: warning: {ck75}: cannot read checkpoint item(s) policy"), line
    assert line.endswith("; evaluating the newest good checkpoint, step 50, instead"), line
    assert json.loads(out)["step"] == 50
    assert snapshot(d, skip=("eval",)) == before
    # asked for explicitly: refused
    rc, out, err = _main(["eval", str(d), "--step", "75", *EVAL])
    assert rc == 2 and one_error_line(err).startswith(f"nmrl: error: {ck75}: cannot read checkpoint item(s)")
    # resume: refused in one line naming the path and the newest good step; nothing changed
    rc, out, err = _main(["train", "--resume", "--out", str(d), "--quiet"])
    line = one_error_line(err)
    assert rc == 2 and line.startswith(f"nmrl: error: {ck75}: cannot read checkpoint item(s) state"), line
    assert line.endswith("; resume from the newest good checkpoint with --resume --step 50 (nothing was changed)")
    assert snapshot(d, skip=("eval",)) == before


_QUIET_SCRIPT = r"""
import sys, time
from nmrl import cli
rcs = [cli.main(["eval", sys.argv[1], "--seconds", "1", "--no-render"]),
       cli.main(["train", "--resume", "--out", sys.argv[1], "--quiet"])]
time.sleep(3)  # tensorstore's late callbacks printed their tracebacks up to ~1 s after the failed read
print(rcs)
"""


def test_corrupted_checkpoint_paths_keep_stderr_free_of_library_noise(base, tmp_path):
    """In a process of its own (the noise came after the failed read had returned, until exit)."""
    d = _copy(base, tmp_path)
    ck75 = d / "checkpoints" / "75"
    _corrupt(ck75, "deleted")
    p = subprocess.run([sys.executable, "-c", _QUIET_SCRIPT, str(d)], capture_output=True, text=True,
                       timeout=600, cwd=pathlib.Path(__file__).resolve().parents[1])
    assert p.stdout.splitlines()[-1] == "[0, 2]", p.stdout[-2000:] + p.stderr[-3000:]
    warning, error = p.stderr.splitlines()  # exactly these two lines: no traceback, no absl, no asyncio
    assert warning.startswith(f"nmrl: warning: {ck75}: cannot read") and "step 50, instead" in warning
    assert error.startswith(f"nmrl: error: {ck75}: cannot read") and error.endswith("(nothing was changed)")


def test_resume_from_an_older_checkpoint_on_request_equals_the_uninterrupted_run(base, tmp_path):
    a = base["dir"]
    d = _copy(base, tmp_path)
    _corrupt(d / "checkpoints" / "75", "deleted")
    before = snapshot(d)
    rc, out, err = _main(["train", "--resume", "--step", "50", "--out", str(d), "--quiet"])
    assert rc == 0 and err.splitlines() == base["stderr"].splitlines(), err  # the budget note, nothing else
    after = snapshot(d)
    for k, v in before.items():  # the good checkpoints are untouched
        if k.startswith(("checkpoints/25", "checkpoints/50")):
            assert after[k] == v, k
    assert _without_timing(run.read_metrics(d)) == _without_timing(run.read_metrics(a))
    # the step-75 checkpoint is rewritten, bit-identical in its data to the uninterrupted run's
    m_d, m_a = checkpoint.load_metadata(d, 75), checkpoint.load_metadata(a, 75)
    assert m_d["state_digest"] == m_a["state_digest"] and m_d["policy_digest"] == m_a["policy_digest"]
    (rec,) = [json.loads(x) for x in (d / "resumes.jsonl").read_text().splitlines()]
    assert rec["from_step"] == 50 and rec["config_json_updated"] is False
    assert (d / "config.json").read_bytes() == (a / "config.json").read_bytes()


def test_checkpoints_without_an_identity_field_still_restore(base, tmp_path):
    """Checkpoints written before the identity field: their config and model hash are the identity."""
    d = _copy(base, tmp_path)
    for meta_file in (d / "checkpoints").glob("*/meta/metadata"):
        meta = json.loads(meta_file.read_text())
        del meta["identity"]
        meta_file.write_text(json.dumps(meta))
    cfg = checkpoint.load_run_config(d)
    ts = checkpoint.restore(d, make_train(cfg))
    assert int(ts.step) == 75
    step, (meta, _), skipped = evaluate.select_policy(d)
    assert step == 75 and skipped == [] and "identity" not in meta
    # a config edited under a recorded identity is caught
    meta = checkpoint.load_metadata(base["dir"], 50)
    checkpoint.check_identity(meta, checkpoint.load_run_config(base["dir"]))
    meta["config"]["l"] = 5
    with pytest.raises(checkpoint.CorruptCheckpoint, match="does not match its own config"):
        checkpoint.check_identity(meta, None)


# ----------------------------------------------------------------------------- 5. bad values


@pytest.mark.parametrize("argv,message", [
    (["--control-dt", "0.007"], "control_dt=0.007 is invalid: must be a whole multiple of the physics timestep "
                                "0.005 s (e.g. 0.005, 0.01, 0.02; --physics-timestep sets it)"),
    (["--control-dt", "inf"], "control_dt=inf is invalid: must be a finite number"),
    (["--control-dt", "nan"], "control_dt=nan is invalid: must be a finite number"),
    (["--sigma", "inf"], "sigma=inf is invalid: must be a finite number"),
    (["--seed", "99999999999"], "seed=99999999999 is invalid: must be an integer in [0, 4294967295]"),
    (["--seed", "-1"], "seed=-1 is invalid: must be an integer in [0, 4294967295]"),
    (["--stop-prob", "0", "--trials", "10"], "trials=10 is invalid with stop_prob=0"),
    (["--step", "25"], "--step=25 picks the checkpoint to resume from and needs --resume (the budget is --steps)"),
])
def test_bad_train_values(tmp_path, argv, message):
    out = tmp_path / "run"
    rc, stdout, err = _main(["train", *TINY, *argv, "--out", str(out)])
    assert rc == 2 and stdout == ""
    assert message in one_error_line(err)
    assert not out.exists() and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv,message", [
    (["--seed0", "-1"], "seed0=-1 is invalid: must be an integer in [0, 4294967295] (JAX's PRNG seeds are 32-bit; "
                        "others wrap around to another seed)"),
    (["--seed0", "4294967295", "--seeds", "2"], "seeds=2 is invalid: the last seed, seed0 + seeds - 1 = 4294967296, "
                                                "must be an integer in [0, 4294967295] (JAX's PRNG seeds are 32-bit"),
    (["--seeds", "0"], "seeds=0 is invalid: must be an integer >= 1"),
])
def test_a_sweeps_seeds_are_held_to_the_one_seed_range(tmp_path, argv, message):
    """``--seed0`` and the last seed ``seed0 + seeds - 1`` are checked by the run field ``seed``'s
    declaration (nmrl.options.check_seed), one line and exit 2, nothing written; the top seed itself
    is allowed."""
    out = tmp_path / "sweep"
    rc, stdout, err = _main(["sweep", *TINY, "--l", "1", "--steps", "25", *argv, "--out", str(out)])
    assert rc == 2 and stdout == "" and message in one_error_line(err)
    assert not out.exists() and list(tmp_path.iterdir()) == []
    from nmrl.experiments import sweep

    sweep.SweepSpec(ls=(1,), seeds=1, seed0=4294967295, base=options.build(TrainConfig, steps=25)).validate()


def test_bad_out(tmp_path):
    f = tmp_path / "a_file"
    f.write_text("precious\n")
    for out, message in [
        (f, f"--out={str(f)!r} is invalid: it exists and is not a directory"),
        (f / "sub", f"--out={str(f / 'sub')!r} is invalid: {f} is not a directory"),
        (pathlib.Path("/proc/nmrl"), "--out='/proc/nmrl' is invalid: cannot create the directory ("),
    ]:
        rc, stdout, err = _main(["train", *TINY, "--steps", "25", "--out", str(out)])
        assert rc == 2 and message in one_error_line(err), err
    assert f.read_text() == "precious\n" and sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]
    assert not pathlib.Path("/proc/nmrl").exists()


@pytest.mark.parametrize("argv,message", [
    (["--seconds", "nan"], "--seconds=nan is invalid: must be a finite number of simulated seconds in (0, 600]"),
    (["--seconds", "inf"], "--seconds=inf is invalid"),
    (["--seconds", "0"], "--seconds=0.0 is invalid"),
    (["--seconds", "1e9"], "--seconds=1000000000.0 is invalid"),
    (["--seed", "99999999999"], "--seed=99999999999 is invalid: must be an integer in [0, 4294967295]"),
    (["--step", "-25"], "--step=-25 is invalid"),
])
def test_bad_eval_values(base, argv, message):
    before = snapshot(base["dir"])
    rc, stdout, err = _main(["eval", str(base["dir"]), "--no-render", *argv])
    assert rc == 2 and stdout == "" and message in one_error_line(err)
    assert snapshot(base["dir"]) == before


def test_eval_of_a_missing_run(tmp_path):
    rc, _, err = _main(["eval", str(tmp_path / "nope"), *EVAL])
    assert rc == 2 and one_error_line(err) == f"nmrl: error: {tmp_path / 'nope'}: run directory does not exist"
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------- 6. signals, progress


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_stops_after_the_saved_chunk_with_its_own_status(base, tmp_path, monkeypatch, sig):
    d = _copy(base, tmp_path)
    append = loop.append_metrics  # the chunk loop's, where the rows are written

    def append_and_signal(run_dir, row):
        append(run_dir, row)
        os.kill(os.getpid(), sig)  # arrives during the chunk's bookkeeping, as a user's Ctrl-C would

    monkeypatch.setattr(loop, "append_metrics", append_and_signal)
    old_handler = signal.getsignal(sig)
    rc, out, err = _main(["train", "--resume", "--out", str(d), "--steps", "150", "--quiet"])
    assert rc == 128 + sig == {signal.SIGINT: 130, signal.SIGTERM: 143}[sig]
    assert err.splitlines() == [
        "", f"signal {int(sig)}: stopping after the chunk in flight is saved, or in "
            f"{signals.DEFAULT_GRACE_S:g} s with the last saved chunk kept (again to stop now)",
        f"stopped by signal {int(sig)} at step 100 (saved); continue with: nmrl train --resume --out {d}"]
    assert json.loads(out)["step"] == 100
    assert checkpoint.latest_step(d) == 100 and run.read_metrics(d)[-1]["step"] == 100
    assert signal.getsignal(sig) is old_handler


def _same_state(a, b) -> bool:
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    return ta == tb and all(np.asarray(x).tobytes() == np.asarray(y).tobytes() and np.asarray(x).dtype == np.asarray(y).dtype
                            for x, y in zip(la, lb))


@pytest.mark.slow  # a real process (~50 s); the in-process signal tests above cover the handler by default
def test_sigterm_to_an_nmrl_train_process_saves_exits_143_and_resume_is_bit_identical(tmp_path):
    """A real ``nmrl train`` process gets SIGTERM from outside while it trains: it exits 143 after the
    chunk in flight is saved (the newest checkpoint is its last metrics row), and ``--resume``
    continues to the metrics and the state of an uninterrupted run, bit for bit (README: "continue
    (bit-identical to an uninterrupted run)")."""
    import time

    d = tmp_path / "S"
    cmd = [sys.executable, "-m", "nmrl.cli", "train", *TINY, "--devices", "1", "--steps", "100000", "--out", str(d)]
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 300
    try:
        while not (d / "metrics.jsonl").exists() or (d / "metrics.jsonl").read_text().count("\n") < 2:
            assert time.time() < deadline and p.poll() is None, p.poll()
            time.sleep(0.05)
        p.send_signal(signal.SIGTERM)
        out, err = p.communicate(timeout=300)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    assert p.returncode == 143, err[-2000:]
    last = run.read_metrics(d)[-1]["step"]
    assert last >= 50 and checkpoint.latest_step(d) == last
    assert f"stopped by signal 15 at step {last} (saved)" in err and json.loads(out)["step"] == last
    rc, _, err = _main(["train", "--resume", "--out", str(d), "--steps", str(last + 50), "--devices", "1", "--quiet"])
    assert rc == 0, err
    ref = tmp_path / "R"
    rc, _, err = _main(["train", *TINY, "--devices", "1", "--steps", str(last + 50), "--out", str(ref)])
    assert rc == 0, err
    assert _without_timing(run.read_metrics(d)) == _without_timing(run.read_metrics(ref))
    trainer = make_train(checkpoint.load_config(ref))
    assert checkpoint.latest_step(d) == checkpoint.latest_step(ref) == last + 50
    assert _same_state(checkpoint.restore(d, trainer), checkpoint.restore(ref, trainer))


def test_a_diverging_run_exits_3_says_so_and_keeps_its_last_good_checkpoint(tmp_path):
    """Absurd step sizes (beta = 0.1; here the parameters pass the norm limit in the second chunk):
    status 3, one message naming the step and the last good checkpoint, nothing on stdout, and that
    checkpoint holds the last good, finite parameters."""
    d = tmp_path / "div"
    rc, out, err = _main(["train", *TINY, "--beta-theta", "0.1", "--beta-v", "0.1", "--steps", "500",
                          "--devices", "1", "--out", str(d)])
    rows = run.read_metrics(d)
    assert len(rows) >= 2, rows  # at least one good chunk before the divergence (else pick smaller betas)
    bad, good = rows[-1], rows[-2]
    assert bad["diverged"] is True and not any(r["diverged"] for r in rows[:-1]) and bad["step"] < 500
    assert rc == 3 and out == ""
    (line,) = err.splitlines()
    assert line.startswith(f"nmrl: training diverged at step {bad['step']}: an update took a parameter norm past "
                           f"the limit 100000 (or to a non-finite value) and was rejected"), line
    assert "frozen at their last accepted values (theta norm " in line
    assert f"the last good checkpoint (step {good['step']}) is kept in {d}. Try smaller step sizes." in line
    assert checkpoint.all_steps(d)[-1] == good["step"]
    ts = checkpoint.restore(d, make_train(checkpoint.load_config(d)))
    assert int(ts.step) == good["step"] and not bool(ts.diverged)
    norms = [float(np.sqrt(sum(np.sum(np.square(x)) for x in jax.tree.leaves(t)))) for t in (ts.theta, ts.v)]
    assert norms == pytest.approx([good["theta_norm"], good["v_norm"]], rel=1e-5) and max(norms) < 1e5


def test_progress_eta_after_resume_uses_this_sessions_speed(capsys):
    cfg = options.build(TrainConfig, num_envs=8, chunk_steps=25, steps=100)
    bar = loop.Progress(cfg, True, done0=50)
    bar.t0 -= 10.0  # 25 steps in 10 s: the last 25 need 10 s more
    row = {"step": 75, "trials": 3, "total_steps": 600, "steps_per_s": 60.0, "avg_reward": -0.5,
           "forward_speed": 0.0}
    bar.update(row)
    bar.close()
    line = capsys.readouterr().err.strip()
    assert line.startswith("[ 75.0%]") and line.endswith("ETA 10s"), line
    assert "step 75 of 100 per env (600 in all" in line, line  # --steps counts per environment
    assert "reward -0.500/step (-25.0/s)" in line, line  # per control step of 0.02 s and per second


def test_return_per_trial_is_the_chunks_reward_over_its_ended_trials():
    """A chunk of 25 steps of 8 environments at -0.5 per step collects -100 over the 4 trials that
    ended in it: -25 per trial (the renewal estimate of the episode return); None without a trial."""
    cfg = options.build(TrainConfig, num_envs=8, chunk_steps=25, steps=100)
    m = {"step": 75, "trials": 9, "avg_reward": -0.5, "forward_speed": 0.0, "trials_in_chunk": 4}
    assert loop.metrics_row(cfg, m, wall=2.0)["return_per_trial"] == pytest.approx(-25.0)
    assert loop.metrics_row(cfg, {**m, "trials_in_chunk": 0}, wall=2.0)["return_per_trial"] is None


@pytest.mark.parametrize("argv,message", [
    (["ppo", "--num-envs", "1.5"], "--num-envs='1.5' is invalid: must be an integer"),
    (["ppo", "--learning-rate", "fast"], "--learning-rate='fast' is invalid: must be a number"),
    (["ppo", "--trials", "5"], "unknown option(s) --trials 5"),
    (["ppo", "--seed", "4294967296"], "seed=4294967296 is invalid: must be an integer in [0, 4294967295]"),
    (["ppo", "--seed", "-1"], "seed=-1 is invalid: must be an integer in [0, 4294967295]"),
    (["eval", "RUN", "--seconds", "601"], "--seconds=601.0 is invalid: must be in (0, 600]"),
    (["ppo", "--grace-s", "-1"], "--grace-s='-1' is invalid: the grace is a positive, finite number of seconds"),
    (["ppo", "--grace-s", "inf"], "--grace-s='inf' is invalid"),
])
def test_bad_baseline_values_are_one_line(tmp_path, argv, message):
    """``nmrl baseline`` answers a bad option as ``nmrl train`` does: one line, status 2, nothing written."""
    out = tmp_path / "run"
    argv = [str(tmp_path / "RUN") if a == "RUN" else a for a in argv]
    o, e = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(o), contextlib.redirect_stderr(e):
        try:
            rc = cli.main(["baseline", *argv, *(["--out", str(out)] if argv[0] == "ppo" else [])])
        except SystemExit as exit_:  # argparse's exit, as the console script sees it
            rc = exit_.code
    stdout, err = o.getvalue(), e.getvalue()
    lines = err.splitlines()
    assert rc == 2 and stdout == "" and len(lines) == 1 and lines[0].startswith("nmrl baseline"), err
    assert message in lines[0]
    assert list(tmp_path.iterdir()) == []


def test_a_long_chunk_without_heartbeats_gets_a_line_every_tick(capsys, monkeypatch):
    """Without a terminal, a chunk that shows no line for TICK_S seconds (no heartbeat: e.g. PPO on
    MJX) gets one with its time so far and, after the first chunk, the last chunk's time; a closed
    bar prints nothing more."""
    import time

    monkeypatch.setattr(loop, "TICK_S", 0.3)
    cfg = options.build(TrainConfig, num_envs=8, chunk_steps=25, steps=100)
    bar = loop.Progress(cfg, True)
    time.sleep(1.2)
    first = [l for l in capsys.readouterr().err.splitlines() if "the chunk has run" in l]
    assert first and "last chunk" not in first[0], first
    bar.update({"step": 25, "trials": 1, "total_steps": 200, "steps_per_s": 20.0, "avg_reward": 0.0,
                "forward_speed": 0.0, "wall_s": 1.2})
    time.sleep(1.2)
    bar.close()
    later = [l for l in capsys.readouterr().err.splitlines() if "the chunk has run" in l]
    assert later and all(re.search(r"the chunk has run \d+ s \(the last chunk took \d+ s\)$", l) for l in later), later
    time.sleep(0.8)
    assert "the chunk has run" not in capsys.readouterr().err
