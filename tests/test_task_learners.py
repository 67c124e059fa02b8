"""The learners on Gymnasium's tasks (``--env``, docs/tasks.md): the actor-critic's action on each
task's action space, the env in its config and identity (runs without it keep their digest), the
refusals of every command that builds an environment, the studies' cells and endpoint, and every
exploration process on every task with each learner that takes it."""

from __future__ import annotations

import json
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")

from nmrl import options
from nmrl import cli  # noqa: E402
from nmrl.learners import ac  # noqa: E402
from nmrl.learners.ac_config import TrainConfig  # noqa: E402
from nmrl.physics import mujoco_c  # noqa: E402
from nmrl.runs import checkpoint, identity  # noqa: E402
from nmrl.tasks.gym_v5 import TASKS  # noqa: E402

NAMES = tuple(TASKS)
REPO = pathlib.Path(__file__).resolve().parents[1]
#: a tiny actor-critic run on MuJoCo C
AC_TINY = ["--physics", "c", "--num-envs", "4", "--hidden-actor", "8", "--hidden-critic", "8"]
PPO_TINY = ["--learner", "ppo", "--physics", "c", "--num-envs", "4", "--batch-size", "4", "--num-minibatches", "2",
            "--epochs", "1", "--policy-layers", "1", "--policy-width", "16", "--value-layers", "1",
            "--value-width", "16"]


def _gym(name):
    return gym.make({"halfcheetah-v5": "HalfCheetah-v5", "hopper-v5": "Hopper-v5", "walker2d-v5": "Walker2d-v5"}[name])


# ------------------------------------------------------------------ the actor-critic's action
@pytest.mark.parametrize("name", NAMES)
def test_ac_maps_its_action_onto_the_tasks_action_space(name):
    """The actor's a (paper units, a = 20 u spans the range) reaches a task as centre + half-width *
    clip(a / 20, -1, 1) of Gymnasium's own ``action_space``; on the paper's robot a is sent as it is."""
    space = _gym(name).action_space
    lo, hi = space.low.astype(np.float64), space.high.astype(np.float64)
    for env_name in (name, "paper-cheetah"):
        cfg = options.build(TrainConfig, env=env_name, physics="c", num_envs=1, hidden_actor=4, hidden_critic=4)
        tr = ac.make(cfg)
        theta = tr.init(jax.random.PRNGKey(0)).theta  # output layer 0: a~ = 0 (Sec. V-C)
        pol = ac.policy(cfg, tr.env)
        obs = jnp.zeros(tr.env.obs_dim)
        for a in (5.0, -12.0, 30.0, -400.0):
            got = np.asarray(pol.act({"theta": theta}, obs, a * jnp.ones(tr.env.act_dim)), np.float64)
            want = ((lo + hi) / 2 + (hi - lo) / 2 * np.clip(a / 20, -1, 1)) if env_name == name else a
            np.testing.assert_allclose(got, np.broadcast_to(want, got.shape), rtol=1e-6, atol=1e-7)


def test_ac_trains_on_a_task_with_the_control_cost_of_an_action_inside_the_space(tmp_path):
    """``nmrl train --env hopper-v5`` (the actor-critic): the task's own control step, the env in
    config.json and the identity; with sigma = 10 (the largest allowed) the exploring a ~ N(0, 10^2)
    reaches the task as u = clip(a / 20) with E u^2 ~ 0.23, and the control cost is Gymnasium's of
    an action in [-1, 1]^3: between 3e-4 and 3e-3 per step (a sent unmapped would cost ~0.3)."""
    out = tmp_path / "r"
    assert cli.main(["train", "--env", "hopper-v5", *AC_TINY, "--sigma", "10", "--chunk-steps", "25",
                     "--steps", "50", "--out", str(out)]) == 0
    cfg = json.loads((out / "config.json").read_text())
    assert (cfg["env"], cfg["control_dt"]) == ("hopper-v5", _gym("hopper-v5").unwrapped.dt)
    rows = [json.loads(x) for x in (out / "metrics.jsonl").read_text().splitlines()]
    assert len(rows) == 2
    for r in rows:
        assert -3e-3 - 1e-7 <= r["reward_ctrl"] < -3e-4, r["reward_ctrl"]
    assert identity.identity_config(checkpoint.load_run_config(out))["env"] == "hopper-v5"


