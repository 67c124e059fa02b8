"""The one driver takes any learner of the contract (nmrl/learners/contract.py).

A second learner is defined here, small on purpose: a linear policy a = W^T s + xi (xi ~ N(0,
sigma^2 I), white) on the real Half-Cheetah, with a trivial update (W += lr * mean_e (r_e - b) s_e
xi_e^T, b a running mean of the reward). Through it the driver, the checkpoints, the compact
continuation state, the sweep, evaluation and the command line are run without the actor-critic:
a resumed run equals an uninterrupted one bit for bit, a point of a sweep equals the same run
alone, evaluation rolls out the learner's own policy (checked against a plain loop over the
environment), and the learner's options appear on the command line.
"""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

from nmrl import cli, learners, options, tasks
from nmrl.analysis import evaluate
from nmrl.cli import arguments, config_options
from nmrl.experiments import sweep
from nmrl.paper.env import EnvConfig, HalfCheetah
from nmrl.runs import checkpoint, driver, store

SKIP = {"wall_s", "steps_per_s"}


@dataclasses.dataclass(frozen=True)
class ToyBudget:
    seed: int = 0
    num_envs: int = 2
    chunk_steps: int = 5
    steps: int | None = None
    trials: int | None = None
    max_param_norm: float = 1e5


@dataclasses.dataclass(frozen=True)
class ToyEnvironment(tasks.EnvFields):
    """The paper's robot, stopping a trial with probability 0.02 per control step."""

    stop_prob: float = options.same_as(tasks.EnvFields, "stop_prob", 0.02)


@dataclasses.dataclass(frozen=True)
class ToyConfig:
    lr: float = 1e-4  #: step size of the update
    sigma: float = 0.3  #: std of the white exploration noise
    budget: ToyBudget = options.group(ToyBudget)
    environment: ToyEnvironment = options.group(ToyEnvironment)

    def validate(self) -> None:
        if not (isinstance(self.lr, (int, float)) and self.lr >= 0):
            raise ValueError(f"lr={self.lr!r} is invalid: must be >= 0")
        if not (isinstance(self.sigma, (int, float)) and self.sigma > 0):
            raise ValueError(f"sigma={self.sigma!r} is invalid: must be > 0")
        for name in ("num_envs", "chunk_steps"):
            if not (isinstance(getattr(self.budget, name), int) and getattr(self.budget, name) >= 1):
                raise ValueError(f"{name}={getattr(self.budget, name)!r} is invalid: must be an integer >= 1")
        self.environment.env_config().validate()

    def resolved(self) -> "ToyConfig":
        self.validate()
        return options.replace(self, steps=10) if self.budget.steps is None and self.budget.trials is None else self


class ToyHyper(NamedTuple):
    lr: jax.Array
    sigma: jax.Array

    @staticmethod
    def from_config(c: ToyConfig) -> "ToyHyper":
        return ToyHyper(jnp.float32(c.lr), jnp.float32(c.sigma))


@struct.dataclass
class ToyState:
    w: jax.Array
    baseline: jax.Array
    env: Any
    key: jax.Array
    hyper: ToyHyper
    step: jax.Array
    trials: jax.Array
    diverged: jax.Array


class ToyTrainer(NamedTuple):
    config: ToyConfig
    env: Any
    init: Any
    chunk: Any


def make_toy(config: ToyConfig, env=None, *, axis_name=None, num_shards: int = 1) -> ToyTrainer:
    cfg = config.resolved()
    env = env or HalfCheetah(cfg.environment.env_config())
    N = cfg.budget.num_envs
    n_local = N // num_shards

    def psum(x):
        return jax.lax.psum(x, axis_name) if num_shards > 1 else x

    def init(key, hyper=None):
        hyper = ToyHyper.from_config(cfg) if hyper is None else hyper
        k_env, key = jax.random.split(key)
        z32 = jnp.zeros((), jnp.int32)
        return ToyState(w=jnp.zeros((env.obs_dim, env.act_dim), jnp.float32), baseline=jnp.zeros((), jnp.float32),
                        env=jax.vmap(env.reset)(jax.random.split(k_env, N)), key=key, hyper=hyper, step=z32,
                        trials=z32, diverged=jnp.zeros((), bool))

    def step(ts: ToyState, _):
        key, k = jax.random.split(ts.key)
        eps = jax.random.normal(k, (N, env.act_dim), jnp.float32)
        if num_shards > 1:
            eps = jax.lax.dynamic_slice_in_dim(eps, jax.lax.axis_index(axis_name) * n_local, n_local)
        xi = ts.hyper.sigma * eps
        obs = ts.env.obs
        es = jax.vmap(env.step)(ts.env, obs @ ts.w + xi)
        r_mean = psum(jnp.sum(es.reward)) / N
        g = psum(jnp.einsum("n,ni,nj->ij", es.reward - ts.baseline, obs, xi)) / N
        w = ts.w + ts.hyper.lr * g
        ok = jnp.isfinite(jnp.linalg.norm(w)) & (jnp.linalg.norm(w) < cfg.budget.max_param_norm) & ~ts.diverged
        new = ts.replace(w=jnp.where(ok, w, ts.w), baseline=ts.baseline + 0.1 * (r_mean - ts.baseline), env=es,
                         key=key, step=ts.step + 1, trials=ts.trials + psum(jnp.sum(es.done > 0).astype(jnp.int32)),
                         diverged=ts.diverged | ~ok)
        return new, {"reward": r_mean, "speed": psum(jnp.sum(es.metrics["forward_speed"])) / N,
                     "trials": psum(jnp.sum(es.done > 0).astype(jnp.int32))}

    def chunk(ts):
        ts, s = jax.lax.scan(step, ts, None, length=cfg.budget.chunk_steps)
        return ts, {"avg_reward": jnp.mean(s["reward"]), "forward_speed": jnp.mean(s["speed"]),
                    "trials_in_chunk": jnp.sum(s["trials"]), "step": ts.step, "trials": ts.trials,
                    "diverged": ts.diverged, "w_norm": jnp.linalg.norm(ts.w)}

    return ToyTrainer(cfg, env, init, chunk)


