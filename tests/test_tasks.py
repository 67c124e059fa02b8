"""Gymnasium's v5 HalfCheetah, Hopper and Walker2d in nmrl (nmrl/tasks/) checked against
``gymnasium.make("<Task>-v5")`` itself (Gymnasium 1.4.0, MuJoCo 3.17.0).

Every check starts nmrl from the state Gymnasium's ``reset(seed=...)`` made (``Task.state_at``) and
feeds both the same uniform random actions; when Gymnasium's episode ends (terminated or truncated)
both restart from Gymnasium's next reset, so 1,000+ steps span several Hopper and Walker2d episodes.

* **C path: bit for bit.** MuJoCo's whole integration state after every step equals Gymnasium's
  (``mj_getState``) bit for bit, the observation is Gymnasium's rounded to float32 (the JAX side is
  float32), ``terminated`` and ``truncated`` are Gymnasium's, the reward equals it to float32
  precision (|Δr| <= 1e-6 (1 + |r|); measured worst: 3e-7 relative): it is computed in float32 from
  the float64 x before and after (nmrl/tasks/doubles.py), Gymnasium's in float64.
* **MJX: one step from each state, and a free run until chaos parts them.** MJX steps in float32, so
  it cannot follow float64 MuJoCo for long. From a start rounded to float32 (a relative change of
  ~1e-8), MuJoCo C *itself* parts from its unrounded run (relative observation difference > 1e-2)
  after 25-73 HalfCheetah steps (1.3-3.7 s), 68-1,000+ Hopper and 294-508 Walker2d steps; MJX parts
  from it after 12-45, 68-460 and 24-193 steps (seeds 0-4, uniform random actions, no reset after
  a fall; ``python tests/test_tasks.py`` prints the table): its float32 rounding perturbs every
  substep. The checks are therefore (a) one MJX step from each state of a 1,000-step Gymnasium run
  (episodes chained) equals Gymnasium's step: terminations exactly, the observation within 2e-4
  relative (``|Δ| / (1 + |o|)``) at 99% of the steps (measured: 3e-6 to 5e-5) and 0.5 at every step
  (measured worst 2e-4; in runs of fallen robots a step where a contact or a joint limit switches on
  in one engine and not the other within float32 rounding reaches 0.12), the reward within 1e-4
  relative (measured worst 3.5e-5); and (b) free runs of the first 5 HalfCheetah, 50 Hopper and 20
  Walker2d steps within 1e-3 (slow).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")

from nmrl import options
from nmrl.physics import mujoco_c  # noqa: E402
from nmrl.tasks import doubles  # noqa: E402
from nmrl.tasks.env import Task, TaskConfig  # noqa: E402
from nmrl.tasks.gym_v5 import TASKS, model_path  # noqa: E402

NAMES = tuple(TASKS)
STATE = mujoco.mjtState.mjSTATE_INTEGRATION
#: free-run horizon (steps) over which MJX stays within 1e-3 of Gymnasium (module docstring)
MJX_FREE_RUN = {"halfcheetah-v5": 5, "hopper-v5": 50, "walker2d-v5": 20}


def _gym(name):
    return gym.make(TASKS[name].gym_id)


def _mj_state(env) -> np.ndarray:
    u = env.unwrapped
    s = np.empty(mujoco.mj_stateSize(u.model, STATE))
    mujoco.mj_getState(u.model, u.data, s, STATE)
    return s


def _gym_run(name: str, n: int, seed: int):
    """Gymnasium's run of ``n`` steps of uniform random actions, episodes chained by ``reset(seed=...)``:
    per step (qpos, qvel before it, action, obs, reward, terminated, truncated, MuJoCo state after)."""
    env = _gym(name)
    env.reset(seed=seed)
    env.action_space.seed(seed)
    rows = []
    for k in range(n):
        d = env.unwrapped.data
        q, v = d.qpos.copy(), d.qvel.copy()
        a = env.action_space.sample()
        o, r, term, trunc, _ = env.step(a)
        rows.append((q, v, a, o, r, term, trunc, _mj_state(env)))
        if term or trunc:
            env.reset(seed=seed + 1 + k)
    return rows


# --------------------------------------------------------------------------------------- C path
@pytest.mark.parametrize("name", NAMES)
def test_c_path_equals_gymnasium_bit_for_bit(name):
    env = Task(name, TaskConfig(physics="c", auto_reset=False))
    rows = _gym_run(name, 1010, seed=3)
    step = jax.jit(env.step)
    state, worst = None, 0.0
    ends = {"terminated": 0, "truncated": 0}
    for k, (q, v, a, o, r, term, trunc, s_gym) in enumerate(rows):
        if state is None:
            state = env.state_at(q, v)
        state = step(state, a)
        s = mujoco_c.from_bits(np.asarray(state.data.state))
        assert s.view(np.uint64).tolist() == s_gym.view(np.uint64).tolist(), f"step {k}: MuJoCo state differs"
        np.testing.assert_array_equal(np.asarray(state.obs), o.astype(np.float32), err_msg=f"step {k}")
        assert (float(state.info["terminated"]), float(state.info["truncated"])) == (term, trunc), k
        assert float(state.done) == float(term or trunc)
        worst = max(worst, abs(float(state.reward) - r) / (1 + abs(r)))
        ends["terminated"] += term
        ends["truncated"] += trunc
        if term or trunc:
            state = None
    assert worst <= 1e-6
    if name == "halfcheetah-v5":
        assert ends == {"terminated": 0, "truncated": 1}  # the time limit at step 1,000
    else:
        assert ends["terminated"] >= 5  # random actions fell the robot in several episodes


def test_reward_terms_are_gymnasiums():
    """The reward of one Hopper step, term by term, as Gymnasium's ``info`` gives them."""
    env = Task("hopper-v5", TaskConfig(physics="c", auto_reset=False))
    g = _gym("hopper-v5")
    g.reset(seed=0)
    state = env.state_at(g.unwrapped.data.qpos, g.unwrapped.data.qvel)
    a = np.array([0.5, -1.0, 0.25], np.float32)
    _, r, _, _, info = g.step(a)
    state = jax.jit(env.step)(state, a)
    for k in ("reward_forward", "reward_ctrl", "reward_survive"):
        np.testing.assert_allclose(float(state.metrics[k]), info[k], rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(float(state.metrics["x_velocity"]), info["x_velocity"], rtol=1e-6)


def test_models_are_gymnasiums_files():
    for name, spec in TASKS.items():
        env = _gym(name).unwrapped
        assert env.fullpath == str(model_path(spec))
        assert (env.frame_skip, env.model.opt.timestep) == (spec.frame_skip, spec.timestep)
        assert Task(name, TaskConfig(physics="c")).control_dt == env.dt
        assert _gym(name).spec.max_episode_steps == spec.max_episode_steps


def test_doubles_read_float64_as_float32_pairs():
    rng = np.random.default_rng(0)
    x = np.concatenate([rng.normal(size=500) * 10.0 ** rng.integers(-6, 4, 500), [0.0, -0.0, 1.0, -2.5, np.inf]])
    hi, lo = jax.jit(doubles.split)(jnp.asarray(mujoco_c.to_bits(x)))
    hi, lo = np.asarray(hi, np.float64), np.asarray(lo, np.float64)
    fin = np.isfinite(x)
    assert np.all(np.abs(hi[fin] + lo[fin] - x[fin]) <= 2.0**-47 * np.abs(x[fin]))
    assert np.array_equal(hi[fin], x[fin].astype(np.float32))  # hi is float32 rounding of x
    assert hi[-1] == np.inf
    # the difference of two close numbers far from 0 keeps its bits (float32 alone loses them)
    a, b = 123.456789012345, 123.456789012345 + 3e-7
    pa, pb = (jax.jit(doubles.split)(jnp.asarray(mujoco_c.to_bits(np.array([v])))) for v in (a, b))
    np.testing.assert_allclose(float(doubles.diff(pb, pa)[0]), b - a, rtol=1e-6)
    assert bool(doubles.greater(pb, b - 1e-12)[0]) and not bool(doubles.greater(pb, b + 1e-12)[0])


# ----------------------------------------------------------------------------- the interface
def test_reset_noise_is_gymnasiums_distribution():
    for name in ("halfcheetah-v5", "hopper-v5"):
        env = Task(name, TaskConfig(physics="c"))
        s = TASKS[name].reset_noise_scale
        st = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), 4000))
        q = mujoco_c.from_bits(np.asarray(st.data.state))
        dq, v = env.c.split(q)[0] - env.init_qpos, env.c.split(q)[1]
        assert np.all(np.abs(dq) <= s) and np.allclose(dq.std(0), s / np.sqrt(3), rtol=0.05)
        if TASKS[name].qvel_noise == "normal":
            np.testing.assert_allclose(v.std(0), s, rtol=0.05)
        else:
            assert np.all(np.abs(v) <= s) and np.allclose(v.std(0), s / np.sqrt(3), rtol=0.05)
        c = TASKS[name].obs_qvel_clip or np.inf
        qpos = env.c.split(q)[0]
        want = np.concatenate([qpos[:, 1:], np.clip(v, -c, c)], axis=1).astype(np.float32)
        np.testing.assert_array_equal(np.asarray(st.obs), want)


