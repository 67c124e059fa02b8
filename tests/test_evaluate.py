"""Evaluation of a saved policy (nmrl.analysis.evaluate): JSON summary, pictures, determinism, bad paths."""

from __future__ import annotations

import json
import math

import imageio.v3 as iio
import jax
import numpy as np
import pytest

from nmrl.runs import checkpoint
from nmrl.analysis import evaluate
from nmrl.runs.checkpoint import CheckpointError
from nmrl.paper.env import REWARD_TERMS
from nmrl.paper.learner import TrainConfig, make_train

CFG = TrainConfig(num_envs=4, chunk_steps=5, hidden_actor=8, hidden_critic=8, steps=10, seed=1)
SECONDS = 1.0
POLICY_KEYS = {"avg_reward", "forward_speed", "distance", "terms", "ground_share", "nonfinite"}


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A freshly trained tiny run: two chunks, a checkpoint after each."""
    out = tmp_path_factory.mktemp("eval_run")
    trainer = make_train(CFG)
    chunk = jax.jit(trainer.chunk)
    ts = jax.device_put(jax.jit(trainer.init)(jax.random.PRNGKey(CFG.seed)))
    for _ in range(2):
        ts, _ = chunk(ts)
        checkpoint.save(out, ts, trainer.config)
    return out


@pytest.fixture(scope="module")
def result(run):
    return evaluate.evaluate(run, seconds=SECONDS, seed=0)


def _check_policy(d: dict) -> None:
    assert set(d) == POLICY_KEYS
    assert set(d["terms"]) == set(REWARD_TERMS)
    assert set(d["ground_share"]) == {"heel", "knee", "head"}
    assert d["nonfinite"] == 0
    for v in (d["avg_reward"], d["forward_speed"], d["distance"], *d["terms"].values()):
        assert isinstance(v, float) and math.isfinite(v)
    for v in d["ground_share"].values():
        assert 0.0 <= v <= 1.0
    assert math.isclose(d["avg_reward"], sum(d["terms"].values()), rel_tol=1e-4, abs_tol=1e-5)


def test_json_well_formed(result, run):
    text = json.dumps(result, allow_nan=False)
    back = json.loads(text)
    for k in ("run_dir", "step", "seconds", "seed", "control_dt", "l", "deterministic", "exploring"):
        assert k in back, k
    assert back["run_dir"] == str(run) and back["step"] == 10 and back["seed"] == 0
    assert back["seconds"] == SECONDS and back["control_dt"] == CFG.control_dt and back["l"] == CFG.l
    assert back["steps"] == round(SECONDS / CFG.control_dt)
    _check_policy(back["deterministic"])
    _check_policy(back["exploring"])
    assert back["deterministic"] != back["exploring"]  # the noise changes the trial
    assert json.loads((run / "eval" / "eval.json").read_text()) == back


def test_pictures(result, run):
    png = run / "eval" / "strobe.png"
    gif = run / "eval" / "gait.gif"
    assert result["files"] == {"strobe": str(png), "gif": str(gif)}
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    img = iio.imread(png)
    assert 200 <= img.shape[0] <= 3000 and 300 <= img.shape[1] <= 3000, img.shape
    assert img[..., :3].std() > 5  # not blank
    frames = iio.imread(gif, index=None)
    n_expected = round(SECONDS / CFG.control_dt) // round(1 / (25 * CFG.control_dt)) + 1
    assert frames.shape[0] == n_expected and frames.shape[1] >= 100 and frames.shape[2] >= 200
    assert iio.immeta(gif)["duration"] == 40  # 25 frames per second of simulated time
    assert not list((run / "eval").glob(".*tmp*"))


def test_deterministic_for_same_checkpoint_and_seed(result, run):
    text = (run / "eval" / "eval.json").read_text()
    again = evaluate.evaluate(run, seconds=SECONDS, seed=0, render=False)
    again.pop("files", None)
    first = dict(result)
    first.pop("files")
    assert json.dumps(again, sort_keys=True) == json.dumps(first, sort_keys=True)
    other = evaluate.evaluate(run, seconds=SECONDS, seed=3, render=False)
    assert other["deterministic"] == result["deterministic"]  # no randomness without noise
    assert other["exploring"] != result["exploring"]
    evaluate.evaluate(run, seconds=SECONDS, seed=0)
    assert (run / "eval" / "eval.json").read_text() == text


def test_older_step(run):
    r = evaluate.evaluate(run, step=5, seconds=SECONDS, render=False, out_dir=run / "eval_5")
    assert r["step"] == 5 and (run / "eval_5" / "eval.json").is_file()


def test_bad_path(tmp_path, run):
    bad = tmp_path / "missing_run"
    with pytest.raises(CheckpointError, match=str(bad)):
        evaluate.evaluate(bad, seconds=SECONDS)
    with pytest.raises(CheckpointError, match="step 7"):
        evaluate.evaluate(run, step=7, seconds=SECONDS)
    with pytest.raises(ValueError, match="seconds"):
        evaluate.evaluate(run, seconds=0.0)


def test_initial_pose_looks_like_a_cheetah(run):
    """The rollout's frame 0 is the reset pose: trunk ~0.6 m up, head ahead, hind paw behind."""
    cfg, theta, _ = checkpoint.restore_policy(run)
    traj = evaluate.rollout(cfg, theta, seconds=SECONDS, seed=0, exploring=False)
    pos = traj["pos"]
    assert pos.shape == (round(SECONDS / CFG.control_dt) + 1, 10, 2)
    p = pos[0]
    assert abs(p[3, 1] - 0.6) < 0.1 and abs(p[4, 1] - 0.6) < 0.1  # hip and neck
    assert p[5, 0] > p[4, 0] > p[3, 0] > p[0, 0] - 0.3  # head ahead of the neck ahead of the hip
    assert np.all(np.isfinite(pos))
