"""Tests of nmrl.paper.env (the paper's Half-Cheetah, Sec. V-A/V-B) against independent computations.

The reference values are computed here by hand from the paper's numbers, typed in as literals
(not imported from nmrl.paper.geometry), or by C MuJoCo (``mujoco.MjModel``/``MjData``, float64),
which shares no code with the JAX environment. One jitted single-env ``step`` and one jitted
batched ``step`` are shared by the whole module (compiles dominate the run time).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from nmrl.paper.env import MODEL_PATH, EnvConfig, HalfCheetah
from nmrl.paper.robot import forward_kinematics, kinematics, observation, soft_step, state_rewards

PI = math.pi
C = math.cos

# ----------------------------------------------------------------- the paper's numbers (Sec. V-A)
MASS = [1, 1, 1, 4, 1, 2, 1, 1, 1, 1]  # joints 0..9 [kg]
LEN = [0.2 / C(PI / 12), 0.15 / C(PI / 3), 0.25 / C(PI / 6), 1.0, 0.3, 0.3,
       0.25 / C(PI / 9), 0.2 / C(PI / 9), 0.15 / C(PI / 9)]  # links 0..8 [m]
W0 = dict(zip(range(1, 9), np.array([-5 / 12, 1 / 2, -2 / 3, 1 / 6, -1, 1 / 6, 5 / 18, 0]) * PI))
LO = dict(zip(range(1, 9), np.array([-5 / 6, 1 / 4, -5 / 6, 1 / 6, -1, 1 / 18, 0, -2 / 3]) * PI))
HI = dict(zip(range(1, 9), np.array([-1 / 6, 3 / 4, -1 / 3, 1 / 6, -1, 1 / 2, 8 / 9, 1 / 9]) * PI))
ACT = (1, 2, 3, 6, 7, 8)  # I_j; action index k drives joint ACT[k]
STRENGTH = {1: 60.0, 2: 90.0, 3: 120.0, 6: 90.0, 7: 60.0, 8: 30.0}
TOL = 0.005  # EnvConfig.contact_tol: "[y = 0]" is y <= 5 mm
B = 1024  # batch of the shared vmapped step
T_BATCH = 30  # control steps of the batched run (stop-rate test)


# ----------------------------------------------------------------------------- hand computations


def hand_pose(x=0.0, z=0.0, th=0.0, q=None, dx=0.0, dz=0.0, dth=0.0, dq=None):
    """Joint positions/velocities (10, 2) and link angles/rates (9,), by hand, float64.

    Conventions (docs/model.md): phi_k = angle of link k (pointing from joint k to joint k+1)
    to the horizontal, counter-clockwise; omega_i = phi_i - phi_{i-1}; q_i = omega_i - omega^0_i
    is the MuJoCo hinge angle of joint i; the first link is at -pi/12 to the upward vertical
    (read clockwise): phi_0 = 90 + 15 degrees. At reset the hind paw is at (0, 0.1).
    (x, z, th) are the root slide/hinge coordinates (hip displacement, trunk rotation).
    """
    q = {i: 0.0 for i in ACT} | (q or {})
    dq = {i: 0.0 for i in ACT} | (dq or {})
    w = {i: W0[i] + q.get(i, 0.0) for i in range(1, 9)}
    # initial pose: phi_0 = 105 deg, then add omega^0 -> 30, 120, 0 (trunk), 30, -150, -120, -70, -70
    phi_init0 = [math.radians(a) for a in (105, 30, 120, 0, 30, -150, -120, -70, -70)]
    hip0 = np.array([sum(LEN[k] * math.cos(phi_init0[k]) for k in range(3)), 0.1 + 0.2 + 0.15 + 0.25])
    phi = [0.0] * 9
    dphi = [0.0] * 9
    phi[3], dphi[3] = th, dth  # trunk horizontal at reset
    phi[2], dphi[2] = phi[3] - w[3], dphi[3] - dq[3]
    phi[1], dphi[1] = phi[2] - w[2], dphi[2] - dq[2]
    phi[0], dphi[0] = phi[1] - w[1], dphi[1] - dq[1]
    for i in range(4, 9):
        phi[i] = phi[i - 1] + w[i]
        dphi[i] = dphi[i - 1] + dq.get(i, 0.0)
    u = lambda k: LEN[k] * np.array([math.cos(phi[k]), math.sin(phi[k])])  # noqa: E731
    du = lambda k: LEN[k] * dphi[k] * np.array([-math.sin(phi[k]), math.cos(phi[k])])  # noqa: E731
    p = [None] * 10
    v = [None] * 10
    p[3], v[3] = hip0 + np.array([x, z]), np.array([dx, dz])
    for i in (2, 1, 0):
        p[i], v[i] = p[i + 1] - u(i), v[i + 1] - du(i)
    for i in range(4, 10):
        p[i], v[i] = p[i - 1] + u(i - 1), v[i - 1] + du(i - 1)
    return np.array(p), np.array(v), np.array(phi), np.array(dphi)


def hand_obs(p, v, phi, dphi):
    """Table I, s_1..s_31 (with s_2 = dy_0/dt / 0.3), written out one by one."""
    y, xd, yd = p[:, 1], v[:, 0], v[:, 1]
    s = [
        (y[0] - 0.1) / 0.1,
        yd[0] / 0.3,
        (float(y[0] <= TOL) - 0.5) / 0.5,
        ((y[3] + y[4]) / 2 - 0.6) / 0.2,
        (xd[3] + xd[4]) / 2 - 1,
        yd[3] / 0.3,
        yd[4] / 0.3,
        (y[9] - 0.1) / 0.1,
        yd[9] / 0.3,
        (float(y[9] <= TOL) - 0.5) / 0.5,
    ]
    for j in (0, 1, 2, 3):  # s_{11+3j}, s_{12+3j}, s_{13+3j}
        s += [math.cos(phi[j]) / 0.7, math.sin(phi[j]) / 0.7, dphi[j] / 3]
    for k in (0, 1, 2):  # s_{23+3k}.. : links 6, 7, 8
        s += [math.cos(phi[6 + k]) / 0.7, math.sin(phi[6 + k]) / 0.7, dphi[6 + k] / 3]
    return np.array(s)


def f_hand(x):
    if x <= 0:
        return 0.0
    if x <= 0.5:
        return 2 * x * x
    if x <= 1:
        return 1 - 2 * (x - 1) ** 2
    return 1.0


def hand_state_rewards(p, v):
    y, xd, yd = p[:, 1], v[:, 0], v[:, 1]
    return {
        "r8_speed": 0.5 * (xd[3] + xd[4]),
        "r11_lift": (f_hand(0.3 * max(yd[3] + (y[0] > TOL), yd[4] + (y[9] > TOL)) + 0.1) - 1)
        * (1 - f_hand(1.5 * (xd[3] + xd[4]))),
        "r12_heel": f_hand(9 * y[1]) - 1,
        "r13_knee": f_hand(5 * y[2]) - 1,
        "r14_head": f_hand(2 * y[5]) - 1,
    }


# ---------------------------------------------------------------------------- C MuJoCo helpers


@pytest.fixture(scope="module")
def mjm():
    return mujoco.MjModel.from_xml_path(str(MODEL_PATH))


def adr(m, name):
    return int(m.joint(name).qposadr[0])


def qpos_of(m, x=0.0, z=0.0, th=0.0, q=None):
    qp = np.zeros(m.nq)
    qp[adr(m, "rootx")], qp[adr(m, "rootz")], qp[adr(m, "rooty")] = x, z, th
    for i, v in (q or {}).items():
        qp[adr(m, f"j{i}")] = v
    return qp


def c_sites(m, qpos):
    d = mujoco.MjData(m)
    d.qpos[:] = qpos
    mujoco.mj_kinematics(m, d)
    return np.array([d.site(f"joint{i}").xpos[[0, 2]] for i in range(10)])


def c_limit_torque(m, d):
    """J^T f over the joint-limit rows of the last forward pass (per dof)."""
    f = np.where(d.efc_type == mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT, d.efc_force, 0.0)
    res = np.zeros(m.nv)
    if d.nefc:
        mujoco.mj_mulJacTVec(m, d, res, f)
    return res


def c_control_step(m, qpos, qvel, action, n_sub=4):
    """One 0.02 s control step in C MuJoCo with the paper's torque law written out by hand."""
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:] = qpos, qvel
    pre_all, tw_all = [], []
    for _ in range(n_sub):
        pre = {}
        for k, i in enumerate(ACT):
            q = d.qpos[adr(m, f"j{i}")]  # = omega_i - omega^0_i
            qd = d.qvel[int(m.joint(f"j{i}").dofadr[0])]
            tau0 = 2 / PI * math.atan(-2 * q - 0.05 * qd)
            pre[i] = tau0 + 0.1 * action[k]
            d.actuator(f"m{i}").ctrl[0] = STRENGTH[i] * min(max(-1.0, pre[i]), 1.0)
        mujoco.mj_step(m, d)  # Euler: efc_* stay those of this substep's forward pass
        tw = c_limit_torque(m, d)
        tw_all.append({i: tw[int(m.joint(f"j{i}").dofadr[0])] for i in ACT})
        pre_all.append(pre)
    return d, pre_all, tw_all


