"""One config model: a run's settings are each declared and checked in one place.

* the environment (``--env``, ``--physics``, the control step, the stop rule, the trial length, the
  timestep) is :class:`nmrl.tasks.EnvFields`: every learner's config holds it as its group ``environment``,
  and the study's and the baseline's options are made from them;
* a bad ``--env`` or ``--physics`` is refused in one line naming the value and what is allowed, exit
  status 2, nothing written, by every command, for the paper's robot and for a Gymnasium task;
* ``--physics c`` checks the model the run steps: a task's own, not the paper's;
* one seed range, one ``--devices``; the other learners' options are read only when an option is unknown;
* each learner's ``Hyper`` is a class written out, whose leaves are its config's traced declarations.
"""

from __future__ import annotations

import argparse
from typing import Any, NamedTuple

import pytest

from nmrl import cli, learners, options, physics, tasks
from nmrl.learners.ac_config import TrainConfig
from nmrl.runs import preflight

ENV_FIELDS = ("env", "control_dt", "stop_prob", "trial_s", "physics", "physics_timestep")


# ------------------------------------------------------------------------ declared once
@pytest.mark.parametrize("name", learners.names())
def test_every_learner_takes_the_environment_fields_of_their_one_declaration(name):
    cls = learners.get(name).config
    for field in ENV_FIELDS:
        assert options.declaration(cls, field) is options.declaration(tasks.EnvFields, field), (name, field)
    assert options.declaration(tasks.EnvFields, "physics").choices == physics.PHYSICS
    assert options.declaration(tasks.EnvFields, "env").choices == tasks.ENVS


def _help_of(parser: argparse.ArgumentParser, flag: str) -> str:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                if flag in sub._option_string_actions:
                    return sub._option_string_actions[flag].help
        elif flag in action.option_strings:
            return action.help
    raise AssertionError(f"no {flag}")


def test_the_study_and_the_baseline_make_their_environment_options_from_the_declaration(monkeypatch):
    """``nmrl study`` and ``nmrl baseline`` build their parsers from the same declarations (their
    ``--help`` shows the declared help)."""
    from nmrl.experiments import baseline_ppo, study
    from nmrl.runs import parser

    made: dict[str, argparse.ArgumentParser] = {}

    def capture(self, *a, **k):
        made[self.prog] = self
        raise SystemExit(0)

    monkeypatch.setattr(parser.OneLineParser, "parse_args", capture)
    for main in (study.main, baseline_ppo.main):
        with pytest.raises(SystemExit):
            main(["--help"])
    assert set(made) == {"nmrl study", "nmrl baseline"}
    for prog, p in made.items():
        for field in ("env", "physics"):
            assert options.declaration(tasks.EnvFields, field).help in _help_of(p, f"--{field}"), (prog, field)


# ----------------------------------------------------------------------------- refusals
PHYSICS_LINE = "physics='gpu' is invalid: choose one of mjx, c"
ENV_LINE = "env='ant-v5' is invalid: choose one of paper-cheetah, halfcheetah-v5, hopper-v5, walker2d-v5"


@pytest.mark.parametrize("argv, why", [
    (["train", "--physics", "gpu"], PHYSICS_LINE),
    (["train", "--env", "hopper-v5", "--physics", "gpu"], PHYSICS_LINE),
    (["train", "--learner", "ppo", "--physics", "gpu"], PHYSICS_LINE),
    (["train", "--learner", "ppo", "--env", "walker2d-v5", "--physics", "gpu"], PHYSICS_LINE),
    (["sweep", "--env", "hopper-v5", "--physics", "gpu", "--l", "1"], PHYSICS_LINE),
    (["study", "--physics", "gpu"], PHYSICS_LINE),
    (["study", "--env", "hopper-v5", "--dt", "0.008", "--physics", "gpu"], PHYSICS_LINE),
    (["baseline", "ppo", "--physics", "gpu"], PHYSICS_LINE),
    (["baseline", "ppo", "--env", "hopper-v5", "--physics", "gpu"], PHYSICS_LINE),
    (["train", "--learner", "ppo", "--env", "ant-v5"], ENV_LINE),
    (["baseline", "ppo", "--env", "ant-v5"], ENV_LINE),
])
def test_a_bad_physics_or_env_is_refused_in_one_line_by_every_command(tmp_path, capsys, argv, why):
    out = tmp_path / "r"
    assert cli.main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].endswith(why), err
    assert not out.exists()