def test_a_finer_control_step_keeps_seconds_and_rates():
    """HalfCheetah at 0.01 s (frame skip 1): five steps are the 0.05 s step's substeps bit for bit,
    their rewards sum to its reward (rates), and the time limit stays 50 s."""
    coarse = Task("halfcheetah-v5", TaskConfig(physics="c", auto_reset=False))
    fine = Task("halfcheetah-v5", TaskConfig(physics="c", control_dt=0.01, auto_reset=False))
    assert (fine.n_substeps, fine.max_steps, coarse.max_steps) == (1, 5000, 1000)
    assert fine.max_steps * fine.control_dt == pytest.approx(coarse.max_steps * coarse.control_dt)
    s0 = coarse.reset(jax.random.key(1))
    a = jnp.asarray([0.3, -0.7, 1.0, -1.0, 0.1, 0.5])
    c1 = jax.jit(coarse.step)(s0, a)
    f, total = s0, 0.0
    for _ in range(5):
        f = jax.jit(fine.step)(f, a)
        total += float(f.reward)
    np.testing.assert_array_equal(np.asarray(f.data.state), np.asarray(c1.data.state))
    np.testing.assert_allclose(total, float(c1.reward), rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="multiple of HalfCheetah-v5's physics timestep 0.01"):
        Task("halfcheetah-v5", TaskConfig(control_dt=0.015))


