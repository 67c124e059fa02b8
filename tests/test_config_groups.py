"""A learner's config is nested, its flat view is config.json's layout (nmrl/options.py's groups).

* every learner's config holds its groups (``environment``, ``budget``, PPO's ``noise``), each leaf
  with one flat name, and its flat view has the keys, in the order, of a committed run's config.json;
* a committed config.json read into the nested config and written back gives the same text, byte for
  byte (the identity digests hash this view: tests/data/config_identities.json);
* a config is made and changed by flat names, in whichever group a name is, and an unknown name is
  refused in one line.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib

import pytest

from nmrl import learners, options, tasks
from nmrl.learners.ac_config import ACBudget, TrainConfig
from nmrl.learners.ppo_config import PPOBudget, PPOConfig, PPONoise
from nmrl.runs import store

REPO = pathlib.Path(__file__).resolve().parents[1]
#: a committed run of each learner written with today's fields
COMMITTED = {"ac": REPO / "results/thesis_ac/grid/dt0.0025/points/p0.2s_s3/config.json",
             "ppo": REPO / "results/exploration2/diagnosis/stages/dt0.02/white/points/s0/config.json"}


@pytest.mark.parametrize("name", sorted(COMMITTED))
def test_the_flat_view_has_the_keys_of_a_committed_config_json_in_their_order(name):
    saved = json.loads(COMMITTED[name].read_text())
    cls = learners.get(name).config
    assert [learners.KEY, *options.leaves(cls)] == list(saved)
    assert list(learners.config_dict(cls())) == list(saved)


@pytest.mark.parametrize("name", sorted(COMMITTED))
def test_a_committed_config_json_reads_into_the_nested_config_and_writes_back_byte_for_byte(name, tmp_path):
    text = COMMITTED[name].read_text()
    cfg = learners.config_from_dict(json.loads(text))
    assert isinstance(cfg.environment, tasks.EnvFields) and cfg.budget.seed == json.loads(text)["seed"]
    store.write_config(tmp_path, cfg)
    assert (tmp_path / store.CONFIG_FILE).read_text() == text


def test_every_config_in_the_tree_reads_into_its_learners_config_and_back():
    paths = sorted(REPO.glob("results/**/config.json")) + sorted(REPO.glob("tests/data/**/config.json"))
    assert len(paths) > 100
    for path in paths:
        d = json.loads(path.read_text())
        if not isinstance(d, dict) or not (set(d) - {learners.KEY}) <= set(options.leaves(
                learners.get(d.get(learners.KEY) or learners.DEFAULT).config)):
            continue  # a baseline's or a study's config
        cfg = learners.config_from_dict(d)
        flat = learners.config_dict(cfg)
        saved = {k: v for k, v in d.items() if k != learners.KEY}
        assert {k: flat[k] for k in saved} == saved, path


def test_the_groups_and_their_access_paths():
    ac, ppo = TrainConfig(), PPOConfig()
    assert options.groups(TrainConfig) == {"environment": tasks.EnvFields, "budget": ACBudget}
    assert options.groups(PPOConfig) == {"environment": tasks.EnvFields, "noise": PPONoise, "budget": PPOBudget}
    assert (ac.environment.control_dt, ac.budget.num_envs, ac.sigma) == (0.02, 256, 1.0)
    assert (ppo.environment.physics, ppo.noise.exploration, ppo.noise.sigma, ppo.budget.num_envs) == \
        ("mjx", "white", 1.0, 64)
    assert options.leaves(PPOConfig)["beta"] == (("noise", "beta"), PPONoise)
    assert options.value(ppo, "seed") == 0 and "sigma" in options.leaves(TrainConfig)


def test_a_config_is_made_and_changed_by_flat_names():
    cfg = options.build(PPOConfig, num_envs=8, control_dt=0.01, beta=1.0, exploration="colored", clip_eps=0.2)
    assert (cfg.budget.num_envs, cfg.environment.control_dt, cfg.noise.beta, cfg.clip_eps) == (8, 0.01, 1.0, 0.2)
    new = options.replace(cfg, seed=3, physics="c", epochs=2)
    assert (new.budget.seed, new.environment.physics, new.epochs, new.budget.num_envs) == (3, "c", 2, 8)
    assert options.replace(cfg) is cfg
    assert options.flat(options.build(TrainConfig, **options.flat(TrainConfig(l=3)))) == options.flat(TrainConfig(l=3))


@pytest.mark.parametrize("call", [lambda: options.replace(TrainConfig(), num_env=4),
                                  lambda: options.build(PPOConfig, clip=0.1),
                                  lambda: options.replace(PPOConfig(), environment=tasks.EnvFields())])
def test_an_unknown_flat_name_is_refused_in_one_line(call):
    with pytest.raises(ValueError, match="no such field of") as e:
        call()
    assert "\n" not in str(e.value)


def test_a_flat_name_twice_among_the_leaves_is_refused():
    @dataclasses.dataclass(frozen=True)
    class Twice:
        control_dt: float = 0.1
        environment: tasks.EnvFields = options.group(tasks.EnvFields)

    with pytest.raises(TypeError, match="occur twice"):
        options.leaves(Twice)