def test_ac_learns_from_a_fall_with_the_value_after_it_0():
    """On Hopper-v5 a fall ends the actor-critic's period and is learned from with the value after it
    0; nothing else ends a trial within 100 steps. With l = 1, the step sizes 0 and a critic V = c
    everywhere, every step is a learned period with d = r + gamma c - c, or r - c where it fell: the
    chunk's summed TD error is sum r + c (gamma (n - falls) - n)."""
    c, gamma, N, T = 5.0, 0.9, 4, 100
    cfg = options.build(TrainConfig, env="hopper-v5", control_dt=0.008, physics="c", l=1, sigma=10.0, gamma=gamma, num_envs=N,
                      chunk_steps=T, hidden_actor=8, hidden_critic=8, beta_theta=0.0, beta_v=0.0)
    tr = ac.make(cfg)
    ts = tr.init(jax.random.PRNGKey(0))
    v = jax.tree.map(lambda x: x, ts.v)
    v["params"]["output"]["bias"] = jnp.full_like(v["params"]["output"]["bias"], c)
    ts, m = jax.jit(tr.chunk)(ts.replace(v=v))
    n, falls = int(m["periods_in_chunk"]), int(m["trials_in_chunk"])
    assert falls > 0 and n == N * T
    td_sum = float(m["td_mean"]) * n
    want = float(m["avg_reward"]) * N * T + c * (gamma * (n - falls) - n)
    assert td_sum == pytest.approx(want, rel=1e-4, abs=1e-3)


@pytest.mark.slow
def test_an_ac_sweep_runs_every_point_on_the_task(tmp_path):
    """``nmrl sweep --env walker2d-v5`` over l: every point's config and the saved spec name the task
    and its own control step; each point learned periods of its own l on it."""
    out = tmp_path / "s"
    assert cli.main(["sweep", "--env", "walker2d-v5", *AC_TINY[:2], "--num-envs", "2", "--hidden-actor", "8",
                     "--hidden-critic", "8", "--l", "1", "4", "--seeds", "1", "--chunk-steps", "20", "--steps", "20",
                     "--out", str(out)]) == 0
    assert json.loads((out / "sweep.json").read_text())["base"]["env"] == "walker2d-v5"
    points = sorted((out / "points").iterdir())
    assert len(points) == 2
    periods = {}
    for d in points:
        cfg = json.loads((d / "config.json").read_text())
        assert (cfg["env"], cfg["control_dt"]) == ("walker2d-v5", 0.008)
        periods[cfg["l"]] = json.loads((d / "metrics.jsonl").read_text().splitlines()[-1])["periods_in_chunk"]
    assert periods[1] >= 30 and 0 < periods[4] <= 12, periods  # 2 environments x 20 steps in periods of l


def test_runs_without_env_keep_their_identity():
    """Checkpoints written before the field (tests/data, by f021abf's code) carry the identity digest
    their code computed; the config read back today gives the same digest. Every committed run
    config of the actor-critic reads back as the paper's robot with no env in its identity."""
    data = REPO / "tests" / "data"
    metas = sorted(data.glob("f021abf_*/**/checkpoints/*/meta/metadata"))
    assert len(metas) >= 3
    for m in metas:
        run = m.parents[3]
        meta = json.loads(m.read_text())
        cfg = checkpoint.load_run_config(run)
        assert cfg.environment.env == "paper-cheetah"
        assert meta["identity"] == identity.identity_digest(cfg, meta["model_sha256"]), run
    fields = set(options.leaves(TrainConfig)) | {"learner"}
    configs = [p for p in (REPO / "results").glob("**/config.json")  # the actor-critic's (not Brax's, PPO's)
               if json.loads(p.read_text()).get("learner", "ac") == "ac" and set(json.loads(p.read_text())) <= fields]
    assert configs
    for p in configs:
        cfg = checkpoint.load_run_config(p.parent)
        assert cfg.environment.env == "paper-cheetah" and "env" not in identity.identity_config(cfg), p