def test_auto_reset_keeps_the_terminal_observation_and_the_flags_apart():
    env = Task("hopper-v5", TaskConfig(physics="c", auto_reset=True))
    step = jax.jit(jax.vmap(env.step))
    st = jax.vmap(env.reset)(jax.random.split(jax.random.key(2), 3))
    a = jnp.asarray([[1.0, -1.0, 1.0]] * 3)
    for _ in range(200):
        prev = st
        st = step(st, a)
        if float(st.done.max()) > 0:
            break
    i = int(np.argmax(np.asarray(st.done)))
    assert float(st.info["terminated"][i]) == 1.0 and float(st.info["truncated"][i]) == 0.0
    assert int(st.info["steps"][i]) == 0 and int(prev.info["steps"][i]) >= 1
    assert not np.array_equal(np.asarray(st.obs[i]), np.asarray(st.info["terminal_obs"][i]))
    assert float(st.metrics["reward_survive"][i]) == 0.0  # Gymnasium: healthy_reward * is_healthy
    with pytest.raises(ValueError, match="choose one of halfcheetah-v5, hopper-v5, walker2d-v5"):
        Task("ant-v5")


# ------------------------------------------------------------------------- --env (the learners)
def test_make_env_and_its_refusals():
    from nmrl.paper.env import EnvConfig, HalfCheetah
    from nmrl.tasks import ENVS, make_env

    assert ENVS == ("paper-cheetah", "halfcheetah-v5", "hopper-v5", "walker2d-v5")
    assert isinstance(make_env("paper-cheetah", EnvConfig(physics="c")), HalfCheetah)
    env = make_env("walker2d-v5", EnvConfig(control_dt=0.02, physics="c", auto_reset=False))
    assert isinstance(env, Task) and (env.n_substeps, env.max_steps, env.config.auto_reset) == (10, 400, False)
    with pytest.raises(ValueError, match="stop_prob, timestep are options of paper-cheetah only"):
        make_env("hopper-v5", EnvConfig(stop_prob=0.01, timestep=0.001))