def toy_policy(cfg: ToyConfig, env) -> learners.Policy:
    return learners.Policy(act=lambda p, obs, xi: obs @ p["w"] + xi,
                           noise_init=lambda act_dim: jnp.zeros((), jnp.float32),
                           noise_step=lambda a, s, eps: (s, a["sigma"] * eps),
                           noise_args={"sigma": jnp.float32(cfg.sigma)})


TOY = learners.register(learners.Learner(
    name="toy", config=ToyConfig, hyper=ToyHyper.from_config, hyper_fields=("lr", "sigma"), make=make_toy,
    env_fields=("env",), compact_fields=("w", "baseline"), policy_fields=("w",), policy=toy_policy,
    doc="a linear policy with a trivial update (tests only)", help={"lr": "toy step size"}, sweep_field="lr",
    describe=lambda c: {"lr": float(c.lr), "sigma": float(c.sigma)}))

CFG = options.build(ToyConfig, lr=3e-4, steps=15)


def _rows(d):
    return [{k: v for k, v in r.items() if k not in SKIP} for r in store.read_metrics(d)]


def _leaves(ts):
    return [np.asarray(x) for x in jax.tree.leaves(ts)]


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    d = tmp_path_factory.mktemp("toy") / "a"
    driver.train(CFG, d, progress=False, devices=1)
    return d


def test_config_json_and_checkpoints_name_the_learner(uninterrupted):
    d = uninterrupted
    assert json.loads((d / store.CONFIG_FILE).read_text()) == {"learner": "toy", **options.flat(CFG.resolved())}
    assert checkpoint.load_run_config(d) == CFG.resolved()
    meta = checkpoint.load_metadata(d)
    assert meta["learner"] == "toy" and meta["step"] == 15
    assert [r["step"] for r in store.read_metrics(d)] == [5, 10, 15]
    # the policy item holds the learner's policy fields: the same W as the full state
    cfg, w = checkpoint.restore_policy(d)
    full = checkpoint.restore(d, make_toy(cfg))
    np.testing.assert_array_equal(np.asarray(w), np.asarray(full.w))
    assert float(np.abs(np.asarray(full.w)).sum()) > 0  # it learned something (the update is not a no-op)


def test_resume_is_bit_identical(uninterrupted, tmp_path):
    d = tmp_path / "b"
    driver.train(CFG, d, progress=False, devices=1, max_chunks=1)
    assert checkpoint.all_steps(d) == [5]
    driver.train(CFG, d, resume=True, progress=False, devices=1)
    assert _rows(d) == _rows(uninterrupted)
    tr = make_toy(CFG)
    for a, b in zip(_leaves(checkpoint.restore(d, tr)), _leaves(checkpoint.restore(uninterrupted, tr)), strict=True):
        np.testing.assert_array_equal(a, b)
    # a checkpoint of this learner is refused by another learner's trainer
    with pytest.raises(checkpoint.ForeignCheckpoint, match="toy"):
        checkpoint.restore(d, learners.get("ac").make(options.build(learners.get("ac").config, num_envs=2,
                                                                                   hidden_actor=4, hidden_critic=4)))


