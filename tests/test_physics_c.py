"""MuJoCo C physics inside the jitted program (nmrl/physics/mujoco_c.py, ``--physics c``).

The C path's control step is checked against a plain MuJoCo loop (``mj_setState``, the PD torque of
Sec. V-A written out here, ``mj_step``; no JAX, no ``mujoco.batch``) bit for bit, eq. (9)-(10)
against the loop's own constraint arrays, and the run machinery (resume, sweep points, identity)
against the same runs on C physics made another way.
"""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from nmrl import cli, options
from nmrl.paper import geometry as g
from nmrl.paper.env import MODEL_PATH, EnvConfig, HalfCheetah
from nmrl.learners.ac_config import TrainConfig
from nmrl.physics import mujoco_c
from nmrl.runs import driver as run
from nmrl.runs import identity

N_STEPS = 60
SPEC = mujoco.mjtState.mjSTATE_INTEGRATION


def _actions(n_env: int, seed: int = 0) -> np.ndarray:
    """Bang-bang actions held for 5 steps: they saturate the torque and drive joints into limits."""
    rng = np.random.default_rng(seed)
    a = np.sign(rng.normal(size=(N_STEPS // 5, n_env, 6))).astype(np.float32) * 20.0
    return np.repeat(a, 5, axis=0)


def _plain_loop(actions: np.ndarray, control_dt: float = 0.02):
    """One environment by hand: (states (T, nstate) float64, r9 (T,), r10 (T,)) per control step."""
    m = mujoco.MjModel.from_xml_path(str(MODEL_PATH))
    d = mujoco.MjData(m)
    n_sub = round(control_dt / m.opt.timestep)
    strength = np.array([g.STRENGTH[g.ACTUATED.index(i)] for i in g.QPOS_JOINTS])
    act_index = [g.ACTUATED.index(i) for i in g.QPOS_JOINTS]
    states, r9, r10 = [], [], []
    for a in actions:
        a0 = 0.1 * np.asarray(a, np.float64)[act_index]
        over, limit = [], []
        for _ in range(n_sub):
            q, qd = d.qpos[3:], d.qvel[3:]
            pre = 2.0 / np.pi * np.arctan(-2.0 * q - 0.05 * qd) + a0
            d.ctrl[:] = strength * np.clip(pre, -1.0, 1.0)
            mujoco.mj_step(m, d)
            over.append(np.maximum(np.abs(pre) - 1.0, 0.0))
            rows = d.efc_type == mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT
            J = d.efc_J.reshape(d.nefc, m.nv)[rows]
            limit.append((J.T @ d.efc_force[rows])[3:])
        s = np.empty(mujoco.mj_stateSize(m, SPEC))
        mujoco.mj_getState(m, d, s, SPEC)
        states.append(s)
        r9.append(-0.05 * np.sum(np.mean(over, axis=0)))
        r10.append(-0.1 * np.sum(np.mean(np.minimum(np.abs(limit), 50.0), axis=0)))
    return np.array(states), np.array(r9), np.array(r10)


@pytest.fixture(scope="module")
def c_env():
    return HalfCheetah(EnvConfig(physics="c", stop_prob=0.0, auto_reset=False))


def _c_rollout(env, actions):
    """The C path under jit, vmap over the environments and scan over the steps."""
    keys = jax.random.split(jax.random.PRNGKey(0), actions.shape[1])
    s0 = jax.vmap(env.reset)(keys)

    def f(s, a):
        s = jax.vmap(env.step)(s, a)
        return s, (s.data.state, s.data.qpos, s.metrics["r9_torque"], s.metrics["r10_limit"], s.metrics["nonfinite"])

    _, out = jax.jit(lambda s, a: jax.lax.scan(f, s, a))(s0, jnp.asarray(actions))
    return [np.asarray(x) for x in out]


def test_c_step_equals_a_plain_mujoco_loop_bit_for_bit(c_env):
    actions = _actions(3)
    bits, qpos, r9, r10, nonfinite = _c_rollout(c_env, actions)
    assert not nonfinite.any()
    assert np.any(r10 < -1.0), "the actions must drive joints into their limits"
    for e in range(3):
        states, r9_ref, r10_ref = _plain_loop(actions[:, e])
        got = mujoco_c.from_bits(bits[:, e])
        # the whole integration state (time, qpos, qvel, warm start, ctrl, ...) bit for bit
        np.testing.assert_array_equal(got.view(np.uint64), states.view(np.uint64))
        np.testing.assert_array_equal(qpos[:, e], states[:, 1:10].astype(np.float32))
        # eq. (9) and (10): the JAX side sums float32 reports of float64 quantities
        np.testing.assert_allclose(r9[:, e], r9_ref, rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(r10[:, e], r10_ref, rtol=1e-5, atol=1e-5)


def test_batch_axes_and_thread_counts_give_the_same_bits(c_env):
    actions = _actions(4, seed=1)[:10]
    ref = _c_rollout(c_env, actions)[0]
    two = HalfCheetah(EnvConfig(physics="c", stop_prob=0.0, auto_reset=False, threads=2))
    np.testing.assert_array_equal(_c_rollout(two, actions)[0], ref)
    # nested vmap (points x environments), as a sweep runs it
    s0 = jax.vmap(jax.vmap(c_env.reset))(jax.random.split(jax.random.PRNGKey(0), 4).reshape(2, 2, 2))
    a = jnp.asarray(actions).reshape(10, 2, 2, 6)
    step = jax.vmap(jax.vmap(c_env.step))
    _, bits = jax.jit(lambda s, a: jax.lax.scan(lambda s, x: (step(s, x),) * 2, s, a))(s0, a)
    np.testing.assert_array_equal(np.asarray(bits.data.state).reshape(10, 4, -1), ref)


def test_c_and_mjx_agree_before_chaos_parts_them(c_env):
    mjx_env = HalfCheetah(EnvConfig(physics="mjx", stop_prob=0.0, auto_reset=False))
    actions = _actions(1, seed=2)[:10, 0]

    def roll(env):
        def f(s, a):
            s = env.step(s, a)
            return s, (s.data.qpos, s.reward)
        return jax.jit(lambda s: jax.lax.scan(f, s, actions))(env.reset(jax.random.PRNGKey(0)))[1]

    (qc, rc), (qm, rm) = roll(c_env), roll(mjx_env)
    np.testing.assert_allclose(np.asarray(qc), np.asarray(qm), atol=1e-4)
    np.testing.assert_allclose(np.asarray(rc), np.asarray(rm), atol=1e-3, rtol=1e-4)


def test_an_unstable_state_stops_the_trial_and_restarts(c_env, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MuJoCo logs its warnings to MUJOCO_LOG.TXT in the working directory
    env = HalfCheetah(EnvConfig(physics="c", stop_prob=0.0, auto_reset=True))
    s = env.reset(jax.random.PRNGKey(0))
    bad = mujoco_c.from_bits(np.asarray(s.data.state)[None])[0].copy()
    bad[10 + 3] = np.nan  # a joint velocity: MuJoCo warns (mjWARN_BADQVEL) and resets
    s = s.replace(data=s.data.replace(state=jnp.asarray(mujoco_c.to_bits(bad))))
    s2 = jax.jit(env.step)(s, jnp.zeros(6))
    assert float(s2.done) == 1.0 and float(s2.metrics["nonfinite"]) == 1.0 and float(s2.reward) == 0.0
    np.testing.assert_array_equal(np.asarray(s2.data.state), np.asarray(env.reset(jax.random.PRNGKey(0)).data.state))
    huge = bad.copy()
    huge[10 + 3] = 1e30
    out, _, ok = env.c.host_step(huge[None], np.zeros((1, 6)))
    assert not ok[0]
    assert "unstable" in (tmp_path / "MUJOCO_LOG.TXT").read_text()  # it was MuJoCo's warning that stopped it


def test_unsupported_device_and_model_are_refused(monkeypatch):
    m = mujoco.MjModel.from_xml_path(str(MODEL_PATH))
    mujoco_c.check_supported(m)
    m.opt.enableflags |= int(mujoco.mjtEnableBit.mjENBL_SLEEP)
    with pytest.raises(mujoco_c.PhysicsUnsupported, match="sleep"):
        mujoco_c.check_supported(m)
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    with pytest.raises(mujoco_c.PhysicsUnsupported, match="CPU only"):
        mujoco_c.check_supported(mujoco.MjModel.from_xml_path(str(MODEL_PATH)))


def test_cli_refuses_physics_c_off_the_cpu(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    out = tmp_path / "r"
    assert cli.main(["train", "--physics", "c", "--steps", "10", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "CPU only" in err[0] and not out.exists()


def test_physics_is_part_of_the_identity_and_mjx_runs_keep_theirs():
    mjx_ident = identity.identity_config(TrainConfig())
    assert "physics" not in mjx_ident  # runs made before the option keep their digest
    assert identity.identity_config(options.build(TrainConfig, physics="c"))["physics"] == "c"


TINY = ["--preset", "fast", "--hidden-actor", "8", "--hidden-critic", "8", "--num-envs", "4",
        "--chunk-steps", "25", "--devices", "1"]


def _rows(d):
    return [{k: v for k, v in r.items() if k not in ("wall_s", "steps_per_s")} for r in run.read_metrics(d)]


def test_resume_on_c_is_bit_exact_and_keeps_its_physics(tmp_path, capsys):
    whole, part = tmp_path / "whole", tmp_path / "part"
    assert cli.main(["train", *TINY, "--physics", "c", "--steps", "50", "--out", str(whole)]) == 0
    assert cli.main(["train", *TINY, "--physics", "c", "--steps", "25", "--out", str(part)]) == 0
    assert cli.main(["train", "--resume", "--steps", "50", "--out", str(part)]) == 0
    assert _rows(part) == _rows(whole)
    assert json.loads((whole / "config.json").read_text())["physics"] == "c"
    capsys.readouterr()
    assert cli.main(["train", "--resume", "--physics", "mjx", "--steps", "75", "--out", str(part)]) == 2
    assert "physics" in capsys.readouterr().err


def test_a_sweep_point_on_c_equals_the_run_alone(tmp_path):
    from nmrl.experiments import sweep

    base = options.build(TrainConfig, num_envs=4, chunk_steps=25, steps=50, hidden_actor=8, hidden_critic=8, beta_theta=1e-3,
                       beta_v=1e-3, physics="c")
    out = tmp_path / "sweep"
    sweep.run_sweep(sweep.SweepSpec(ls=(1, 3), seeds=1, base=base), out, progress=False, plot=False)
    alone = tmp_path / "alone"
    run.train(options.replace(base, l=3, seed=0), alone, progress=False)
    for a, b in zip(_rows(alone), _rows(sweep.point_dir(out, 3, 0))):
        assert a.keys() == b.keys()
        for k in a:
            if isinstance(a[k], float):
                assert b[k] == pytest.approx(a[k], rel=1e-4, abs=1e-6), k
            else:
                assert a[k] == b[k], k


def test_a_fresh_batch_reports_the_limit_force_of_its_first_substep():
    """The first call on a new batch (each calling thread gets its own) reports the sensors of its
    first substep too, as a plain loop computes them from the constraint arrays."""
    m = mujoco.MjModel.from_xml_path(str(MODEL_PATH))
    d = mujoco.MjData(m)
    a = _actions(1)[:, 0]
    states, _, _ = _plain_loop(a[:7])
    env = HalfCheetah(EnvConfig(physics="c", stop_prob=0.0, auto_reset=False, threads=1))
    s6 = states[5]  # the state after 6 control steps, joints in their limits
    _, reports, ok = env.c.host_step(s6[None], a[6][None].astype(np.float64))
    mujoco.mj_setState(m, d, s6, SPEC)
    q, qd = d.qpos[3:], d.qvel[3:]
    strength = np.array([g.STRENGTH[g.ACTUATED.index(i)] for i in g.QPOS_JOINTS])
    a0 = 0.1 * a[6].astype(np.float64)[[g.ACTUATED.index(i) for i in g.QPOS_JOINTS]]
    d.ctrl[:] = strength * np.clip(2.0 / np.pi * np.arctan(-2.0 * q - 0.05 * qd) + a0, -1.0, 1.0)
    mujoco.mj_step(m, d)
    rows = d.efc_type == mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT
    limit = (d.efc_J.reshape(d.nefc, m.nv)[rows].T @ d.efc_force[rows])[3:]
    assert ok[0] and np.any(np.abs(limit) > 1.0)
    np.testing.assert_allclose(np.abs(reports[0, 0, 6:]), np.abs(limit), rtol=1e-9, atol=1e-9)
