"""Evaluation of a saved policy (nmrl.analysis.evaluate): JSON summary, pictures, determinism, bad paths."""

from __future__ import annotations

import dataclasses
import json
import math

import imageio.v3 as iio
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from nmrl import options
from nmrl.runs import checkpoint
from nmrl.analysis import evaluate
from nmrl.runs.checkpoint import CheckpointError
from nmrl.paper.env import MODEL_PATH, REWARD_TERMS
from nmrl.learners.ac_config import TrainConfig
from nmrl.learners.ac_train import make_train

CFG = options.build(TrainConfig, num_envs=4, chunk_steps=5, hidden_actor=8, hidden_critic=8, steps=10, seed=1)
SECONDS = 1.0
POLICY_KEYS = {"avg_reward", "forward_speed", "distance", "terms", "ground_share", "gait", "nonfinite"}


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A freshly trained tiny run: two chunks, a checkpoint after each."""
    out = tmp_path_factory.mktemp("eval_run")
    trainer = make_train(CFG)
    chunk = jax.jit(trainer.chunk)
    ts = jax.device_put(jax.jit(trainer.init)(jax.random.PRNGKey(CFG.budget.seed)))
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
    g = d["gait"]
    assert set(g) == {"from_s", "hind_paw", "front_paw", "wrist_ground_share"}
    assert g["from_s"] == SECONDS / 2  # a 1-s rollout: strides counted over its second half
    for paw in ("hind_paw", "front_paw"):
        p = g[paw]
        assert isinstance(p["touchdowns"], int) and p["touchdowns"] >= 0
        assert math.isclose(p["stride_frequency_hz"], p["touchdowns"] / (SECONDS - g["from_s"]))
        assert (p["stride_length_m"] is None) == (p["touchdowns"] == 0)
        assert 0.0 <= p["ground_share"] <= 1.0
    assert 0.0 <= g["wrist_ground_share"] <= 1.0


def test_gait_counts_touchdowns_of_a_known_stride():
    """A made-up trial: the hind paw lands every 0.25 s (4 Hz) and stays down 0.1 s, the front paw
    never lands, the wrist is always down, the trunk moves at 3 m/s: 4 Hz, 0.75 m per stride, ground
    shares 0.4 / 0 / 1, counted from 1 s on (the landing from the initial pose is not a stride);
    then an irregular stride, whose interval_cv is large."""
    dt, n = 0.02, 500  # 10 s
    t = np.arange(n + 1) * dt
    pos = np.zeros((n + 1, 10, 2))
    pos[:, :, 1] = 0.3
    phase = np.arange(n + 1) % 12.5  # not a whole number of steps: the stride does not lock to dt
    pos[:, 0, 1] = np.where(phase >= 7.5, 0.0, 0.2)  # down 5 of every 12.5 steps
    pos[:, evaluate.WRIST, 1] = 0.0
    x = 3.0 * t
    g = evaluate.gait(pos, x, dt)
    assert g["from_s"] == 1.0
    hind = g["hind_paw"]
    window = (phase[50:] >= 7.5)
    expected = int(np.sum(~window[:-1] & window[1:]))
    assert hind["touchdowns"] == expected and abs(expected - 9 * 4) <= 1
    assert math.isclose(hind["stride_frequency_hz"], expected / 9.0)
    assert math.isclose(hind["stride_length_m"], 27.0 / expected)
    assert abs(hind["ground_share"] - 0.4) < 0.01
    assert hind["interval_cv"] < 0.05  # intervals of 12 and 13 steps
    assert g["front_paw"] == {"touchdowns": 0, "stride_frequency_hz": 0.0, "stride_length_m": None,
                              "interval_cv": None, "ground_share": 0.0}
    # an irregular stride: landings after 6, 7, 20, 6, 7, 20, ... steps
    pos[:, 0, 1] = 0.2
    at = 50 + np.cumsum(np.tile([6, 7, 20], 20))
    pos[at[at <= n], 0, 1] = 0.0
    gaps = np.tile([6, 7, 20], 20)[1:len(at[at <= n])]
    irregular = evaluate.gait(pos, x, dt)["hind_paw"]
    assert irregular["touchdowns"] == len(at[at <= n])
    assert math.isclose(irregular["interval_cv"], np.std(gaps) / np.mean(gaps)) and irregular["interval_cv"] > 0.5
    assert g["wrist_ground_share"] == 1.0


def test_json_well_formed(result, run):
    text = json.dumps(result, allow_nan=False)
    back = json.loads(text)
    for k in ("run_dir", "step", "seconds", "seed", "control_dt", "l", "deterministic", "exploring"):
        assert k in back, k
    assert back["run_dir"] == str(run) and back["step"] == 10 and back["seed"] == 0
    assert back["seconds"] == SECONDS and back["control_dt"] == CFG.environment.control_dt and back["l"] == CFG.l
    assert back["steps"] == round(SECONDS / CFG.environment.control_dt)
    _check_policy(back["deterministic"])
    _check_policy(back["exploring"])
    assert back["deterministic"] != back["exploring"]  # the noise changes the trial
    assert json.loads((run / "eval" / "eval.json").read_text()) == back


def test_pictures(result, run):
    png = run / "eval" / "strobe.png"
    gif = run / "eval" / "gait.gif"
    traj = run / "eval" / "trajectory.npz"
    assert result["files"] == {"strobe": str(png), "gif": str(gif), "trajectory": str(traj)}
    with np.load(traj) as z:
        pos, dt = z["pos"], float(z["control_dt"])
    assert dt == CFG.environment.control_dt and pos.shape == (round(SECONDS / CFG.environment.control_dt) + 1, 10, 2)
    assert np.all(np.isfinite(pos))
    np.testing.assert_allclose(pos[0, 0], [0.0, 0.1], atol=1e-5)  # frame 0: hind paw at (0, 0.1) m (Sec. V-C)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    img = iio.imread(png)
    assert 200 <= img.shape[0] <= 3000 and 300 <= img.shape[1] <= 3000, img.shape
    assert img[..., :3].std() > 5  # not blank
    frames = iio.imread(gif, index=None)
    n_expected = round(SECONDS / CFG.environment.control_dt) // round(1 / (25 * CFG.environment.control_dt)) + 1
    assert frames.shape[0] == n_expected and frames.shape[1] >= 100 and frames.shape[2] >= 200
    assert iio.immeta(gif)["duration"] == 40  # 25 frames per second of simulated time
    assert not list((run / "eval").glob(".*tmp*"))


def test_strobe_draws_the_poses_it_is_given(tmp_path, saved_figures):
    """The strobe's content: one stick figure every 0.1 s (every 5th control step), exactly the given
    joint positions, a pose with a non-finite joint left out, the joints drawn by mass (Sec. V-A)."""
    rng = np.random.default_rng(0)
    pos = rng.uniform(0.0, 1.0, size=(51, 10, 2))  # 1 s of 0.02 s steps, frame 0 the initial pose
    pos[10, 3, 1] = np.nan
    evaluate.plot_strobe(pos, 0.02, tmp_path / "strobe.png", title="T")
    ((_, fig),) = saved_figures
    (ax,) = fig.axes
    sticks = [ln for ln in ax.lines if len(ln.get_xdata()) == 10]
    frames = [0, 5, 15, 20, 25, 30, 35, 40, 45, 50]  # 10 is not finite
    assert len(sticks) == len(frames) == len(ax.collections)
    for ln, dots, i in zip(sticks, ax.collections, frames):
        np.testing.assert_array_equal(np.column_stack(ln.get_data()), pos[i])
        np.testing.assert_array_equal(dots.get_offsets(), pos[i])
        np.testing.assert_array_equal(dots.get_sizes(), 10.0 * np.array([1, 1, 1, 4, 1, 2, 1, 1, 1, 1]))
    (ground,) = [ln for ln in ax.lines if ln not in sticks]
    assert list(ground.get_ydata()) == [0.0, 0.0]
    assert ax.get_title() == "T\nevery 0.10 s, t = 0 to 1.00 s"
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("x [m]", "y [m]")
    assert (tmp_path / "strobe.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


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


@pytest.fixture(scope="module")
def compact_run(run, tmp_path_factory):
    """The newest state of ``run`` published as a compact state only (``compact.npz`` and the run's
    config.json, no checkpoints directory), as ``results/`` keeps its policies."""
    out = tmp_path_factory.mktemp("compact_run")
    trainer = make_train(CFG)
    ts = checkpoint.restore(run, trainer)
    checkpoint.save_compact(out, ts, trainer.config)
    (out / checkpoint.RUN_CONFIG).write_text(json.dumps(options.flat(CFG)))
    return out


def test_compact_policy_evaluates_like_its_checkpoint(run, compact_run, result):
    """A published compact state evaluates exactly as the checkpoint it was made from: the same
    parameters (bit for bit), the same step and trials, the same deterministic and exploring trials."""
    assert not checkpoint.checkpoint_dir(compact_run).exists()
    cfg_a, theta_a, v_a = checkpoint.restore_policy(run)
    cfg_b, theta_b, v_b = checkpoint.restore_policy(compact_run)
    assert cfg_a == cfg_b
    for a, b in ((theta_a, theta_b), (v_a, v_b)):
        assert jax.tree.structure(a) == jax.tree.structure(b)
        for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
            assert x.dtype == y.dtype
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    r = evaluate.evaluate(compact_run, seconds=SECONDS, seed=0, render=False)
    assert r["step"] == result["step"] == 10 and r["trials"] == result["trials"]
    assert r["deterministic"] == result["deterministic"]
    assert r["exploring"] == result["exploring"]
    assert (compact_run / "eval" / "eval.json").is_file()


def test_compact_policy_bad_step_and_foreign_config(compact_run, tmp_path):
    with pytest.raises(CheckpointError, match="compact state is at step 10, not 5"):
        evaluate.evaluate(compact_run, step=5, seconds=SECONDS, render=False)
    other = tmp_path / "other"
    other.mkdir()
    (other / checkpoint.COMPACT_FILE).write_bytes((compact_run / checkpoint.COMPACT_FILE).read_bytes())
    (other / checkpoint.RUN_CONFIG).write_text(json.dumps(options.flat(dataclasses.replace(CFG, l=7))))
    with pytest.raises(checkpoint.ForeignCheckpoint, match="l=10 in the checkpoint but 7"):
        evaluate.evaluate(other, seconds=SECONDS, render=False)
    data = bytearray((compact_run / checkpoint.COMPACT_FILE).read_bytes())
    data[len(data) // 2] ^= 0xFF
    (other / checkpoint.COMPACT_FILE).write_bytes(bytes(data))
    (other / checkpoint.RUN_CONFIG).unlink()
    with pytest.raises(CheckpointError, match="compact"):
        evaluate.evaluate(other, seconds=SECONDS, render=False)


def test_published_policy_only_evaluates_like_its_checkpoint_and_cannot_be_trained_on(run, result, tmp_path):
    """``save_compact_policy`` (a policy copied out of a checkpoint, as results/ publishes it) gives the
    checkpoint's evaluation; continuing training from it is refused with a clear error."""
    meta = checkpoint.load_metadata(run)
    config, theta, v = checkpoint.restore_policy(run)
    out = tmp_path / "published"
    checkpoint.save_compact_policy(out, config, theta, v, step=meta["step"], trials=meta["trials"])
    r = evaluate.evaluate(out, seconds=SECONDS, seed=0, render=False)
    assert (r["step"], r["trials"]) == (result["step"], result["trials"])
    assert r["deterministic"] == result["deterministic"] and r["exploring"] == result["exploring"]
    with pytest.raises(CheckpointError, match="evaluation only"):
        checkpoint.restore_compact(out, make_train(CFG))


