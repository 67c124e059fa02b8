"""The study's spec (nmrl/experiments/timescale.py) and the Brax baseline's config
(nmrl/experiments/baseline_config.py) are declared with ``option(...)``: their command lines are made
from the declarations (every spelling parses to the field it names), a bad value is refused in one
line naming it and what its declaration allows (exit 2, nothing written), and every committed
``study.json`` of the timescale study loads and checks as it did."""

from __future__ import annotations

import json
import pathlib

import pytest

from nmrl import cli, options, tasks
from nmrl.experiments import baseline_config, baseline_ppo, study
from nmrl.experiments.baseline_config import BaselineConfig
from nmrl.experiments.timescale import TimescaleSpec

REPO = pathlib.Path(__file__).resolve().parents[1]
STUDIES = [REPO / "results" / d / "study.json" for d in ("timescale", "timescale_cap", "timescale_cap300")]


def _main(argv: list[str]) -> int:
    try:
        return cli.main(argv)
    except SystemExit as e:  # argparse's exit, as the console script sees it
        return e.code


def _study(monkeypatch, argv: list[str]) -> TimescaleSpec:
    got = []
    monkeypatch.setattr(study, "run_study", lambda spec, out, **kw: got.append(spec) or {})
    assert study.main(["--out", "unused", *argv]) == 0
    return got[0]


def test_every_study_option_parses_into_its_field(monkeypatch):
    argv = ["--dt", "0.01", "0.005", "--periods", "stationary", "0.2", "--beta-theta", "1e-5", "--beta-v", "1e-4",
            "3e-4", "--grid-seconds", "10", "--final-seconds", "20", "--chunk-seconds", "5", "--seeds", "2",
            "--num-envs", "8", "--checkpoint-every", "2", "--gradvar-envs", "16", "--gradvar-batches", "4",
            "--beta-theta-cap", "1e-5", "--physics", "c", "--env", "hopper-v5"]
    base = TimescaleSpec().base
    assert _study(monkeypatch, argv) == TimescaleSpec(
        dts=(0.01, 0.005), periods=(None, 0.2), beta_theta_grid=(1e-5,), beta_v_grid=(1e-4, 3e-4), grid_seconds=10.0,
        final_seconds=20.0, chunk_seconds=5.0, seeds=2, num_envs=8, checkpoint_every=2, gradvar_envs=16,
        gradvar_batches=4, beta_theta_cap=1e-5, physics="c", base=options.replace(base, env="hopper-v5"))
    assert _study(monkeypatch, []) == TimescaleSpec()
    for none in ("none", "1"):
        assert _study(monkeypatch, ["--periods", none, "0.1"]).periods == (None, 0.1)