# ----------------------------------------------------------------------------- refusals
@pytest.mark.parametrize("argv, why", [
    (["train", "--env", "ant-v5"], "env='ant-v5' is invalid: choose one of paper-cheetah, halfcheetah-v5, "
                                   "hopper-v5, walker2d-v5"),
    (["train", "--env", "hopper-v5", "--trial-s", "5"], "trial_s is an option of paper-cheetah only"),
    (["train", "--env", "halfcheetah-v5", "--control-dt", "0.015"], "0.015"),
    (["sweep", "--env", "walker2d-v5", "--stop-prob", "0.01", "--l", "1", "2"], "stop_prob is an option of paper-cheetah only"),
    (["sweep", "--env", "ant-v5", "--l", "1"], "env='ant-v5' is invalid"),
    (["study", "--env", "ant-v5"], "env='ant-v5' is invalid"),
    (["study", "--env", "halfcheetah-v5"], "0.005"),  # the study's default 5 ms step is not HalfCheetah's
    # colored's default band (to 25 Hz) needs a step of at most 0.02 s: HalfCheetah's 0.05 s is refused
    (["train", "--learner", "ppo", "--env", "halfcheetah-v5", "--exploration", "colored"],
     "f_max_hz must be <= the Nyquist frequency 10 Hz"),
])
def test_bad_env_input_is_refused_in_one_line(tmp_path, capsys, argv, why):
    out = tmp_path / "r"
    assert cli.main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and why in err[0], err
    assert not out.exists()


# ------------------------------------------------------------------------- the studies
def test_the_finer_step_study_takes_env_into_every_point():
    """``nmrl study --env`` (the actor-critic): every grid and final point runs on the task, with the
    task's own end of a trial and its rates (no stop probability or reward scale converted from the
    paper's 0.02 s)."""
    from nmrl.experiments.timescale import TimescaleSpec

    spec = TimescaleSpec(dts=(0.016, 0.008), periods=(None, 0.08), base=options.build(TrainConfig, env="hopper-v5"),
                         chunk_seconds=0.08, grid_seconds=0.16, final_seconds=0.16)
    spec.validate()
    cfgs = [c for dt in spec.dts for c in spec.grid_points(dt)[1]]
    cfgs += [c for dt in spec.dts for c in spec.final_points(dt, {"stationary": (1e-5, 1e-4), "p0.08s": (1e-5, 1e-4)})[1]]
    assert len(cfgs) == 2 * 2 * 9 + 2 * 2 * 3
    for c in cfgs:
        assert (c.environment.env, c.environment.stop_prob, c.reward_scale) == ("hopper-v5", TrainConfig().environment.stop_prob, 1.0)
    assert {c.l for c in cfgs} == {1, 5, 10}  # 0.08 s periods at 16 and 8 ms
    assert TimescaleSpec.from_json(spec.to_json()) == spec


def test_the_endpoint_on_a_task_is_a_gymnasium_episodes_return_per_second():
    """The deterministic endpoint of a policy on Hopper-v5: from the task's reset states, a plain
    Gymnasium loop driven by the same policy sums its rewards until it terminates (or the seconds
    end); that sum over the seconds is the endpoint's reward per second of each rollout."""
    from nmrl.analysis import endpoint, eval_env

    cfg = options.build(TrainConfig, env="hopper-v5", control_dt=0.008, physics="c", hidden_actor=8, hidden_critic=8).resolved()
    tr = ac.make(options.replace(cfg, num_envs=1))
    theta = tr.init(jax.random.PRNGKey(0)).theta
    theta = jax.tree.map(lambda x: x + 3.0 * jax.random.normal(jax.random.PRNGKey(7), x.shape), theta)  # acts
    out = endpoint.deterministic_endpoint(cfg, {"theta": theta}, seconds=1.2, rollouts=3, seed=2)
    n = 150
    assert out["seconds"] == pytest.approx(n * 0.008) and out["start_noise"] is None
    env = eval_env.eval_env("hopper-v5", 0.008, "c")
    pol = ac.policy(cfg, env)
    g = _gym("hopper-v5")
    ended = 0
    for i, key in enumerate(jax.random.split(jax.random.PRNGKey(2), 3)):
        s0 = env.reset(jax.random.split(key)[0])
        q, v = env.c.split(mujoco_c.from_bits(np.asarray(s0.data.state)))
        g.reset(seed=0)
        g.unwrapped.set_state(q, v)
        obs, ret = g.unwrapped._get_obs(), 0.0
        for _ in range(n):
            a = np.asarray(pol.act({"theta": theta}, jnp.asarray(obs, jnp.float32), jnp.zeros(3)), np.float64)
            obs, r, term, _, _ = g.step(a)
            ret += r
            if term:
                ended += 1
                break
        np.testing.assert_allclose(out["rollouts"][i], ret / (n * 0.008), rtol=1e-4, atol=1e-4)
    assert ended >= 1  # the check covers a fall


