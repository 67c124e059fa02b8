"""Cells as typed data (nmrl/experiments/kit_cells.py): every study's cells run the same ``nmrl sweep``
commands as the argv cells they replace (tests/data/cell_commands.json, recorded from that code),
every published cell makes the spec its sweep.json saved, each cell's names and values are checked
against its learner's declarations as it is made, and the sweep's own options a cell gives are those
of the ``nmrl sweep`` parser."""

from __future__ import annotations

import dataclasses
import json

import pytest

from nmrl import options
from nmrl.cli import arguments, config_options
from nmrl.experiments import kit, kit_cells
from tests.study_cells import RECORD, RESULTS, commands, every_cell, learner_of, parsed, spec_of

RECORDED = json.loads(RECORD.read_text())
CELLS = every_cell()


def test_every_recorded_cell_is_still_a_cell_of_its_study():
    assert {k: sorted(v) for k, v in RECORDED.items()} == {k: sorted(c) for k, (_, c) in CELLS.items()}
    assert sum(len(v) for v in RECORDED.values()) == 122


@pytest.mark.parametrize("study", sorted(RECORDED))
def test_every_cell_runs_the_sweep_the_argv_cells_ran(study):
    """Fresh and resumed: the same points file, and a command line the sweep reads as the same options
    (every value equal, the same options given; an option the argv cells gave twice, the later value winning, is given once), so every study directory resumes and every published
    result stays what it is."""
    s, cells = CELLS[study]
    for name, cell in cells.items():
        new, old = commands(s, cell), RECORDED[study][name]
        for how in ("fresh", "resume"):
            assert new[how].get("points") == old[how].get("points"), (study, name, how)
            a, b = new[how]["argv"], old[how]["argv"]
            learner = learner_of(b)
            assert learner_of(a) == learner and b[-2:] == a[-2:] == ["--out", "OUT"]
            assert parsed(a, learner) == parsed(b, learner), (study, name, how)


def test_every_resume_is_the_same_text_and_the_points_cells_start_the_same_text():
    """A resume gives the budget and the run options only, word for word as before; a fresh start of a
    cell of listed points too (its values are in the points file). The other fresh starts differ in
    how a float is written (its shortest round-trip text: ``--sigma 1.0`` where the argv cells wrote
    ``1``) and in option order, which the test above shows the sweep reads as the same."""
    resume = [commands(s, c)["resume"]["argv"] == RECORDED[k][n]["resume"]["argv"]
              for k, (s, cells) in CELLS.items() for n, c in cells.items()]
    listed = [commands(s, c)["fresh"]["argv"] == RECORDED[k][n]["fresh"]["argv"]
              for k, (s, cells) in CELLS.items() for n, c in cells.items() if c.points]
    assert all(resume) and len(resume) == 122 and all(listed) and len(listed) == 46


def test_a_cell_naming_a_field_or_value_its_learner_does_not_allow_is_refused_as_it_is_made():
    with pytest.raises(ValueError, match=r"^cell c: setting 'clip_epsilon' is invalid: .*options of the learner 'ppo'"):
        kit.Cell("c", "ppo", {"clip_epsilon": 0.2})
    with pytest.raises(ValueError, match=r"^cell c: sigma=-1.0 is invalid: must be"):
        kit.Cell("c", "ppo", {"sigma": -1.0})
    with pytest.raises(ValueError, match=r"^cell c: physics='gpu' is invalid: choose one of"):
        kit.Cell("c", "ppo", {"physics": "gpu"})
    with pytest.raises(ValueError, match=r"^cell c: num_envs=2.5 is invalid: must be"):
        kit.Cell("c", "ppo", {"num_envs": 2.5})
    with pytest.raises(ValueError, match=r"^cell c: setting 'steps' is invalid"):
        kit.Cell("c", "ppo", {"steps": 10})
    with pytest.raises(ValueError, match=r"^cell c: vary='num_envs' is invalid: .*traced hyperparameters"):
        kit.Cell("c", "ppo", vary=("num_envs", (1, 2)))
    with pytest.raises(ValueError, match=r"^cell c: point 'a' sets 'steps'"):
        kit.Cell("c", "ac", points=({"name": "a", "steps": 3},))
    with pytest.raises(ValueError, match=r"^cell c: l=0 is invalid"):
        kit.Cell("c", "ac", points=({"name": "a", "l": 0, "seed": 0},))
    with pytest.raises(ValueError, match=r"^cell c: seed0=-1 is invalid"):
        kit.Cell("c", "ppo", seed0=-1)
    with pytest.raises(ValueError, match=r"^cell c: run option 'grup' is invalid: choose one of group"):
        kit.Cell("c", "ppo", run_options={"grup": 2})
    with pytest.raises(ValueError, match=r"^cell c: group=0 is invalid: must be an integer >= 1"):
        kit.Cell("c", "ppo", run_options={"group": 0})
    with pytest.raises(ValueError, match=r"^cell c: learner='sac' is unknown: choose one of ac, ppo"):
        kit.Cell("c", "sac")