# ---------------------------------------------------------------------------- shared jitted env


@pytest.fixture(scope="module")
def env():
    return HalfCheetah()


@pytest.fixture(scope="module")
def jstep(env):
    return jax.jit(env.step)


@pytest.fixture(scope="module")
def jreset(env):
    return jax.jit(env.reset)


def with_state(env, jreset, key, qpos, qvel):
    s = jreset(key)
    data = s.data.replace(qpos=jnp.asarray(qpos, jnp.float32), qvel=jnp.asarray(qvel, jnp.float32))
    return s.replace(data=data)


def step_no_stop(env, jreset, jstep, qpos, qvel, action):
    """One step from (qpos, qvel) with the first key (of a fixed list) whose trial does not stop."""
    for seed in range(20):
        s = with_state(env, jreset, jax.random.key(seed), qpos, qvel)
        out = jstep(s, jnp.asarray(action, jnp.float32))
        if float(out.done) == 0.0:
            return out
    raise AssertionError("every key stopped the trial")


@pytest.fixture(scope="module")
def batch_run(env):
    """B envs from B different keys (two share a key), zero action, T_BATCH control steps."""
    keys = jax.random.split(jax.random.key(123), B)
    keys = keys.at[1].set(keys[0])
    vreset, vstep = jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))
    s = vreset(keys)
    s0 = s
    a = jnp.zeros((B, 6))
    rec = {k: [] for k in ("done", "obs", "terminal_obs", "qpos", "qvel", "steps", "reward")}
    for _ in range(T_BATCH):
        s = vstep(s, a)
        rec["done"].append(np.asarray(s.done))
        rec["obs"].append(np.asarray(s.obs))
        rec["terminal_obs"].append(np.asarray(s.info["terminal_obs"]))
        rec["qpos"].append(np.asarray(s.data.qpos))
        rec["qvel"].append(np.asarray(s.data.qvel))
        rec["steps"].append(np.asarray(s.info["steps"]))
        rec["reward"].append(np.asarray(s.reward))
    out = {k: np.stack(v) for k, v in rec.items()}
    out["s0"], out["s"] = s0, s
    return out


