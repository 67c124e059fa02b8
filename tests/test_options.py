"""Each config field declared once (nmrl/options.py): what is generated from the declarations.

* every committed run config keeps its identity digest (the digests written by the hand-written
  configs, tests/data/config_identities.json) and agrees with its compact continuation state;
* the traced values: PPO's ``Hyper`` from the declarations gives the chunk bit for bit that a
  ``Hyper`` with the leaves in another order gives, its values from an independent computation;
* the checks: a value outside a field's declared range is refused by the config's own ``validate``
  (and so before anything is built); a range belongs to the field that declares it, not to every
  config with a field of that name;
* one seed limit: every learner takes JAX's 32-bit unsigned PRNG seeds;
* the exploration: PPO takes every process, and ``--period-s`` & co. are parsed under the spec's
  names for every learner.
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib
import re
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nmrl import explore, learners, options
from nmrl.learners import ppo, ppo_config
from nmrl.paper.env import MODEL_PATH
from nmrl.learners.ac_config import TrainConfig
from nmrl.runs import bounds, compact, identity
from nmrl.runs.checkpoint_files import _sha256_file

try:
    from tiny_env import TinyEnv
except ImportError:  # pragma: no cover
    from tests.tiny_env import TinyEnv

REPO = pathlib.Path(__file__).resolve().parents[1]
IDENTITIES = json.loads((REPO / "tests/data/config_identities.json").read_text())


def test_every_committed_run_config_keeps_its_identity_digest():
    recorded = IDENTITIES["identity_digest"]
    assert len(recorded) >= 190 and _sha256_file(MODEL_PATH) == IDENTITIES["model_sha256"]
    for path, digest in recorded.items():
        cfg = identity.load_run_config(REPO / pathlib.Path(path).parent)
        cfg.validate()
        assert identity.identity_digest(cfg, IDENTITIES["model_sha256"]) == digest, path


def test_every_committed_compact_state_matches_its_run_config():
    """What resuming from a compact state checks before anything runs: the state's saved config and
    the run's config.json are the same run (nmrl/runs/identity.py's ``_check_config``)."""
    states = [p for p in sorted((REPO / "results").rglob("compact.npz"))  # a learner's (not a Brax tree's)
              if compact._read_npz(p, "")[0].get("format") == compact.COMPACT_FORMAT]
    assert len(states) >= 180
    for p in states:
        meta, _ = compact.load_compact(p.parent)
        run = identity.load_run_config(p.parent)
        if run is not None:
            identity._check_config(meta, run)


class _OtherOrder(NamedTuple):
    """PPO's traced values in another leaf order, computed here from the config's numbers."""

    learning_rate: jax.Array
    entropy_cost: jax.Array
    clip_eps: jax.Array
    vf_coef: jax.Array
    gamma: jax.Array
    lam: jax.Array
    reward_scale: jax.Array
    process: explore.Process


def test_ppo_hyper_from_the_declarations_gives_the_same_chunk_bit_for_bit():
    cfg = options.build(ppo_config.PPOConfig, num_envs=2, batch_size=4, num_minibatches=2, epochs=2, unroll_s=0.1, policy_layers=2,
                               policy_width=8, value_layers=2, value_width=8, control_dt=0.02, exploration="ou",
                               sigma=0.7, corr_time_s=0.05, discount_horizon_s=0.3, clip_eps=0.2).resolved()
    f32 = np.float32
    other = _OtherOrder(f32(3e-4), f32(1e-3), f32(0.2), f32(0.5), f32(math.exp(-0.02 / 0.3)),
                        f32(math.exp(-0.02 / ppo_config.BRAX_HORIZON_S)), f32(1.0),
                        explore.Process(phi=jnp.asarray([math.exp(-0.02 / 0.05)], jnp.float32),
                                        w=jnp.ones(1, jnp.float32), sigma=jnp.float32(0.7),
                                        period=jnp.asarray(explore.NO_RESET, jnp.int32)))
    declared = ppo_config.Hyper.from_config(cfg)
    for k in _OtherOrder._fields:
        for a, b in zip(jax.tree.leaves(getattr(declared, k)), jax.tree.leaves(getattr(other, k))):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=k)
    tr = ppo.make_ppo(cfg, TinyEnv())
    key = jax.random.PRNGKey(5)
    runs = [jax.jit(tr.chunk)(jax.jit(tr.init)(key, h)) for h in (declared, other)]
    (s1, m1), (s2, m2) = runs
    for a, b in zip(jax.tree.leaves((s1.policy, s1.value, s1.opt, s1.obs_stats, s1.noise, m1)),
                    jax.tree.leaves((s2.policy, s2.value, s2.opt, s2.obs_stats, s2.noise, m2))):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.parametrize("cls, field, value", [
    (ppo_config.PPOConfig, "sigma", 0.0), (ppo_config.PPOConfig, "learning_rate", 0.0),
    (ppo_config.PPOConfig, "clip_eps", 0.0), (ppo_config.PPOConfig, "stop_prob", 1.5),
    (ppo_config.PPOConfig, "squash", "sigmoid"), (ppo_config.PPOConfig, "normalize_obs", 1),
    (ppo_config.PPOConfig, "entropy_cost", float("nan")), (TrainConfig, "sigma", 0.0), (TrainConfig, "beta_v", -1.0),
    (TrainConfig, "gamma", 1.5), (TrainConfig, "stop_prob", 1.5), (TrainConfig, "preset", "turbo"),
])
def test_config_validate_refuses_a_value_outside_its_declared_range(cls, field, value):
    with pytest.raises(ValueError, match=rf"^{field}={value!r} is invalid: "):
        options.build(cls, **{field: value}).validate()


@pytest.mark.parametrize("cls, field, value, allowed", [
    (TrainConfig, "beta_theta", 1e3, "[0, 1]"), (ppo_config.PPOConfig, "learning_rate", 1.5, "(0, 1]"),
    (ppo_config.PPOConfig, "sigma", 11.0, "(0, 10]"), (TrainConfig, "control_dt", 2.0, "(0, 1]"),
])
def test_a_cap_of_sense_is_checked_before_a_run_not_by_validate(cls, field, value, allowed):
    """Code may set a step size beyond 1 (a test that makes a run diverge on purpose); a run may not."""
    cfg = options.build(cls, **{field: value})
    cfg.validate()
    with pytest.raises(ValueError, match=rf"^{field}={value!r} is invalid: must be in {re.escape(allowed)}"):
        bounds.check(cfg)


def test_a_range_belongs_to_the_config_that_declares_it():
    """A config of another learner with a field named ``sigma`` but no declared range keeps its own
    meaning: only float32 limits apply to it."""

    @dataclasses.dataclass(frozen=True)
    class Other:
        sigma: float = 20.0
        learning_rate: float = 5.0

    bounds.check(Other())
    with pytest.raises(ValueError, match=r"^sigma=20.0 is invalid: must be in \(0, 10\]"):
        bounds.check(TrainConfig(sigma=20.0))


@pytest.mark.parametrize("learner", ["ac", "ppo"])
def test_every_learner_takes_every_32_bit_unsigned_seed(learner):
    cfg = learners.get(learner).config
    top = 2**32 - 1
    keys = {tuple(np.asarray(jax.random.PRNGKey(s)).tolist()) for s in (0, 2**31 - 1, 2**31, top)}
    assert len(keys) == 4  # JAX gives each of these seeds a key of its own
    options.build(cfg, seed=top).validate()
    for bad in (top + 1, -1):
        with pytest.raises(ValueError, match=rf"^seed={bad} is invalid: must be an integer in \[0, {top}\]"):
            options.build(cfg, seed=bad).validate()


def test_ppo_takes_every_exploration_process():
    lr = learners.get("ppo")
    assert lr.explorations == explore.KINDS
    for kind in explore.KINDS:
        options.build(ppo_config.PPOConfig, exploration=kind).resolved()


@pytest.mark.parametrize("learner, expect", [("ac", {"l": 5}), ("ppo", {"period_s": 0.1})])
def test_exploration_options_are_parsed_under_the_spec_names(learner, expect):
    from nmrl.cli import arguments, config_options

    lr = config_options.get_learner(learner)
    args = arguments.build_parser(lr).parse_args(["train", "--learner", learner, "--out", "x", "--exploration",
                                            "nm-periods", "--period-s", "0.1"])
    assert args.period_s == 0.1 and not any(k.startswith("x_") for k in vars(args))
    cfg = config_options.config_from_args(args)
    assert {k: options.value(cfg, k) for k in expect} == expect  # l = round(0.1 s / 0.02 s)


@pytest.mark.parametrize("learner", ["ac", "ppo"])
def test_traced_fields_are_the_ones_a_sweep_may_vary(learner):
    """Configs that differ in a traced field run as one program, in a static one (PPO's ``order``,
    a shape; the actor-critic's hidden units) not."""
    lr = learners.get(learner)
    base = lr.config()
    assert lr.hyper_fields == options.traced(lr.config) and "seed" not in lr.hyper_fields
    varied = {"ac": dict(l=3, gamma=0.9, beta_v=0.1), "ppo": dict(clip_eps=0.1, sigma=2.0, gae_horizon_s=1.0)}
    static = {"ac": dict(hidden_actor=7), "ppo": dict(order=3)}
    if learner == "ppo":
        base = options.replace(base, exploration="colored")
    assert learners.program_key(options.replace(base, **varied[learner])) == learners.program_key(base)
    assert learners.program_key(options.replace(base, **static[learner])) != learners.program_key(base)
