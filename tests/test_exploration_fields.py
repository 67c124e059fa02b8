"""The exploration's one declaration (nmrl/explore/fields.py): every field of ``ExplorationFields``
is an option of ``nmrl train`` and ``nmrl sweep`` for every learner that explores, parsed under its
name with its declared type; PPO's config holds the same declarations; a bad value is refused in
one line naming it and what its declaration allows, the same line from the command line, from a
config and from an ``ExplorationSpec``."""

from __future__ import annotations

import contextlib
import dataclasses
import io

import pytest

from nmrl import cli, explore, options
from nmrl.cli import arguments, config_options
from nmrl.explore import fields
from nmrl.learners import ppo_config

#: one value of each option as given on the command line, and the value it parses to
GIVEN = {"exploration": ("colored", "colored"), "period_s": ("0.3", 0.3), "corr_time_s": ("0.1", 0.1),
         "beta": ("0.5", 0.5), "f_min_hz": ("0.5", 0.5), "f_max_hz": ("20", 20.0), "order": ("8", 8)}


def _main(argv: list[str]) -> tuple[int, str]:
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        try:
            rc = cli.main(argv)
        except SystemExit as e:
            rc = e.code
    return rc, err.getvalue()


def test_the_declared_fields_are_the_specs():
    """The spec's kind and parameters (but each learner's own sigma) are the declared fields."""
    assert set(fields.PARAMS) | {"kind", "sigma"} == {f.name for f in dataclasses.fields(explore.ExplorationSpec)}
    assert list(options.declarations(fields.ExplorationFields)) == ["exploration", *fields.PARAMS]
    for name, decl in options.declarations(fields.ExplorationFields).items():
        assert decl.help and decl.group == fields.GROUP
        assert decl.choices == explore.KINDS if name == "exploration" else decl.range is not None


def test_ppo_holds_the_declared_fields():
    for name, decl in options.declarations(fields.ExplorationFields).items():
        assert options.declaration(ppo_config.PPOConfig, name) is decl, name
    assert ppo_config.PPOConfig().noise.exploration == "white" and fields.ExplorationFields().exploration is None


@pytest.mark.parametrize("cmd", ["train", "sweep"])
@pytest.mark.parametrize("learner", ["ac", "ppo"])
def test_every_spelling_parses_under_its_name(cmd, learner):
    lr = config_options.get_learner(learner)
    argv = [cmd, "--learner", learner, "--out", "x"]
    for name, (text, _) in GIVEN.items():
        argv += ["--" + name.replace("_", "-"), text]
    args = arguments.build_parser(lr).parse_args(argv)
    for name, (_, value) in GIVEN.items():
        got = getattr(args, name)
        assert got == value and type(got) is type(value), (name, got)
    none = arguments.build_parser(lr).parse_args([cmd, "--learner", learner, "--out", "x"])
    assert all(getattr(none, name) is None for name in GIVEN)


@pytest.mark.parametrize("learner", ["ac", "ppo"])
def test_help_names_every_option_with_its_declaration(learner):
    """The help as argparse wraps it (whitespace aside) holds each option and its declared help."""
    p = arguments.build_parser(config_options.get_learner(learner))._subparsers._group_actions[0].choices["train"]
    text = "".join(p.format_help().split())
    for name, decl in options.declarations(fields.ExplorationFields).items():
        assert f"--{name.replace('_', '-')}" in text
        assert "".join(decl.help.split()) in text, name


BAD = [  # (learner, argv, the one line's text after "nmrl: error: " or the parser's prefix)
    ("ppo", ["--exploration", "pink"], "exploration='pink' is invalid: choose one of white, nm-periods, ou, colored"),
    ("ac", ["--exploration", "pink"], "exploration='pink' is invalid: choose one of white, nm-periods, ou, colored"),
    ("ppo", ["--exploration", "colored", "--beta", "3"], "beta=3.0 is invalid: must be in [0, 2]"),
    ("ppo", ["--beta", "-1"], "beta=-1.0 is invalid: must be in [0, 2]"),
    ("ppo", ["--exploration", "colored", "--order", "40"], "order=40 is invalid: must be an integer in [1, 32]"),
    ("ppo", ["--exploration", "colored", "--f-min-hz", "0"], "f_min_hz=0.0 is invalid: must be a finite number > 0"),
    ("ppo", ["--exploration", "ou", "--corr-time-s", "nan"], "corr_time_s=nan is invalid: must be a finite number"),
    ("ac", ["--period-s", "-1"], "period_s=-1.0 is invalid: must be a finite number > 0"),
    ("ac", ["--corr-time-s", "0"], "corr_time_s=0.0 is invalid: must be a finite number > 0"),
    ("ppo", ["--exploration", "white", "--period-s", "0.2"], "period_s is a parameter of nm-periods, not of white"),
    ("ac", ["--exploration", "colored"], "exploration='colored' is a process the learner 'ac' cannot use"),
    ("ac", ["--beta", "abc"], "--beta='abc' is invalid: must be a number"),
    ("ppo", ["--order", "2.5"], "--order='2.5' is invalid: must be an integer"),
]


@pytest.mark.parametrize("learner, argv, line", BAD)
def test_a_bad_value_is_refused_in_one_line(tmp_path, learner, argv, line):
    out = tmp_path / "run"
    rc, err = _main(["train", "--learner", learner, "--out", str(out), *argv])
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and line in lines[0], err
    assert not out.exists()


@pytest.mark.parametrize("kwargs", [dict(kind="colored", beta=3.0), dict(kind="colored", order=0),
                                    dict(kind="ou", corr_time_s=-1.0), dict(kind="nm-periods", period_s=0.0),
                                    dict(kind="colored", f_max_hz=float("inf"))])
def test_the_spec_and_a_config_refuse_by_the_declaration(kwargs):
    """The same message from ExplorationSpec and from PPO's config: one check, the declaration's."""
    (name, value), = [(k, v) for k, v in kwargs.items() if k != "kind"]
    with pytest.raises(ValueError) as declared:
        fields.check_field(name, value)
    with pytest.raises(ValueError) as spec:
        explore.ExplorationSpec(**kwargs)
    with pytest.raises(ValueError) as config:
        options.build(ppo_config.PPOConfig, exploration=kwargs["kind"], **{name: value}).validate()
    assert str(spec.value) == str(config.value) == str(declared.value)