# ========================================================================= geometry (Sec. V-A)


def test_reset_pose_by_hand_matches_c_mujoco_and_forward_kinematics(env, mjm):
    p, _, phi, _ = hand_pose()
    # the derivation, explicitly: heights of heel, knee, hip, neck, head, front paw
    np.testing.assert_allclose(p[:, 1][[0, 1, 2, 3, 4, 5]], [0.1, 0.3, 0.45, 0.7, 0.7, 0.85], atol=1e-12)
    assert p[9, 1] == pytest.approx(0.1 + 0.25 - 0.25 * C(PI / 6) / C(PI / 9), abs=1e-12)
    assert p[9, 1] - p[0, 1] == pytest.approx(0.0196, abs=1e-4)  # docs/model.md: front paw 1.96 cm up
    assert p[0, 0] == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(c_sites(mjm, mjm.qpos0), p, atol=1e-9)
    assert np.allclose(mjm.qpos0, 0.0)
    np.testing.assert_allclose(np.asarray(env.reset(jax.random.key(0)).data.qpos), 0.0, atol=0)
    p_fk, phi_fk = forward_kinematics(jnp.zeros(mjm.nq))
    np.testing.assert_allclose(np.asarray(p_fk), p, atol=2e-6)
    np.testing.assert_allclose(np.asarray(phi_fk), phi, atol=2e-6)
    np.testing.assert_allclose(p[6], p[4], atol=1e-12)  # shoulder at the neck
    assert p[5, 0] > p[3, 0]  # head ahead of the hip: x points forward
    # the first link at -pi/12 to the upward vertical (clockwise): leaning back from paw to heel
    d = p[1] - p[0]
    assert math.atan2(-d[0], d[1]) == pytest.approx(PI / 12)
    # link lengths in the model equal the paper's
    ps = c_sites(mjm, mjm.qpos0)
    np.testing.assert_allclose(np.linalg.norm(np.diff(ps, axis=0), axis=1), LEN, atol=1e-9)