@pytest.mark.slow  # ~55 s cold; by default test_sweep and test_layout check both for the paper's learner
def test_sweep_point_equals_the_run_alone_and_continues_from_compact_state(uninterrupted, tmp_path):
    out = tmp_path / "sweep"
    spec = sweep.SweepSpec(ls=(1e-4, 3e-4), seeds=1, base=dataclasses.replace(CFG, lr=1e-4), field="lr")
    rows = sweep.run_sweep(spec, out, progress=False)
    assert [(r["lr"], r["seed"], r["steps"]) for r in rows] == [(1e-4, 0, 15), (3e-4, 0, 15)]
    saved = json.loads((out / sweep.SPEC_FILE).read_text())
    assert (saved["learner"], saved["field"]) == ("toy", "lr")
    alone, point = _rows(uninterrupted), _rows(sweep.point_dir(out, 3e-4, 0, "lr"))
    assert [r["step"] for r in point] == [r["step"] for r in alone]
    for p, a in zip(point, alone):  # compiled apart: equal up to float rounding
        assert {k: v for k, v in p.items() if not isinstance(v, float)} == \
               {k: v for k, v in a.items() if not isinstance(v, float)}
        np.testing.assert_allclose([p[k] for k in a if isinstance(a[k], float)],
                                   [a[k] for k in a if isinstance(a[k], float)], rtol=1e-5, atol=1e-6)
    other = _rows(sweep.point_dir(out, 1e-4, 0, "lr"))
    assert other[-1]["w_norm"] != point[-1]["w_norm"]  # the traced lr is used, not the first point's

    # a fresh clone of the results: no checkpoints, only the compact states; a larger budget continues
    for d in (out / "points").iterdir():
        shutil.rmtree(d / "checkpoints")
        with np.load(d / store.COMPACT_FILE) as z:
            assert int(z["step"]) == 15 and "w" in z.files and "baseline" in z.files
    sweep.run_sweep(dataclasses.replace(spec, base=options.replace(spec.base, steps=25)), out, resume=True,
                    progress=False)
    d = sweep.point_dir(out, 3e-4, 0, "lr")
    got = store.read_metrics(d)
    assert [r["step"] for r in got] == [5, 10, 15, 20, 25]
    assert got[-1]["trials"] >= got[2]["trials"]
    (rec,) = store.read_jsonl(d / store.RESUMES_FILE)
    assert rec["from_step"] == 15 and rec["from_checkpoint"].endswith(store.COMPACT_FILE)