def test_ppo_takes_env_into_its_config_and_identity(tmp_path, capsys):
    from nmrl import cli
    from nmrl.learners.ppo_config import PPOConfig
    from nmrl.runs import identity

    assert "env" not in identity.identity_config(PPOConfig())  # runs made before the option keep their digest
    assert identity.identity_config(options.build(PPOConfig, env="hopper-v5"))["env"] == "hopper-v5"
    out = tmp_path / "r"
    assert cli.main(["train", "--learner", "ppo", "--env", "ant-v5", "--steps", "10", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["nmrl: error: env='ant-v5' is invalid: choose one of paper-cheetah, halfcheetah-v5, hopper-v5, "
                   "walker2d-v5"] and not out.exists()


@pytest.mark.slow
def test_ppo_trains_on_a_task(tmp_path):
    import json

    from nmrl import cli

    out = tmp_path / "r"
    assert cli.main(["train", "--learner", "ppo", "--env", "hopper-v5", "--physics", "c", "--num-envs", "4",
                     "--batch-size", "4", "--num-minibatches", "2", "--epochs", "1", "--policy-layers", "1",
                     "--value-layers", "1", "--steps", "100", "--out", str(out)]) == 0
    assert json.loads((out / "config.json").read_text())["env"] == "hopper-v5"


# ------------------------------------------------------------------------------------- MJX
@pytest.mark.parametrize("name", [pytest.param(n, marks=() if n == "halfcheetah-v5" else pytest.mark.slow)
                                  for n in NAMES])
def test_mjx_one_step_from_each_state_equals_gymnasium(name):
    env = Task(name, TaskConfig(physics="mjx", auto_reset=False))
    rows = _gym_run(name, 1000, seed=4)
    step = jax.jit(env.step)  # one state at a time: compiles faster than the vmapped step
    outs = [step(env.state_at(q, v), a) for q, v, a, *_ in rows]
    got_obs, got_rew = np.stack([o.obs for o in outs]), np.array([o.reward for o in outs])
    obs = np.stack([r[3] for r in rows])
    rew, term = np.array([r[4] for r in rows]), np.array([r[5] for r in rows])
    err = np.max(np.abs(got_obs - obs) / (1 + np.abs(obs)), axis=1)
    np.testing.assert_array_equal([float(o.info["terminated"]) > 0 for o in outs], term)
    assert np.quantile(err, 0.99) <= 2e-4 and err.max() <= 0.5, (np.quantile(err, 0.99), err.max())
    assert np.max(np.abs(got_rew - rew) / (1 + np.abs(rew))) <= 1e-4


@pytest.mark.slow
@pytest.mark.parametrize("name", NAMES)
def test_mjx_free_run_follows_gymnasium_until_chaos(name):
    env = Task(name, TaskConfig(physics="mjx", auto_reset=False))
    h = MJX_FREE_RUN[name]
    for seed in range(3):
        rows = _gym_run(name, h, seed=seed)
        acts = jnp.asarray(np.stack([r[2] for r in rows]))
        _, out = jax.jit(lambda s, a: jax.lax.scan(lambda s, x: (env.step(s, x),) * 2, s, a))(
            env.state_at(rows[0][0], rows[0][1]), acts)
        ends = [k for k, r in enumerate(rows) if r[5] or r[6]]
        n = ends[0] + 1 if ends else h  # up to Gymnasium's first episode end
        obs, rew = np.stack([r[3] for r in rows[:n]]), np.array([r[4] for r in rows[:n]])
        np.testing.assert_array_less(np.abs(np.asarray(out.obs[:n]) - obs) / (1 + np.abs(obs)), 1e-3)
        np.testing.assert_array_less(np.abs(np.asarray(out.reward[:n]) - rew), 1e-3)
        np.testing.assert_array_equal(np.asarray(out.info["terminated"][:n]) > 0, [r[5] for r in rows[:n]])


# ----------------------------------------------------------------- the measurement behind the horizons
def parting_steps(name: str, seeds=range(5), n: int = 1000, tol: float = 1e-2) -> dict[str, list[int]]:
    """The first step at which a run's observation differs from Gymnasium's float64 run by more than
    ``tol`` (relative), per seed: MuJoCo C started from the state rounded to float32, and MJX."""
    out = {"c_from_float32_start": [], "mjx": []}
    env = Task(name, TaskConfig(physics="mjx", auto_reset=False))
    roll = jax.jit(lambda s, a: jax.lax.scan(lambda s, x: (env.step(s, x),) * 2, s, a)[1].obs)
    for seed in seeds:
        ref, other = _gym(name).unwrapped, _gym(name).unwrapped
        ref.reset(seed=seed)
        other.reset(seed=seed)
        q, v = ref.data.qpos.copy(), ref.data.qvel.copy()
        other.set_state(q.astype(np.float32).astype(np.float64), v.astype(np.float32).astype(np.float64))
        acts = np.random.default_rng(seed).uniform(-1, 1, (n, env.act_dim)).astype(np.float32)
        o_ref = np.stack([ref.step(a)[0] for a in acts])
        o_other = np.stack([other.step(a)[0] for a in acts])
        o_mjx = np.asarray(roll(env.state_at(q, v), jnp.asarray(acts)))
        for key, o in (("c_from_float32_start", o_other), ("mjx", o_mjx)):
            far = np.max(np.abs(o - o_ref) / (1 + np.abs(o_ref)), axis=1) > tol
            out[key].append(int(np.argmax(far)) if far.any() else n)
    return out


if __name__ == "__main__":
    for task in NAMES:
        print(task, parting_steps(task))


@pytest.mark.parametrize("name", NAMES)
def test_ppo_acts_within_the_tasks_action_space(name):
    """PPO's squashed action covers the task's action space and nothing beyond it (Gymnasium's
    ``action_space``, read from gymnasium itself); on the paper's robot it spans a = 20 u (Sec. V-A:
    a^0 = 0.1 a in [-2, 2])."""
    from nmrl.learners import ppo, ppo_config

    space = _gym(name).action_space
    for env_name, lo, hi in ((name, space.low, space.high), ("paper-cheetah", -20.0, 20.0)):
        cfg = options.build(ppo_config.PPOConfig, env=env_name, physics="c", num_envs=2, policy_layers=1, value_layers=1)
        tr = ppo.make_ppo(cfg)
        st = tr.init(jax.random.PRNGKey(0))
        pol = ppo.policy(cfg, tr.env)
        params = {"policy": st.policy, "obs_stats": st.obs_stats}
        obs = st.env.obs[0]
        for sign in (1.0, -1.0):
            a = np.asarray(pol.act(params, obs, sign * 8.0 * jnp.ones(tr.env.act_dim)), np.float64)
            assert np.all(a >= lo) and np.all(a <= hi), (env_name, a)
            edge = hi if sign > 0 else lo
            np.testing.assert_allclose(a, np.broadcast_to(edge, a.shape), rtol=1e-3, atol=1e-3 * np.max(np.abs(hi)))


def test_ppo_learns_from_a_fall_as_a_termination_and_from_nothing_else_as_one():
    """Gymnasium's Hopper terminates when it is unhealthy (the value after the fall is 0); PPO's
    batch marks those steps as terminations, not as truncations (which carry no learning signal)."""
    from nmrl.learners import ppo, ppo_config

    cfg = options.build(ppo_config.PPOConfig, env="hopper-v5", physics="c", num_envs=4, batch_size=4, num_minibatches=2,
                               policy_layers=1, value_layers=1, sigma=3.0)
    tr = ppo.make_ppo(cfg)
    st = tr.init(jax.random.PRNGKey(0))
    _, data = jax.jit(tr.rollout)(st, jax.random.PRNGKey(1))
    term, trunc = np.asarray(data.termination), np.asarray(data.truncation)
    assert term.shape[-1] * term.shape[-2] < 1000  # no episode reaches Hopper's time limit in one iteration
    assert term.sum() > 0 and trunc.sum() == 0, (term.sum(), trunc.sum())


def test_a_task_runs_eval_scores_episodes_as_a_gymnasium_loop_does(tmp_path):
    """``nmrl eval`` of a PPO run on Hopper-v5 (C physics, the task's own control step by default)
    reports each episode's return and length;
    a plain Gymnasium loop from the same reset states, with actions from the same policy on
    Gymnasium's observations, ends its episodes at the same steps with the same returns."""
    import json

    from nmrl import cli
    from nmrl.analysis import eval_env, task_eval
    from nmrl.learners import ppo
    from nmrl.runs import checkpoint

    out = tmp_path / "r"
    assert cli.main(["train", "--learner", "ppo", "--env", "hopper-v5", "--physics", "c", "--num-envs", "4",
                     "--batch-size", "4", "--num-minibatches", "2", "--epochs", "1", "--policy-layers", "1",
                     "--value-layers", "1", "--steps", "100", "--out", str(out)]) == 0
    assert cli.main(["eval", str(out), "--seed", "5"]) == 0
    ev = json.loads((out / "eval" / "eval.json").read_text())
    det = ev["deterministic"]
    assert ev["env"] == "hopper-v5" and ev["physics"] == "c" and det["episodes"] == task_eval.EPISODES
    assert not (out / "eval" / "strobe.png").exists()

    _, cfg, params = checkpoint.restore_params(out)
    env = eval_env.eval_env("hopper-v5", float(cfg.environment.control_dt), "c")
    pol = ppo.policy(cfg, env)
    k_reset, _ = jax.random.split(jax.random.PRNGKey(5))
    s0 = jax.vmap(env.reset)(jax.random.split(k_reset, task_eval.EPISODES))
    g = _gym("hopper-v5")
    assert cfg.environment.control_dt == g.unwrapped.dt  # without --control-dt a task runs at its own step
    for i in range(task_eval.EPISODES):
        q, v = env.c.split(mujoco_c.from_bits(np.asarray(s0.data.state[i])))
        g.reset(seed=0)
        g.unwrapped.set_state(q, v)
        obs, ret, n = g.unwrapped._get_obs(), 0.0, 0
        while True:
            a = np.asarray(pol.act(params, jnp.asarray(obs, jnp.float32), jnp.zeros(env.act_dim)), np.float64)
            obs, r, term, trunc, _ = g.step(a)
            ret, n = ret + r, n + 1
            if term or trunc:
                break
        assert n == det["length"][i], (i, n, det["length"][i])
        np.testing.assert_allclose(det["return"]["each"][i], ret, rtol=1e-4)


def test_a_task_run_at_another_step_resumes_with_its_env_given_again(tmp_path):
    """The task's own step is the default of a fresh run only: a run made at 0.004 s continues when
    ``--env`` is given again without ``--control-dt``."""
    import json

    from nmrl import cli

    out = tmp_path / "r"
    argv = ["train", "--learner", "ppo", "--env", "hopper-v5", "--physics", "c", "--num-envs", "4",
            "--batch-size", "4", "--num-minibatches", "2", "--epochs", "1", "--policy-layers", "1",
            "--value-layers", "1", "--out", str(out)]
    assert cli.main([*argv, "--control-dt", "0.004", "--steps", "200"]) == 0  # one iteration: 2 unrolls of 100
    assert cli.main([*argv, "--resume", "--steps", "200"]) == 0
    assert json.loads((out / "config.json").read_text())["control_dt"] == 0.004


@pytest.mark.parametrize("name", sorted(TASKS))
def test_each_tasks_model_is_gymnasiums_field_for_field_without_the_deprecated_attribute(name, capfd):
    """nmrl's compiled model of each task equals MuJoCo's compile of Gymnasium's file in every array
    field, and loading it prints no deprecation warning (HalfCheetah's settotalmass is applied after
    compiling)."""
    import mujoco

    from nmrl.tasks.gym_v5 import load_model

    capfd.readouterr()
    got = load_model(TASKS[name])
    assert "deprecated" not in capfd.readouterr().err
    ref = mujoco.MjModel.from_xml_path(str(model_path(TASKS[name])))
    capfd.readouterr()
    fields = [n for n in dir(ref) if not n.startswith("_") and isinstance(getattr(ref, n, None), np.ndarray)]
    assert len(fields) > 50
    for n in fields:
        np.testing.assert_array_equal(getattr(got, n), getattr(ref, n), err_msg=n)