def test_masses_per_joint(mjm):
    by_joint = {}
    for g in mujoco.MjSpec.from_file(str(MODEL_PATH)).geoms:  # masses as written in the MJCF
        if g.name.startswith("joint"):
            by_joint[int(g.name[5])] = g.mass
        elif g.name != "floor":
            assert g.mass == 0.0, g.name  # links are massless
    assert [by_joint[i] for i in range(10)] == pytest.approx(MASS)
    body = {mjm.body(b).name: mjm.body_mass[b] for b in range(mjm.nbody)}
    assert body["trunk"] == pytest.approx(MASS[3] + MASS[4] + MASS[5] + MASS[6])
    for name, i in (("link2", 2), ("link1", 1), ("link0", 0), ("link6", 7), ("link7", 8), ("link8", 9)):
        assert body[name] == pytest.approx(MASS[i])
    assert mjm.body_subtreemass[1] == pytest.approx(sum(MASS))
    # the mass sits at the joint: geom centres coincide with the joint sites
    d = mujoco.MjData(mjm)
    mujoco.mj_kinematics(mjm, d)
    for g in range(mjm.ngeom):
        name = mjm.geom(g).name
        if name.startswith("joint"):
            np.testing.assert_allclose(d.geom_xpos[g], d.site(name[:6]).xpos, atol=1e-9)


def test_joint_ranges_are_paper_bounds_minus_omega0(mjm):
    for i in ACT:
        j = mjm.joint(f"j{i}")
        assert j.limited[0] if np.ndim(j.limited) else j.limited
        np.testing.assert_allclose(j.range, [LO[i] - W0[i], HI[i] - W0[i]], atol=1e-9)
    # joints 4 and 5 are fixed at omega^0 (lower == upper in the paper) and are not in the model
    assert LO[4] == HI[4] == W0[4] and LO[5] == HI[5] == W0[5]
    assert mjm.nu == 6 and mjm.nq == 9


def test_random_qpos_fk_matches_c_mujoco_and_hinge_sign(mjm):
    rng = np.random.default_rng(0)
    for _ in range(5):
        x, z, th = rng.uniform(-0.5, 0.5), rng.uniform(-0.2, 0.4), rng.uniform(-1, 1)
        q = {i: rng.uniform(LO[i] - W0[i], HI[i] - W0[i]) for i in ACT}
        qp = qpos_of(mjm, x, z, th, q)
        ps = c_sites(mjm, qp)
        p_fk, phi_fk = forward_kinematics(jnp.asarray(qp, jnp.float32))
        np.testing.assert_allclose(np.asarray(p_fk), ps, atol=2e-5)
        np.testing.assert_allclose(hand_pose(x, z, th, q)[0], ps, atol=1e-9)
        # omega_i measured on C MuJoCo's sites (relative angle of consecutive links) == omega^0_i + q_i
        lk = np.diff(ps, axis=0)
        phi_c = np.arctan2(lk[:, 1], lk[:, 0])
        np.testing.assert_allclose(np.cos(np.asarray(phi_fk) - phi_c), 1.0, atol=1e-9)
        for i in ACT:
            dw = (phi_c[i] - phi_c[i - 1]) - (W0[i] + q[i])
            assert math.cos(dw) == pytest.approx(1.0, abs=1e-9), i


def test_kinematics_velocities_match_finite_differences(mjm):
    rng = np.random.default_rng(1)
    for _ in range(3):
        q = {i: rng.uniform(LO[i] - W0[i], HI[i] - W0[i]) for i in ACT}
        qp = qpos_of(mjm, rng.normal(), rng.normal() * 0.1, rng.normal() * 0.5, q)
        qv = rng.normal(size=mjm.nv)
        h = 1e-6
        fd = (c_sites(mjm, qp + h * qv) - c_sites(mjm, qp - h * qv)) / (2 * h)
        p, v, phi, dphi = kinematics(jnp.asarray(qp, jnp.float32), jnp.asarray(qv, jnp.float32))
        np.testing.assert_allclose(np.asarray(v), fd, atol=2e-4)
        lk_p = np.diff(c_sites(mjm, qp + h * qv), axis=0)
        lk_m = np.diff(c_sites(mjm, qp - h * qv), axis=0)
        dphi_fd = (np.arctan2(lk_p[:, 1], lk_p[:, 0]) - np.arctan2(lk_m[:, 1], lk_m[:, 0])) / (2 * h)
        np.testing.assert_allclose(np.asarray(dphi), dphi_fd, atol=2e-4)


# ========================================================================= state (Table I)