# ---------------------------------------------------------------------------- preflight
@pytest.mark.parametrize("env", ["paper-cheetah", "hopper-v5"])
def test_physics_c_checks_the_model_of_the_environment_the_run_steps(monkeypatch, env):
    from nmrl.physics import mujoco_c

    seen = []
    monkeypatch.setattr(mujoco_c, "check_supported", lambda m: seen.append((m.nq, m.nu)))
    control_dt = 0.02 if env == tasks.PAPER else 0.008
    preflight.check_config(options.build(TrainConfig, env=env, physics="c", control_dt=control_dt))
    model = tasks.mj_model(env)
    assert seen == [(model.nq, model.nu)]
    assert env == tasks.PAPER or (model.nq, model.nu) != (tasks.mj_model(tasks.PAPER).nq, tasks.mj_model(tasks.PAPER).nu)


# ------------------------------------------------------------------- the seed, --devices
SEED_ALLOWED = "is invalid: must be an integer in [0, 4294967295] (JAX's PRNG seeds are 32-bit; others wrap around " \
               "to another seed)"


@pytest.mark.parametrize("argv", [
    ["train", "--seed", "4294967296"],
    ["train", "--learner", "ppo", "--seed", "-1"],
    ["baseline", "ppo", "--seed", "-1"],
    ["eval", "no-such-run", "--seed", "4294967296"],
])
def test_every_command_refuses_a_seed_by_the_one_seed_range(tmp_path, capsys, argv):
    out = tmp_path / "r"
    assert cli.main([*argv, *([] if argv[0] == "eval" else ["--out", str(out)])]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].endswith(SEED_ALLOWED), err
    assert not out.exists()


def test_train_and_sweep_take_the_same_devices_option():
    p = cli.build_parser()
    sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))
    train, sweep = (sub.choices[c]._option_string_actions["--devices"] for c in ("train", "sweep"))
    assert (train.help, train.default) == (sweep.help, sweep.default)
    assert sub.choices["train"].parse_args(["--out", "r", "--devices", "2"]).devices == "2"


# ----------------------------------------------------- the other learners' options, on failure only
def test_the_other_learners_parsers_are_built_only_when_an_option_is_unknown(tmp_path, capsys, monkeypatch):
    """A command whose options parse builds its own learner's parser only (building every learner's
    costs every start); an unknown option builds the others' to name the learner it belongs to."""
    import nmrl.cli as cli_module

    built = []
    real = cli_module.build_parser
    monkeypatch.setattr(cli_module, "build_parser", lambda learner=None: built.append(learner.name) or real(learner))
    assert cli.main(["train", "--num-envs", "0", "--out", str(tmp_path / "r")]) == 2  # parsed, then refused
    assert built == ["ac"] and "num_envs=0 is invalid" in capsys.readouterr().err
    built.clear()
    assert cli.main(["train", "--learning-rate", "0.1", "--out", str(tmp_path / "r")]) == 2
    assert built[0] == "ac" and "ppo" in built
    assert "--learning-rate: an option of the learner 'ppo', not of 'ac'" in capsys.readouterr().err


# --------------------------------------------------------------------------- typed Hyper
@pytest.mark.parametrize("name", learners.names())
def test_each_learners_written_hyper_holds_the_traced_values_its_config_declares(name):
    lr = learners.get(name)
    hyper = type(lr.hyper(lr.config().resolved()))
    assert hyper._fields == options.hyper_leaves(lr.config)
    # every leaf typed, for editors (the annotations name JAX's types, imported for type checkers only)
    assert set(hyper.__annotations__) == set(hyper._fields) and all(hyper.__annotations__.values())


def test_a_hyper_that_is_not_the_declared_traced_values_is_refused():
    class Wrong(NamedTuple):
        delta: Any
        l: Any

    with pytest.raises(TypeError, match="is not the traced values"):
        options.hyper_values(Wrong, TrainConfig())