# -------------------------------------------------- every exploration process on every task
PPO_KINDS = ("white", "nm-periods", "ou", "colored")
CASES = [("ppo", k, n) for k in PPO_KINDS for n in NAMES] + [("ac", k, n) for k in ac.EXPLORATIONS for n in NAMES]
FAST = {("ppo", "colored", "hopper-v5"), ("ac", "nm-periods", "hopper-v5")}


def _case(c):
    return pytest.param(*c, id="-".join(c), marks=() if c in FAST else pytest.mark.slow)


@pytest.mark.parametrize("learner, kind, name", [_case(c) for c in CASES])
def test_every_exploration_process_trains_on_every_task(tmp_path, learner, kind, name):
    """Two chunks of training with the process on the task (its own control step), then a check
    that fails when the process is not the one asked for at that step:

    * PPO: at the trained policy, the likelihood of a fresh rollout's actions recomputed by the
      process's exact (Kalman) log-density over each unroll equals the one the sampler recorded
      (the ratio of PPO's first update is 1), also across the task's terminations and resets;
    * the actor-critic: the standardized noise xi of consecutive steps inside a period has the
      correlation exp(-delta / corr_time) at the task's delta (nm-periods), and none across steps
      (white: every step a period)."""
    out = tmp_path / "r"
    dt = _gym(name).unwrapped.dt
    if learner == "ppo":
        from nmrl.learners import ppo, ppo_config

        it = options.build(ppo_config.PPOConfig, env=name, control_dt=dt, num_envs=4, batch_size=4,
                                  num_minibatches=2).resolved().iteration_steps
        # colored's default band ends at 25 Hz, above the Nyquist frequency 10 Hz of HalfCheetah's 0.05 s
        band = ["--f-max-hz", str(0.5 / dt)] if kind == "colored" and 0.5 / dt < 25 else []
        argv = [*PPO_TINY, "--exploration", kind, *band, "--steps", str(2 * it)]
    else:
        extra = ["--period-s", "0.2", "--corr-time-s", "0.1"] if kind == "nm-periods" else []
        argv = [*AC_TINY, "--exploration", kind, *extra, "--chunk-steps", "20", "--steps", "40"]
    assert cli.main(["train", "--env", name, *argv, "--out", str(out)]) == 0
    rows = [json.loads(x) for x in (out / "metrics.jsonl").read_text().splitlines()]
    assert len(rows) == 2 and all(np.isfinite(r["avg_reward"]) and not r["diverged"] for r in rows)
    cfg = checkpoint.load_run_config(out)
    assert (cfg.environment.env, cfg.environment.control_dt) == (name, dt)
    if learner == "ppo":
        from nmrl.learners import ppo

        tr = ppo.make_ppo(cfg)
        st = checkpoint.restore(out, tr)
        _, data = jax.jit(tr.rollout)(st, jax.random.PRNGKey(9))
        lp = tr.seq_logp(st.policy, st.obs_stats, data, st.hyper.process)
        np.testing.assert_allclose(np.asarray(lp), np.asarray(data.logp), atol=5e-4, rtol=1e-4)
        return
    tr = ac.make(options.replace(cfg, chunk_steps=1, num_envs=16))
    ts, chunk = tr.init(jax.random.PRNGKey(1)), jax.jit(tr.chunk)
    xs, nxt = [], []
    for _ in range(120):
        ts, _ = chunk(ts)
        xs.append(np.asarray(ts.slots.ar.xi, np.float64))
        nxt.append(np.asarray(ts.slots.ar.i))
    xs, nxt = np.stack(xs), np.stack(nxt)
    pairs = nxt[:-1] != 0  # the step after continued the period
    prod = (xs[:-1] * xs[1:]).mean(axis=-1)
    if kind == "white":
        assert not pairs.any()
        assert abs(prod.mean()) < 0.05
    else:
        assert pairs.sum() > 500
        np.testing.assert_allclose(prod[pairs].mean(), np.exp(-dt / 0.1), atol=0.05)