def test_table1_on_a_known_pose(mjm):
    q = {1: 0.2, 2: -0.3, 3: 0.4, 6: 0.1, 7: -0.5, 8: 0.25}
    dq = {1: 1.0, 2: -2.0, 3: 0.5, 6: -1.5, 7: 3.0, 8: -0.7}
    x, th, dx, dz, dth = 0.3, 0.15, 1.2, -0.4, 0.8
    p0, *_ = hand_pose(0.0, 0.0, th, q)
    z = 0.002 - p0[0, 1]  # hind paw 2 mm high (on the ground: s_3 = 1); front paw well above
    p, v, phi, dphi = hand_pose(x, z, th, q, dx, dz, dth, dq)
    assert p[0, 1] <= TOL < p[9, 1]
    expected = hand_obs(p, v, phi, dphi)
    assert expected[2] == 1.0 and expected[9] == -1.0
    qv = np.zeros(mjm.nv)
    qv[[adr(mjm, "rootx"), adr(mjm, "rootz"), adr(mjm, "rooty")]] = dx, dz, dth
    for i, w in dq.items():
        qv[int(mjm.joint(f"j{i}").dofadr[0])] = w
    qp = qpos_of(mjm, x, z, th, q)
    obs = observation(*kinematics(jnp.asarray(qp, jnp.float32), jnp.asarray(qv, jnp.float32)), TOL)
    assert obs.shape == (31,)
    for k in range(31):
        assert float(obs[k]) == pytest.approx(expected[k], abs=5e-5), f"s_{k + 1}"


def test_reset_observation_by_hand(env):
    s = env.reset(jax.random.key(0))
    p, v, phi, dphi = hand_pose()
    expected = hand_obs(p, v, phi, dphi)
    np.testing.assert_allclose(np.asarray(s.obs), expected, atol=2e-6)
    # at reset both paws are in the air: s_1 = 0 (hind paw at 0.1 m), s_3 = s_10 = -1
    assert expected[0] == pytest.approx(0.0) and expected[2] == -1 and expected[9] == -1


# =========================================================================== reward (8)-(14)


def test_soft_step_values():
    xs = [-1.0, 0.0, 0.25, 0.5, 0.75, 1.0, 2.0]
    want = [0.0, 0.0, 0.125, 0.5, 0.875, 1.0, 1.0]
    np.testing.assert_allclose(np.asarray(soft_step(jnp.array(xs))), want, atol=1e-7)
    assert [f_hand(x) for x in xs] == pytest.approx(want)


def test_standing_still_and_ground_penalties():
    p, _, _, _ = hand_pose()
    p = p.copy()
    p[:, 1] -= 0.1  # both paws on the ground (front paw 1.96 cm up: set it to 0 too)
    p[9, 1] = 0.0
    v = np.zeros_like(p)
    r = {k: float(x) for k, x in state_rewards(jnp.asarray(p), jnp.asarray(v), TOL).items()}
    assert r["r11_lift"] == pytest.approx(-0.98)  # (f(0.1) - 1)(1 - f(0)) = 0.02 - 1
    for k in ("r8_speed", "r12_heel", "r13_knee", "r14_head"):
        assert r[k] == pytest.approx(0.0, abs=1e-7), k
    for joint, term in ((1, "r12_heel"), (2, "r13_knee"), (5, "r14_head")):
        pg = p.copy()
        pg[joint, 1] = 0.0
        rg = {k: float(x) for k, x in state_rewards(jnp.asarray(pg), jnp.asarray(v), TOL).items()}
        assert rg[term] == pytest.approx(-1.0), term
        assert sum(rg[t] for t in ("r12_heel", "r13_knee", "r14_head")) == pytest.approx(-1.0)
    # paws up and trunk rising: (11) vanishes; running fast: (11) vanishes too
    pu, vu = p.copy(), v.copy()
    pu[0, 1] = pu[9, 1] = 0.05
    vu[3, 1] = 3.0
    assert float(state_rewards(jnp.asarray(pu), jnp.asarray(vu), TOL)["r11_lift"]) == pytest.approx(0.0)
    vf = v.copy()
    vf[3, 0] = vf[4, 0] = 0.5
    rf = state_rewards(jnp.asarray(p), jnp.asarray(vf), TOL)
    assert float(rf["r11_lift"]) == pytest.approx(0.0) and float(rf["r8_speed"]) == pytest.approx(0.5)


