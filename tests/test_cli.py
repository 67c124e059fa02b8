"""The ``nmrl`` command as a user runs it: relative paths, bad values, resume rules."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from nmrl import cli
from nmrl.runs import driver as run

TINY = ["--num-envs", "4", "--chunk-steps", "5", "--hidden-actor", "8", "--hidden-critic", "8", "--quiet"]


def test_relative_out_train_resume_eval(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert cli.main(["train", *TINY, "--steps", "5", "--out", "rel"]) == 0
    assert cli.main(["train", "--resume", "--steps", "10", "--out", "rel", "--quiet"]) == 0
    rows = run.read_metrics(tmp_path / "rel")
    assert [r["step"] for r in rows] == [5, 10]
    capsys.readouterr()
    assert cli.main(["eval", "rel", "--seconds", "1.0", "--no-render"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["step"] == 10 and set(out) >= {"deterministic", "exploring"}


@pytest.mark.parametrize("argv,needle", [
    (["--l", "0"], "l"),
    (["--delta", "0"], "delta"),
    (["--alpha", "1.0"], "alpha"),
    (["--beta-theta=-1e-6"], "beta_theta"),
    (["--steps", "0"], "steps"),
    (["--trials", "-5"], "trials"),
    (["--preset", "turbo"], "preset='turbo'"),
    (["--num-envs", "0"], "num_envs"),
])
def test_bad_values_exit_2_and_write_nothing(tmp_path, capsys, argv, needle):
    out = tmp_path / "run"
    assert cli.main(["train", *argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert needle in err and "error" in err
    assert not out.exists()


def test_resume_rules(tmp_path, capsys):
    assert cli.main(["train", "--resume", "--out", str(tmp_path / "nothing")]) == 2
    assert "no checkpoint" in capsys.readouterr().err
    assert cli.main(["train", *TINY, "--steps", "5", "--out", str(tmp_path / "r")]) == 0
    assert cli.main(["train", *TINY, "--steps", "5", "--out", str(tmp_path / "r")]) == 2
    assert "--resume" in capsys.readouterr().err


def test_eval_a_published_policy_without_touching_it(tmp_path, capsys):
    """``nmrl eval`` on a policy published under results/ (a Fig. 3 point's compact.npz, no
    checkpoints) with --out: the output goes to --out, the published directory stays byte for byte
    as it is, and the policy is the published one (the compact state's step and trials, its l);
    an --out that is a file is refused."""
    import pathlib

    import numpy as np

    pub = pathlib.Path(__file__).resolve().parents[1] / "results" / "fig3_paper" / "points" / "l10_s0"
    before = {p.name: p.read_bytes() for p in pub.iterdir()}
    with np.load(pub / "compact.npz") as z:
        step, trials = int(z["step"]), int(z["trials"])
    assert cli.main(["eval", str(pub), "--seconds", "1", "--no-render", "--out", str(tmp_path / "ev")]) == 0
    out = json.loads(capsys.readouterr().out)
    assert (out["step"], out["trials"], out["l"]) == (step, trials, 10)
    assert json.loads((tmp_path / "ev" / "eval.json").read_text()) == out
    assert {p.name: p.read_bytes() for p in pub.iterdir()} == before
    (tmp_path / "file").write_text("x")
    assert cli.main(["eval", str(pub), "--out", str(tmp_path / "file")]) == 2
    assert "--out=" in capsys.readouterr().err


def test_importing_the_command_loads_no_numpy_jax_or_run_store():
    """What ``import nmrl.cli`` loads runs before main() installs the signal guard, so a signal in
    that window prints Python's traceback: it stays the light modules (argument parsing, signals,
    devices), and numpy, JAX, the learners and the run store load only once the command runs."""
    code = ("import sys, nmrl.cli; print(','.join(m for m in ('numpy', 'jax', 'nmrl.learners', 'nmrl.runs.store') "
            "if m in sys.modules))")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == ""


def test_bare_nmrl_shows_the_commands_and_version_names_the_package(capsys):
    from importlib import metadata

    assert cli.main([]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: nmrl") and all(c in out for c in ("train", "sweep", "eval", "study", "baseline"))
    with pytest.raises(SystemExit) as e:
        cli.main(["--version"])
    assert e.value.code == 0 and capsys.readouterr().out.strip() == f"nmrl {metadata.version('nmrl')}"


@pytest.mark.parametrize("setting, given, want", [
    (None, None, "~/.cache/nmrl/xla"),  # the default
    (None, "/elsewhere", "/elsewhere"),  # the user's JAX_COMPILATION_CACHE_DIR wins
    ("off", None, None), ("0", None, None),  # turned off
])
def test_the_command_keeps_compiled_programs_unless_told_not_to(monkeypatch, setting, given, want):
    import os

    for name, value in (("NMRL_COMPILE_CACHE", setting), ("JAX_COMPILATION_CACHE_DIR", given)):
        if value is None:
            monkeypatch.delenv(name, raising=False)
        else:
            monkeypatch.setenv(name, value)
    cli.compile_cache()
    assert os.environ.get("JAX_COMPILATION_CACHE_DIR") == (None if want is None else os.path.expanduser(want))


@pytest.mark.parametrize("command", ["train", "sweep"])
def test_a_ppo_budget_below_one_iteration_is_refused_naming_the_iteration(tmp_path, capsys, command):
    """4 environments, minibatches of 4 unrolls, 2 minibatches: an iteration is 2 unrolls of 0.4 s,
    40 control steps per environment at 20 ms."""
    out = tmp_path / "run"
    argv = [command, "--learner", "ppo", "--num-envs", "4", "--batch-size", "4", "--num-minibatches", "2",
            "--steps", "39", "--out", str(out)]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert "--steps 39 is below one iteration of 40 control steps per environment" in err and "--unroll-s" in err
    assert len(err.strip().splitlines()) == 1 and not out.exists()


@pytest.mark.parametrize("argv, want", [
    (["train", "--learning-rate", "0.1"], "--learning-rate: an option of the learner 'ppo', not of 'ac' (give --learner ppo"),
    (["sweep", "--learner", "ppo", "--hidden-actor", "8"], "--hidden-actor: an option of the learner 'ac', not of 'ppo'"),
    (["train", "--bogus", "3"], "unknown option(s) --bogus 3"),
])
def test_an_option_of_another_learner_names_that_learner(tmp_path, capsys, argv, want):
    out = tmp_path / "run"
    try:
        rc = cli.main([*argv, "--out", str(out)])
    except SystemExit as e:  # argparse's own refusal
        rc = e.code
    err = capsys.readouterr().err
    assert rc == 2 and want in err and len(err.strip().splitlines()) == 1 and not out.exists()