def test_every_study_cell_holds_values_its_learner_allows():
    """Each cell is checked as it is made; here again, field by field, by nmrl.options alone."""
    from nmrl import learners, options

    n = 0
    for _, cells in CELLS.values():
        for cell in cells.values():
            cfg = learners.get(cell.learner).config
            decl = options.declarations(cfg)
            for p in (cell.settings, *cell.points):
                for k, v in p.items():
                    if k != "name" and k in decl:
                        options.check_value(k, v, options.kind(cfg, k), decl[k])
                        n += 1
    assert n > 1000


def test_the_sweep_options_of_a_cell_are_those_of_the_sweep_command():
    sub = next(a for a in arguments.build_parser(config_options.get_learner())._actions
               if hasattr(a, "choices") and isinstance(a.choices, dict))
    actions = sub.choices["sweep"]._option_string_actions
    for f in dataclasses.fields(kit_cells.SweepOptions):
        a = actions["--" + f.name.replace("_", "-")]
        assert a.dest == f.name
        if f.type == "bool":
            assert a.nargs == 0 and a.default is False
        else:
            assert str(a.default) == str(f.default), f.name


def test_one_function_writes_every_cell_option_by_its_declared_flag():
    cell = kit.Cell("c", "ppo", {"clip_eps": 0.1, "period_wise": True, "num_envs": 4, "physics": "c"}, steps=8,
                    vary=("sigma", (0.5, 1.0)), seeds=2, seed0=3)
    assert kit_cells.sweep_argv(cell, {"group": 2, "quiet": True, "checkpoint_every": 1}) == [
        "--learner", "ppo", "--clip-eps", "0.1", "--period-wise", "true", "--num-envs", "4", "--physics", "c",
        "--steps", "8", "--vary", "sigma", "0.5", "1.0", "--seeds", "2", "--seed0", "3", "--group", "2", "--quiet",
        "--checkpoint-every", "1"]
    assert kit_cells.sweep_argv(cell, {"quiet": False}, resume=True) == ["--resume", "--steps", "8"]
    ac = kit.Cell("c", "ac", {"num_envs": 4}, trials=5, vary=("l", (1, 10)))
    assert kit_cells.sweep_argv(ac) == ["--learner", "ac", "--num-envs", "4", "--trials", "5", "--l", "1", "10"]


PUBLISHED = {"exploration2": RESULTS / "exploration2" / "runs", "thesis_ac": RESULTS / "thesis_ac",
             "nmp_diagnosis": RESULTS / "exploration2" / "diagnosis",
             "gait_stages": RESULTS / "exploration2" / "diagnosis" / "stages"}


def test_every_published_cell_is_the_sweep_its_sweep_json_holds():
    """Each cell whose published copy exists makes the spec that copy's sweep.json saved (the points,
    seeds, varied values and the resolved base config), up to the budget (the gait stages' cells are
    one sweep resumed at larger budgets): a study resumed from its published copy continues it."""
    from nmrl.experiments import sweep

    n = 0
    for study, root in PUBLISHED.items():
        s, cells = CELLS[study]
        for name, cell in cells.items():
            if not (root / cell.name / "sweep.json").is_file():
                continue
            saved, new = sweep.load_spec(root / cell.name), spec_of(s, cell)
            budget = {k: options.value(saved.base, k) for k in ("steps", "trials")}
            assert dataclasses.replace(new, base=options.replace(new.base, **budget)) == saved, (study, name)
            n += 1
    assert n >= 71  # the cells of the finished studies and study 3's first two; each cell a running study starts adds one