@pytest.mark.parametrize("argv, line", [
    (["--seeds", "0"], "seeds=0 is invalid: must be an integer >= 1"),
    (["--gradvar-batches", "1"], "gradvar_batches=1 is invalid: must be an integer >= 2"),
    (["--dt", "0.02", "0"], "dts=0.0 is invalid: must be in (0, 1]"),
    (["--dt", "0.01", "0.01"], "dts=(0.01, 0.01) is invalid: each control step may appear once"),
    (["--periods", "-1"], "periods=-1.0 is invalid: must be a finite number > 0"),
    (["--periods", "0.2", "0.2"], "periods=(0.2, 0.2) is invalid: each period may appear once"),
    (["--periods", "fast"], "period 'fast' is invalid: give seconds > 0 or 'stationary'"),
    (["--beta-theta", "0"], "beta_theta_grid=0.0 is invalid: must be a finite number > 0"),
    (["--beta-theta-cap", "1e-7"], "beta_theta_cap=1e-07 is invalid: must be >= the smallest grid value 3e-06"),
    (["--chunk-seconds", "-5"], "chunk_seconds=-5.0 is invalid: must be a finite number > 0"),
    (["--grid-seconds", "7"], "grid_seconds=7.0 is invalid: must be a multiple of chunk_seconds=5"),
    (["--seeds", "1.5"], "--seeds='1.5' is invalid: must be an integer"),
])
def test_a_bad_study_value_is_refused_in_one_line(tmp_path, capsys, argv, line):
    out = tmp_path / "s"
    assert _main(["study", "--out", str(out), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and line in err[0], err
    assert not out.exists()


@pytest.mark.parametrize("path", STUDIES, ids=lambda p: p.parent.name)
def test_every_committed_study_loads_checks_and_keeps_its_values(path):
    """(Its ``base`` and the fields it predates take today's defaults, as before.)"""
    d = json.loads(path.read_text())
    spec = TimescaleSpec.from_json(d)
    spec.validate()
    assert TimescaleSpec.from_json(json.loads(json.dumps(spec.to_json()))) == spec
    assert {k: v for k, v in spec.to_json().items() if k in d and k != "base"} == {k: v for k, v in d.items()
                                                                                  if k != "base"}


def _baseline(monkeypatch, argv: list[str]) -> BaselineConfig:
    got = []
    monkeypatch.setattr(baseline_ppo, "run", lambda cfg, out, **kw: got.append(cfg))
    assert baseline_ppo.main(["ppo", "--out", "unused", *argv]) == 0
    return got[0]


def test_every_baseline_option_parses_into_its_field(monkeypatch):
    argv = ["--seed", "7", "--num-timesteps", "1000", "--num-envs", "8", "--batch-size", "16", "--num-minibatches",
            "4", "--unroll-length", "10", "--num-updates-per-batch", "2", "--discounting", "0.9", "--learning-rate",
            "1e-3", "--entropy-cost", "0", "--policy-hidden", "8", "8", "--value-hidden", "16", "--physics", "c"]
    assert _baseline(monkeypatch, argv) == BaselineConfig(
        seed=7, num_timesteps=1000, num_envs=8, batch_size=16, num_minibatches=4, unroll_length=10,
        num_updates_per_batch=2, discounting=0.9, learning_rate=1e-3, entropy_cost=0.0, policy_hidden=(8, 8),
        value_hidden=(16,), physics="c")
    assert _baseline(monkeypatch, []) == BaselineConfig()
    assert _baseline(monkeypatch, ["--env", "hopper-v5"]) == baseline_config.task_config("hopper-v5")


def test_the_baseline_options_are_its_declared_fields():
    """The options are the fields declared ``cli``; the others (the control step, the stop rule, the
    episode cap, ...) are set by code; the environment's fields are EnvFields' declarations."""
    names = [n for n, d in options.declarations(BaselineConfig).items() if d.cli]
    assert names == ["seed", "num_timesteps", "num_envs", "batch_size", "num_minibatches", "unroll_length",
                     "num_updates_per_batch", "discounting", "learning_rate", "entropy_cost", "policy_hidden",
                     "value_hidden", "physics", "env"]
    for name in ("control_dt", "stop_prob", "physics", "env"):
        ours, env = options.declaration(BaselineConfig, name), options.declaration(tasks.EnvFields, name)
        assert (ours.help, ours.range, ours.choices) == (env.help, env.range, env.choices)


@pytest.mark.parametrize("argv, line", [
    (["--num-envs", "0"], "num_envs=0 is invalid: must be an integer >= 1"),
    (["--discounting", "0"], "discounting=0.0 is invalid: must be in (0, 1]"),
    (["--entropy-cost", "-1"], "entropy_cost=-1.0 is invalid: must be a finite number >= 0"),
    (["--learning-rate", "inf"], "learning_rate=inf is invalid: must be a finite number"),
    (["--policy-hidden", "32", "0"], "policy_hidden=0 is invalid: must be an integer >= 1"),
    (["--num-envs", "7"], "num_envs=7 is invalid: batch_size x num_minibatches = 16384 must be a multiple of it"),
])
def test_a_bad_baseline_value_is_refused_in_one_line(tmp_path, capsys, argv, line):
    out = tmp_path / "r"
    assert _main(["baseline", "ppo", "--out", str(out), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and line in err[0], err
    assert not out.exists()
