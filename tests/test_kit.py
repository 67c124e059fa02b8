"""The study kit (nmrl/experiments/kit.py) and the second exploration study's cells as data
(nmrl/experiments/exploration2.py)."""

from __future__ import annotations

import csv
import dataclasses
import json

import pytest

from nmrl import cli
from nmrl.experiments import exploration2, kit

TINY = ("--learner", "ppo", "--num-envs", "4", "--batch-size", "4", "--num-minibatches", "1", "--epochs", "1",
        "--value-layers", "1", "--value-width", "8", "--policy-layers", "1", "--policy-width", "8",
        "--physics", "c", "--devices", "1")


def _spec(argv):
    learner = cli._learner("ppo")
    args = cli.build_parser(learner).parse_args(["sweep", *argv, "--out", "unused"])
    base = cli.config_from_args(args, skip=cli._sweep_skip(learner))
    spec = cli._varied_spec(args, learner, base)
    spec.validate()
    return spec


@pytest.mark.parametrize("cell", exploration2.SIGMA_SCREEN, ids=lambda c: c.name)
def test_every_screen_cell_is_a_valid_sweep_with_the_preregistered_design(cell):
    spec = _spec(cell.sweep)
    cfg = spec.base.resolved()
    assert spec.field == "sigma" and tuple(spec.ls) == (0.064, 0.16, 0.4, 1.0)
    assert [s for _, s in spec.points()][:2] == [100, 101]  # screen seeds are never grid seeds (0-7)
    # 4 iterations of 102.4 simulated seconds per environment, trials of 5 s, 2.5 ms physics, C
    assert cfg.steps * cfg.control_dt == pytest.approx(4 * 102.4)
    assert cfg.iteration_steps * cfg.control_dt == pytest.approx(102.4)
    assert cfg.env_config().step_stop_prob * 5.0 == pytest.approx(cfg.control_dt)
    assert cfg.physics == "c" and cfg.physics_timestep == 0.0025
    assert cfg.reward_scale == pytest.approx(cfg.control_dt / 0.02)
    assert (cfg.batch_size * cfg.num_minibatches * cfg.epochs, cfg.value_layers, cfg.value_width) == (131072, 2, 64)


def _tiny_study(tmp_path):
    cell = kit.Cell("screen/a", (*TINY, "--steps", "20", "--vary", "sigma", "0.5", "1.0", "--seeds", "1",
                                 "--seed0", "7"))
    return kit.Study("tiny", (cell,), kit.Endpoint(seconds=0.2, rollouts=2, start_noise=0.05))


def _rows(path):
    with open(path) as fh:
        return list(csv.DictReader(fh))


def test_a_study_runs_scores_publishes_and_continues_from_its_published_copy(tmp_path):
    study = _tiny_study(tmp_path)
    out = tmp_path / "out"
    rows = kit.run(study, out)
    assert [(r["point"], r["seed"], r["value"], r["steps"]) for r in rows] == \
        [("sigma0.5_s7", 7, 0.5, 20), ("sigma1_s7", 7, 1.0, 20)]
    for r in rows:
        e = json.loads((out / "screen/a/points" / r["point"] / kit.ENDPOINT).read_text())
        assert e["step"] == 20 and len(e["rollouts"]) == 2 and r["det_reward_per_s"] == e["reward_per_s"]
    assert [x["point"] for x in _rows(out / kit.ROWS)] == ["sigma0.5_s7", "sigma1_s7"]
    # a second run has nothing to do and scores nothing again
    stamp = {p: p.stat().st_mtime_ns for p in out.rglob(kit.ENDPOINT)}
    kit.run(study, out)
    assert {p: p.stat().st_mtime_ns for p in out.rglob(kit.ENDPOINT)} == stamp
    # published: no full checkpoints; a fresh directory continues from it to a larger budget
    pub = tmp_path / "pub"
    kit.publish(study, out, pub)
    assert not list(pub.rglob("checkpoints")) and (pub / kit.ROWS).exists()
    longer = dataclasses.replace(study, cells=(dataclasses.replace(
        study.cells[0], sweep=tuple("40" if x == "20" else x for x in study.cells[0].sweep)),))
    rows2 = kit.run(longer, tmp_path / "fresh", published=pub)
    assert [r["steps"] for r in rows2] == [40, 40]
    first = [json.loads(line) for line in (tmp_path / "fresh/screen/a/points/sigma0.5_s7/metrics.jsonl").open()]
    assert [m["step"] for m in first] == [20, 40]  # the published chunk kept, one more trained