@pytest.mark.slow  # ~70 s cold; by default test_cli checks train, resume and eval through the CLI for the paper's learner
def test_cli_train_resume_and_eval_through_the_contract(tmp_path, capsys):
    d = tmp_path / "run"
    tiny = ["--num-envs", "2", "--chunk-steps", "5", "--quiet", "--devices", "1"]
    assert cli.main(["train", "--learner", "toy", "--lr", "0.0003", *tiny, "--steps", "5", "--out", str(d)]) == 0
    assert json.loads((d / store.CONFIG_FILE).read_text())["learner"] == "toy"
    # --resume takes the run's own learner (from config.json) without --learner
    assert cli.main(["train", "--resume", "--steps", "10", "--out", str(d), "--quiet", "--devices", "1"]) == 0
    assert [r["step"] for r in store.read_metrics(d)] == [5, 10]
    capsys.readouterr()
    # another learner on this run: refused, nothing changed
    before = (d / store.METRICS_FILE).read_bytes()
    assert cli.main(["train", "--learner", "ac", "--resume", "--steps", "20", "--out", str(d), "--quiet"]) == 2
    assert "'toy'" in capsys.readouterr().err
    assert (d / store.METRICS_FILE).read_bytes() == before

    assert cli.main(["eval", str(d), "--seconds", "0.3", "--no-render"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert (res["learner"], res["step"], res["lr"]) == ("toy", 10, 3e-4)
    # the deterministic rollout is a = W^T s on a trial without random stops: a plain loop agrees
    _, w = checkpoint.restore_policy(d)
    env = HalfCheetah(EnvConfig(control_dt=0.02, stop_prob=0.0, auto_reset=False))
    s, rewards = env.reset(jax.random.split(jax.random.PRNGKey(0))[0]), []
    step = jax.jit(env.step)
    for _ in range(res["steps"]):
        s = step(s, s.obs @ w)
        rewards.append(float(s.reward))
    assert res["deterministic"]["avg_reward"] == pytest.approx(np.mean(rewards), rel=1e-4, abs=1e-5)
    assert res["exploring"]["avg_reward"] != res["deterministic"]["avg_reward"]


def test_help_lists_the_learners_own_options(capsys):
    with pytest.raises(SystemExit):
        cli.main(["train", "--learner", "toy", "--help"])
    text = capsys.readouterr().out
    assert "--lr" in text and "toy step size" in text and "--beta-theta" not in text
    with pytest.raises(SystemExit):
        cli.main(["train", "--help"])
    text = capsys.readouterr().out
    assert "--beta-theta" in text and "--lr " not in text and "--period-s" in text and "--exploration" in text


def test_unknown_learner_or_exploration_exit_2_and_write_nothing(tmp_path, capsys):
    out = tmp_path / "run"
    assert cli.main(["train", "--learner", "nope", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "'nope'" in err and "ac" in err and "toy" in err
    assert cli.main(["sweep", "--learner", "nope", "--out", str(out)]) == 2
    assert cli.main(["train", "--exploration", "pink", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "'pink'" in err and "nm-periods" in err
    for bad, needle in ((["--exploration", "ou"], "cannot use"), (["--exploration", "colored"], "cannot use"),
                        (["--l", "3", "--period-s", "0.2"], "not both"),
                        (["--alpha", "0.5", "--corr-time-s", "0.1"], "not both"),
                        (["--exploration", "white", "--l", "3"], "l = 1"),
                        (["--period-s", "0.01"], "period_s")):
        assert cli.main(["train", *bad, "--out", str(out)]) == 2, bad
        assert needle in capsys.readouterr().err
    assert not out.exists()


def _ac_config(argv):
    args = arguments.build_parser().parse_args(["train", *argv, "--out", "x"])
    return config_options.config_from_args(args)


def test_exploration_in_seconds_sets_the_actor_critics_l_and_alpha():
    """white is l = 1; nm-periods is l = round(period_s / dt), alpha = exp(-dt / corr_time_s); given
    nothing, the paper's l and alpha stay (and --l/--alpha mean what they always meant)."""
    base = _ac_config([])
    assert (base.l, base.alpha) == (10, 0.8)
    assert _ac_config(["--exploration", "white"]).l == 1
    c = _ac_config(["--exploration", "nm-periods", "--period-s", "0.1", "--corr-time-s", "0.05"])
    assert (c.l, c.alpha) == (5, pytest.approx(math.exp(-0.02 / 0.05)))
    c = _ac_config(["--control-dt", "0.01", "--period-s", "0.2", "--corr-time-s", str(-0.02 / math.log(0.8))])
    assert (c.l, c.alpha) == (20, pytest.approx(math.sqrt(0.8)))  # the paper's process at half the step
    assert _ac_config(["--exploration", "nm-periods"]) == base
    assert _ac_config(["--l", "3", "--alpha", "0.5"]) == dataclasses.replace(base, l=3, alpha=0.5)


def test_cli_sweep_varies_any_traced_field(tmp_path, capsys):
    out = tmp_path / "sw"
    tiny = ["--num-envs", "2", "--chunk-steps", "5", "--steps", "5", "--quiet", "--devices", "1"]
    assert cli.main(["sweep", "--learner", "toy", "--vary", "nope", "1", *tiny, "--out", str(out)]) == 2
    assert "sigma" in capsys.readouterr().err  # names the fields that may vary
    assert cli.main(["sweep", "--learner", "toy", "--vary", "sigma", "0.2", "0.4", "--seeds", "1", *tiny,
                     "--out", str(out)]) == 0
    assert sorted(p.name for p in (out / "points").iterdir()) == ["sigma0.2_s0", "sigma0.4_s0"]
    rows = sweep.load_results(out)
    assert [(r["sigma"], r["seed"], r["steps"]) for r in rows] == [(0.2, 0, 5), (0.4, 0, 5)]
    for r in rows:
        cfg = json.loads((out / "points" / f"sigma{r['sigma']:g}_s0" / store.CONFIG_FILE).read_text())
        assert (cfg["learner"], cfg["sigma"]) == ("toy", r["sigma"])
    # the saved spec resumes without --learner or --vary: a larger budget continues both points
    assert cli.main(["sweep", "--resume", "--steps", "10", "--out", str(out), "--quiet", "--devices", "1"]) == 0
    assert [r["steps"] for r in sweep.load_results(out)] == [10, 10]


def test_the_config_protocol_is_what_register_requires_and_every_learner_has_it():
    """``Config`` (the type nmrl.runs reads) names exactly the groups :func:`register` requires, its
    ``Budget`` the budget's fields, and every built-in learner's config has them with ``resolved`` and
    ``validate``."""
    from nmrl import tasks
    from nmrl.learners import contract

    assert set(contract.Config.__annotations__) == {"environment", "budget"}
    assert set(contract.Budget.__annotations__) == set(contract.COMMON_FIELDS)
    for name in contract.names():
        cls = contract.get(name).config
        groups = options.groups(cls)
        assert set(contract.COMMON_FIELDS) <= set(options.leaves(groups["budget"])), name
        assert issubclass(groups["environment"], tasks.EnvFields), name
        assert callable(cls.resolved) and callable(cls.validate), name