def test_initial_pose_is_the_models_reset_pose(run):
    """The rollout's frame 0 is the reset pose: every joint where C MuJoCo puts the MJCF's sites at
    its initial qpos, and the heights derived from the paper's numbers (Sec. V-A): hind paw 0.1 m
    up, then the legs' vertical projections 0.2, 0.15, 0.25 m: heel 0.3, knee 0.45, hip and neck
    0.7, head 0.85 m."""
    cfg, theta, _ = checkpoint.restore_policy(run)
    traj = evaluate.rollout(cfg, theta, seconds=SECONDS, seed=0, exploring=False)
    pos = traj["pos"]
    assert pos.shape == (round(SECONDS / CFG.environment.control_dt) + 1, 10, 2)
    assert np.all(np.isfinite(pos))
    m = mujoco.MjModel.from_xml_path(str(MODEL_PATH))
    d = mujoco.MjData(m)  # qpos = the model's qpos0
    mujoco.mj_kinematics(m, d)
    c_sites = np.array([d.site(f"joint{i}").xpos[[0, 2]] for i in range(10)])
    np.testing.assert_allclose(pos[0], c_sites, atol=2e-6)
    np.testing.assert_allclose(pos[0][[0, 1, 2, 3, 4, 5], 1], [0.1, 0.3, 0.45, 0.7, 0.7, 0.85], atol=2e-6)
    assert pos[0][3, 0] < pos[0][4, 0] < pos[0][5, 0]  # hip, neck, head: the head ahead
    assert traj["x0"] == pytest.approx(0.5 * (c_sites[3, 0] + c_sites[4, 0]), abs=2e-6)