def test_step_matches_c_mujoco_torque_penalty_and_state_terms(env, jreset, jstep, mjm):
    """(9) with a saturating action; the action -> joint map and sign; obs/(8),(11)-(14) at s_{t+1}."""
    qp = qpos_of(mjm, z=0.3)  # in the air
    qv = np.zeros(mjm.nv)
    a = np.array([20.0, 0, 0, 0, 0, -15.0])  # a^0 = 2 on joint 1, -1.5 on joint 8
    out = step_no_stop(env, jreset, jstep, qp, qv, a)
    d, pre, tw = c_control_step(mjm, qp, qv, a)
    assert d.ncon == 0
    want9 = -0.05 * sum(np.mean([max(abs(pr[i]) - 1, 0) for pr in pre]) for i in ACT)
    # at rest at omega^0, tau^0 = 0: the first substep has tau^0 + a^0 = a^0 exactly
    assert pre[0][1] == pytest.approx(2.0) and pre[0][8] == pytest.approx(-1.5)
    assert want9 < -0.01  # the light legs spin up within the step, so later substeps saturate less
    assert float(out.metrics["r9_torque"]) == pytest.approx(want9, rel=1e-4)
    assert float(out.metrics["r10_limit"]) == 0.0  # away from the bounds
    np.testing.assert_allclose(np.asarray(out.data.qpos), d.qpos, atol=1e-5)
    np.testing.assert_allclose(np.asarray(out.data.qvel), d.qvel, atol=1e-3)
    # positive a_1 turns joint 1 positive (omega_1 up), negative a_8 turns joint 8 negative
    assert d.qpos[adr(mjm, "j1")] > 1e-3 and d.qpos[adr(mjm, "j8")] < -1e-3
    # the returned obs and state terms are those of s_{t+1}, recomputed by hand
    qpn, qvn = np.asarray(out.data.qpos, np.float64), np.asarray(out.data.qvel, np.float64)
    g = lambda n: qpn[adr(mjm, n)]  # noqa: E731
    gv = lambda n: qvn[int(mjm.joint(n).dofadr[0])]  # noqa: E731
    hp = hand_pose(g("rootx"), g("rootz"), g("rooty"), {i: g(f"j{i}") for i in ACT},
                   gv("rootx"), gv("rootz"), gv("rooty"), {i: gv(f"j{i}") for i in ACT})
    np.testing.assert_allclose(np.asarray(out.obs), hand_obs(*hp), atol=1e-4)
    for k, want in hand_state_rewards(hp[0], hp[1]).items():
        assert float(out.metrics[k]) == pytest.approx(want, abs=1e-4), k
    terms = ("r8_speed", "r9_torque", "r10_limit", "r11_lift", "r12_heel", "r13_knee", "r14_head")
    assert float(out.reward) == pytest.approx(sum(float(out.metrics[k]) for k in terms), abs=1e-5)


def test_limit_torque_equals_c_mujoco_constraint_force(env, jreset, jstep, mjm):
    """(10): tau^w = joint-limit constraint force, non-zero at a bound, zero away from it."""
    hi3 = HI[3] - W0[3]
    qp = qpos_of(mjm, z=0.3, q={3: hi3 + 0.005})  # hip just past its upper bound, in the air
    qv = np.zeros(mjm.nv)
    a = np.array([0, 0, 10.0, 0, 0, 0])  # push joint 3 further into the bound
    out = step_no_stop(env, jreset, jstep, qp, qv, a)
    d, _, tw = c_control_step(mjm, qp, qv, a)
    assert d.ncon == 0
    per_sub = np.array([[t[i] for i in ACT] for t in tw])  # (4 substeps, 6)
    assert np.all(per_sub[:, 2] < -1.0)  # the tendon pulls joint 3 back, every substep
    assert np.all(np.abs(per_sub[:, [0, 1, 3, 4, 5]]) == 0.0)
    # all substeps on the same side of the 50 N m cap, so averaging before/after the cap agree
    assert np.all(np.abs(per_sub[:, 2]) < 50) or np.all(np.abs(per_sub[:, 2]) > 50)
    want10 = -0.1 * sum(np.mean(np.minimum(np.abs(per_sub[:, k]), 50.0)) for k in range(6))
    assert want10 < -0.1
    assert float(out.metrics["r10_limit"]) == pytest.approx(want10, rel=2e-3)
    # the same from a single C forward pass: qfrc_constraint (no contact) is the limit force
    dd = mujoco.MjData(mjm)
    dd.qpos[:], dd.qvel[:] = qp, qv
    mujoco.mj_forward(mjm, dd)
    dof3 = int(mjm.joint("j3").dofadr[0])
    assert dd.qfrc_constraint[dof3] == pytest.approx(c_limit_torque(mjm, dd)[dof3])


# ===================================================================== behaviour under zero action