# ------------------------------------------------- eval's numbers vs an independent C MuJoCo rollout

ACT = (1, 2, 3, 6, 7, 8)  # I_j: action index k drives joint ACT[k] (Sec. V-A)
STRENGTH = {1: 60.0, 2: 90.0, 3: 120.0, 6: 90.0, 7: 60.0, 8: 30.0}
TOL = 0.005  # "[y = 0]": the joint's centre at most 5 mm up (docs/model.md)


def _f(x: float) -> float:
    """The soft step f of Sec. V-B."""
    return 0.0 if x <= 0 else 2 * x * x if x <= 0.5 else 1 - 2 * (x - 1) ** 2 if x <= 1 else 1.0


def _c_sites(m, d):
    """Joint positions and velocities (10, 2) in the paper's (x, y) plane from the MJCF's sites."""
    p = np.array([d.site(f"joint{i}").xpos[[0, 2]] for i in range(10)])
    v, res = np.zeros((10, 2)), np.zeros(6)
    for i in range(10):
        mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_SITE, m.site(f"joint{i}").id, res, 0)
        v[i] = res[[3, 5]]
    return p, v


def _c_obs(p, v):
    """Table I from joint positions/velocities; link angles from the sites (s_2 = dy_0/dt / 0.3)."""
    y, xd, yd = p[:, 1], v[:, 0], v[:, 1]
    s = [(y[0] - 0.1) / 0.1, yd[0] / 0.3, (float(y[0] <= TOL) - 0.5) / 0.5, ((y[3] + y[4]) / 2 - 0.6) / 0.2,
         (xd[3] + xd[4]) / 2 - 1, yd[3] / 0.3, yd[4] / 0.3, (y[9] - 0.1) / 0.1, yd[9] / 0.3,
         (float(y[9] <= TOL) - 0.5) / 0.5]
    for k in (0, 1, 2, 3, 6, 7, 8):
        u, du = p[k + 1] - p[k], v[k + 1] - v[k]
        n = math.hypot(*u)
        s += [u[0] / n / 0.7, u[1] / n / 0.7, (u[0] * du[1] - u[1] * du[0]) / n**2 / 3]
    return np.array(s)