def test_zero_action_keeps_it_standing(env, jreset, jstep, mjm):
    """4 s of a = 0: drops 0.1 m, settles on its paws and stands (the PD torques of Sec. V-A)."""
    n = 200
    for seed in range(30):  # a key whose trial is not stopped within 4 s (probability ~0.45 each)
        s = jreset(jax.random.key(1000 + seed))
        rec = []
        for _ in range(n):
            s = jstep(s, jnp.zeros(6))
            rec.append(s)
            if float(s.done):
                break
        if len(rec) == n and not float(rec[-1].done):
            break
    else:
        raise AssertionError("no key without a stop")
    obs = np.stack([np.asarray(r.obs) for r in rec])
    h = 0.6 + 0.2 * obs[:, 3]  # trunk height (y3 + y4)/2 from s_4
    speed = obs[:, 4] + 1.0  # (dx3 + dx4)/2 from s_5
    settled = h[50:]  # after 1 s
    assert abs(h[0] - 0.7) < 0.01 and settled.mean() < 0.69  # it dropped
    assert np.ptp(settled) < 0.03, (settled.min(), settled.max())
    assert np.all(np.abs(speed[50:]) < 0.1)
    assert np.all(obs[50:, 2] == 1.0) and np.all(obs[50:, 9] == 1.0)  # both paws on the ground
    lo = np.array([LO[i] - W0[i] for i in ACT]) + 1e-3
    hi = np.array([HI[i] - W0[i] for i in ACT]) - 1e-3
    for r in rec[50:]:
        qp = np.asarray(r.data.qpos)
        qa = np.array([qp[adr(mjm, f"j{i}")] for i in ACT])
        assert np.all((qa > lo) & (qa < hi))  # no joint on a limit
        assert float(r.metrics["r10_limit"]) == 0.0 and float(r.metrics["r9_torque"]) == 0.0
        y = np.asarray(forward_kinematics(r.data.qpos)[0])[:, 1]
        assert np.all(y[[1, 2, 3, 4, 5, 6, 7, 8]] > 0.05)  # only the paws touch the ground
        assert float(r.metrics["r11_lift"]) == pytest.approx(-0.98, abs=0.05)
        for k in ("r12_heel", "r13_knee", "r14_head"):
            assert float(r.metrics[k]) == 0.0
    assert abs(float(rec[-1].metrics["forward_speed"])) < 0.05
    r11 = np.array([float(r.metrics["r11_lift"]) for r in rec[100:]])
    assert r11.mean() == pytest.approx(-0.98, abs=0.01)  # standing still: (11) = -0.98, see above


# ======================================================================= jit / vmap / keys / resets


def test_shapes_single_and_batched(env, jreset, jstep, batch_run):
    s = jstep(jreset(jax.random.key(0)), jnp.zeros(6))
    assert s.obs.shape == (31,) and s.reward.shape == () and s.done.shape == ()
    assert s.obs.dtype == jnp.float32 and s.reward.dtype == jnp.float32
    sb = batch_run["s"]
    assert sb.obs.shape == (B, 31) and sb.reward.shape == (B,) and sb.done.shape == (B,)
    assert batch_run["s0"].obs.shape == (B, 31)
    assert np.all(np.isfinite(batch_run["obs"])) and np.all(np.isfinite(batch_run["reward"]))


def test_same_key_same_trajectory(env, jreset, jstep, batch_run):
    acts = jax.random.normal(jax.random.key(7), (30, 6))

    def run():
        s = jreset(jax.random.key(42))
        out = []
        for a in acts:
            s = jstep(s, a)
            out.append((np.asarray(s.obs), float(s.reward), float(s.done)))
        return out

    r1, r2 = run(), run()
    for (o1, w1, d1), (o2, w2, d2) in zip(r1, r2):
        np.testing.assert_array_equal(o1, o2)
        assert w1 == w2 and d1 == d2
    # in the batch, envs 0 and 1 share a key: identical stop times
    np.testing.assert_array_equal(batch_run["done"][:, 0], batch_run["done"][:, 1])


def test_different_keys_different_stop_times(batch_run):
    done = batch_run["done"][:, 2:]  # (T, B-2), distinct keys
    first = np.where(done.any(0), done.argmax(0), -1)
    stopped = first[first >= 0]
    assert len(np.unique(stopped)) >= 10
    assert (first < 0).sum() > 0.8 * done.shape[1]  # most trials have not stopped yet


def test_trial_stop_rate_is_1_over_250(batch_run):
    n = batch_run["done"].size
    k = batch_run["done"].sum()
    p = 1 / 250
    se = math.sqrt(n * p * (1 - p))
    assert abs(k - n * p) < 4 * se, (k, n * p, se)