def _c_rollout(theta, steps: int) -> list[dict]:
    """One trial of the deterministic policy in C MuJoCo (float64), rewards (8)-(14) written out."""
    m = mujoco.MjModel.from_xml_path(str(MODEL_PATH))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    P = theta["params"]
    W1, b1 = (np.asarray(P["hidden"][k], np.float64) for k in ("kernel", "bias"))
    W2, b2 = (np.asarray(P["output"][k], np.float64) for k in ("kernel", "bias"))
    rows = []
    for _ in range(steps):
        a = W2.T @ np.arctan(W1.T @ _c_obs(*_c_sites(m, d)) + b1) + b2  # a~(s; theta), Sec. V-C
        over, tau_w = [], []
        for _ in range(4):  # 4 physics steps of 5 ms; the PD torque of Sec. V-A in each
            pre = []
            for k, i in enumerate(ACT):
                j = m.joint(f"j{i}")
                tau0 = 2 / math.pi * math.atan(-2 * d.qpos[j.qposadr[0]] - 0.05 * d.qvel[j.dofadr[0]])
                pre.append(tau0 + 0.1 * a[k])
                d.actuator(f"m{i}").ctrl[0] = STRENGTH[i] * min(max(-1.0, pre[-1]), 1.0)
            mujoco.mj_step(m, d)
            f = np.where(d.efc_type == mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT, d.efc_force, 0.0)
            jt = np.zeros(m.nv)
            if d.nefc:
                mujoco.mj_mulJacTVec(m, d, jt, f)
            tau_w.append([jt[m.joint(f"j{i}").dofadr[0]] for i in ACT])
            over.append(np.maximum(np.abs(pre) - 1.0, 0.0))
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_comVel(m, d)
        p, v = _c_sites(m, d)
        y, xd, yd = p[:, 1], v[:, 0], v[:, 1]
        rows.append({
            "r8_speed": 0.5 * (xd[3] + xd[4]),
            "r9_torque": -0.05 * np.sum(np.mean(over, axis=0)),
            "r10_limit": -0.1 * np.sum(np.mean(np.minimum(np.abs(tau_w), 50.0), axis=0)),
            "r11_lift": (_f(0.3 * max(yd[3] + (y[0] > TOL), yd[4] + (y[9] > TOL)) + 0.1) - 1)
            * (1 - _f(1.5 * (xd[3] + xd[4]))),
            "r12_heel": _f(9 * y[1]) - 1, "r13_knee": _f(5 * y[2]) - 1, "r14_head": _f(2 * y[5]) - 1,
            "speed": 0.5 * (xd[3] + xd[4]), "x": 0.5 * (p[3, 0] + p[4, 0]),
        })
    return rows