def test_auto_reset_restores_reset_pose_and_keeps_terminal_obs(env, batch_run):
    done, obs, tobs = batch_run["done"], batch_run["obs"], batch_run["terminal_obs"]
    steps, qpos, qvel = batch_run["steps"], batch_run["qpos"], batch_run["qvel"]
    reset_obs = np.asarray(env.reset(jax.random.key(0)).obs)
    # with a = 0 every env follows the same physics until its first reset: a never-reset env at
    # step t shows what the pre-reset obs of an env stopped at t must be
    never = ~done.any(0)
    ref = np.argmax(never)
    assert never[ref]
    ts, es = np.nonzero(done)
    assert len(ts) > 50
    for t, e in zip(ts[:200], es[:200]):
        np.testing.assert_allclose(obs[t, e], reset_obs, atol=1e-6)
        np.testing.assert_allclose(qpos[t, e], 0.0, atol=0)
        np.testing.assert_allclose(qvel[t, e], 0.0, atol=0)
        assert steps[t, e] == 0
        if not done[:t, e].any():
            np.testing.assert_allclose(tobs[t, e], obs[t, ref], atol=1e-4)
            assert not np.allclose(tobs[t, e], reset_obs, atol=1e-3)
    # not done: terminal_obs == obs, the step counter counts
    t, e = T_BATCH - 1, ref
    np.testing.assert_array_equal(tobs[t, e], obs[t, e])
    assert steps[t, e] == T_BATCH


# ============================================================================== bad input


def test_bad_action_shape_and_dtype_fail_at_trace_time(env, jreset, jstep):
    s = jreset(jax.random.key(0))
    for bad in (jnp.zeros(5), jnp.zeros((6, 1)), jnp.zeros(())):
        with pytest.raises(ValueError, match=r"action must have shape \(6,\)"):
            jstep(s, bad)
    with pytest.raises(TypeError, match="floating"):
        jstep(s, jnp.zeros(6, jnp.int32))
    with pytest.raises(ValueError, match=r"shape \(6,\)"):
        jax.vmap(env.step)(jax.tree.map(lambda x: x[None], s), jnp.zeros((1, 5)))


def test_nan_action_is_flagged_and_reset(env, jreset, jstep):
    s = jstep(jreset(jax.random.key(0)), jnp.full(6, jnp.nan, jnp.float32))
    assert float(s.metrics["nonfinite"]) == 1.0 and float(s.done) == 1.0
    assert np.all(np.isfinite(np.asarray(s.obs))) and np.isfinite(float(s.reward))
    np.testing.assert_allclose(np.asarray(s.obs), np.asarray(env.reset(jax.random.key(0)).obs))
    assert np.all(np.isfinite(np.asarray(s.data.qpos)))
    s2 = jstep(s, jnp.zeros(6))  # and it goes on from the reset pose
    assert float(s2.metrics["nonfinite"]) == 0.0 and np.all(np.isfinite(np.asarray(s2.obs)))


def test_absurd_state_is_flagged(env, jreset, jstep):
    s = jreset(jax.random.key(0))
    s = s.replace(data=s.data.replace(qvel=s.data.qvel.at[3].set(1e30)))
    out = jstep(s, jnp.zeros(6))
    assert float(out.metrics["nonfinite"]) == 1.0 and float(out.done) == 1.0
    assert np.all(np.isfinite(np.asarray(out.obs))) and np.isfinite(float(out.reward))


def test_good_step_not_flagged(env, jreset, jstep):
    s = jstep(jreset(jax.random.key(0)), jnp.ones(6))
    assert float(s.metrics["nonfinite"]) == 0.0


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"control_dt": 0.013}, "multiple"),
        ({"control_dt": 0.0}, "control_dt"),
        ({"control_dt": -0.02}, "control_dt"),
        ({"control_dt": 0.02, "timestep": 0.003}, "multiple"),
        ({"control_dt": 0.001}, "multiple"),  # shorter than one physics step
        ({"stop_prob": 1.0}, "stop_prob"),
        ({"stop_prob": -0.1}, "stop_prob"),
        ({"stop_prob": float("nan")}, "stop_prob"),
        ({"timestep": 0.0}, "timestep"),
        ({"timestep": -0.005}, "timestep"),
        ({"solver_iterations": 0}, "solver_iterations"),
        ({"solver_iterations": 2.5}, "solver_iterations"),
        ({"ls_iterations": 0}, "ls_iterations"),
    ],
)
def test_bad_config_raises(kwargs, match):
    with pytest.raises(ValueError, match=match):
        HalfCheetah(EnvConfig(**kwargs))


@pytest.mark.parametrize("kwargs", [{"contact_tol": -0.01}])
def test_bad_config_contact_tol(kwargs):
    with pytest.raises(ValueError, match=next(iter(kwargs))):
        EnvConfig(**kwargs).validate()