@pytest.fixture(scope="module")
def moving_run(tmp_path_factory):
    """A checkpoint whose actor moves the robot: random output weights (the initial policy is 0)."""
    out = tmp_path_factory.mktemp("moving_run")
    trainer = make_train(CFG)
    ts = jax.jit(trainer.init)(jax.random.PRNGKey(CFG.budget.seed))
    rng = np.random.default_rng(0)
    o = ts.theta["params"]["output"]
    out_layer = {"kernel": jnp.asarray(2.0 * rng.normal(size=o["kernel"].shape), jnp.float32),
                 "bias": jnp.asarray(rng.normal(size=o["bias"].shape), jnp.float32)}
    ts = ts.replace(theta={"params": {**ts.theta["params"], "output": out_layer}})
    checkpoint.save(out, ts, trainer.config)
    return out, jax.device_get(ts.theta)


def test_eval_numbers_equal_an_independent_c_mujoco_rollout(moving_run, capsys):
    """``nmrl eval``'s deterministic average reward, each term, speed and distance equal a rollout of
    the same policy in C MuJoCo with the torque law, Table I and (8)-(14) written out here (MJX is
    float32: per-step rewards agree to ~6e-4, the means to ~5e-6 here)."""
    from nmrl import cli

    run_dir, theta = moving_run
    assert cli.main(["eval", str(run_dir), "--seconds", str(SECONDS), "--seed", "0", "--no-render"]) == 0
    det = json.loads(capsys.readouterr().out)["deterministic"]
    rows = _c_rollout(theta, round(SECONDS / CFG.environment.control_dt))
    want = {k: float(np.mean([r[k] for r in rows])) for k in REWARD_TERMS}
    assert want["r8_speed"] > 0.3 and want["r10_limit"] < -1.0  # the policy moves and meets its limits
    for k in REWARD_TERMS:
        assert det["terms"][k] == pytest.approx(want[k], abs=5e-5), k
    assert det["avg_reward"] == pytest.approx(sum(want.values()), abs=1e-4)
    assert det["forward_speed"] == pytest.approx(float(np.mean([r["speed"] for r in rows])), abs=5e-5)
    m = mujoco.MjModel.from_xml_path(str(MODEL_PATH))
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    x0 = 0.5 * (d.site("joint3").xpos[0] + d.site("joint4").xpos[0])
    assert det["distance"] == pytest.approx(rows[-1]["x"] - x0, abs=5e-5)


@pytest.mark.parametrize("span", [1.0, 3.0, 10.0, 60.0])
def test_the_strobe_covers_the_evaluated_seconds(span):
    """``nmrl eval --seconds S`` draws a strobe over all S seconds: the paper's 0.1 s spacing up to 3 s,
    wider beyond so that it stays at most 30 poses, the last pose within one spacing of the end."""
    from nmrl.analysis.gait_pictures import strobe_every, strobe_frames

    every = strobe_every(span)
    frames = strobe_frames(np.zeros((round(span / 0.02) + 1, 10, 2)), 0.02, every, span)
    assert len(frames) <= 31 and frames[-1] * 0.02 >= span - every - 1e-9
    assert every == 0.1 if span <= 3.0 else every > 0.1
