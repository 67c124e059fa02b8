"""Brax PPO's view of the v5 tasks (nmrl/adapters/brax_task.py through Brax's own training wrappers)
against the task itself (nmrl/tasks/env.py, checked against Gymnasium in tests/test_tasks.py), and the
baseline's ``--env`` (nmrl/experiments/baseline_ppo.py)."""

from __future__ import annotations

import json
import pathlib
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nmrl.tasks.env import Task, TaskConfig

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _native(name: str, key, actions: np.ndarray) -> dict:
    """A plain loop over the task without auto-reset: an ended episode (terminated or truncated)
    restarts from the state ``reset(key)`` made, as Brax's AutoResetWrapper restarts it."""
    env = Task(name, TaskConfig(physics="c", auto_reset=False))
    s0 = jax.tree.map(lambda x: x[0], jax.jit(jax.vmap(env.reset))(key[None]))  # as Brax's VmapWrapper does
    step = jax.jit(env.step)
    s, out = s0, {"obs": [], "reward": [], "done": [], "truncation": []}
    for a in actions:
        s = step(s, jnp.asarray(a))
        term, trunc = bool(s.info["terminated"]), bool(s.info["truncated"])
        out["reward"].append(float(s.reward))
        out["done"].append(float(term or trunc))
        out["truncation"].append(float(trunc and not term))
        if term or trunc:
            s = s0.replace(info={**s0.info, "key": s.info["key"]})
        out["obs"].append(np.asarray(s.obs))
    return {k: np.asarray(v) for k, v in out.items()}


@pytest.mark.parametrize("name,n", [("halfcheetah-v5", 1010), ("hopper-v5", 300)])
def test_brax_sees_the_task_step_for_step_with_its_time_limit_as_a_truncation(name, n):
    """Same reset state and actions: Brax's wrapped env (Vmap, Episode with the task's time limit,
    AutoReset) gives the task's observations and rewards bit for bit (MuJoCo C), ``done`` at every
    termination and at the time limit, and ``truncation`` exactly where the task is truncated and not
    terminated (HalfCheetah's step 1,000; Hopper's falls are terminations)."""
    pytest.importorskip("brax")
    from nmrl.adapters.brax_env import wrap_for_training
    from nmrl.adapters.brax_task import BraxTask

    key = jax.random.PRNGKey(3)
    actions = np.random.default_rng(0).uniform(-1, 1, (n, Task(name).act_dim)).astype(np.float32)
    want = _native(name, key, actions)
    benv = BraxTask(name, physics="c")
    env = wrap_for_training(benv, episode_length=benv.max_steps)
    state = jax.jit(env.reset)(key[None])

    def body(st, a):
        st = env.step(st, a[None])
        return st, {"obs": st.obs[0], "reward": st.reward[0], "done": st.done[0], "truncation": st.info["truncation"][0]}

    _, got = jax.jit(lambda st, a: jax.lax.scan(body, st, a))(state, jnp.asarray(actions))
    got = jax.device_get(got)
    np.testing.assert_array_equal(got["obs"], want["obs"])
    np.testing.assert_array_equal(got["reward"], want["reward"])
    np.testing.assert_array_equal(got["done"], want["done"])
    np.testing.assert_array_equal(got["truncation"], want["truncation"])
    assert want["done"].sum() >= 1
    if name == "halfcheetah-v5":
        assert np.flatnonzero(want["truncation"]).tolist() == [999]
    else:
        assert want["truncation"].sum() == 0 and want["done"].sum() >= 5


def _baseline(*args: str, cwd: pathlib.Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "nmrl.cli", "baseline", *args], cwd=cwd, capture_output=True,
                          text=True, env={**__import__("os").environ, "PYTHONPATH": str(ROOT) + ":" +
                                          __import__("os").environ.get("PYTHONPATH", "")})


def test_baseline_refuses_an_unknown_env_in_one_line_and_writes_nothing(tmp_path):
    r = _baseline("ppo", "--env", "ant-v5", "--out", str(tmp_path / "run"), cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    lines = [x for x in r.stderr.splitlines() if x.strip()]
    assert len(lines) == 1 and "'ant-v5'" in lines[0] and "halfcheetah-v5" in lines[0] and "walker2d-v5" in lines[0]
    assert not (tmp_path / "run").exists()


def test_a_task_config_has_the_tasks_own_step_and_time_limit_and_refuses_another_limit():
    from nmrl.experiments import baseline_config as bc

    for name, dt in (("halfcheetah-v5", 0.05), ("hopper-v5", 0.008), ("walker2d-v5", 0.008)):
        cfg = bc.task_config(name)
        task = Task(name)
        assert cfg.control_dt == task.control_dt == pytest.approx(dt)
        assert cfg.episode_cap == task.max_steps == 1000
        cfg.validate()
    finer = bc.task_config("halfcheetah-v5", control_dt=0.01)
    assert finer.episode_cap == Task("halfcheetah-v5", TaskConfig(control_dt=0.01)).max_steps == 5000
    with pytest.raises(ValueError, match="episode_cap=10000.*1000"):
        bc.BaselineConfig(env="hopper-v5", control_dt=0.008).validate()
    with pytest.raises(ValueError, match="stop_prob"):
        bc.task_config("hopper-v5", stop_prob=0.01).validate()


@pytest.mark.parametrize("path", sorted((ROOT / "results").glob("baseline_ppo/ppo_s*/config.json")))
def test_published_baseline_configs_load_and_are_stored_as_they_are(path):
    """A run made before ``env`` existed (the paper's robot) loads, and its config is stored with the
    same fields and values (the file a resume rewrites, and the checkpoints' config, are unchanged)."""
    from nmrl.experiments import baseline_config as bc

    cfg = bc.load_config(path.parent)
    assert cfg.env == "paper-cheetah"
    saved = json.loads(path.read_text())
    stored = bc.stored(cfg)
    assert "env" not in stored
    assert {k: v for k, v in stored.items() if k in saved} == saved
    assert set(stored) - set(saved) <= {"physics"}  # written by later versions, at the value of these runs


@pytest.mark.parametrize("path", sorted((ROOT / "results").glob("standard_tasks/brax/ppo_s*/config.json")))
def test_published_task_configs_load_and_are_stored_as_they_are(path):
    """The published Brax runs on a task load as valid configs of that task, and are stored field for
    field as the file holds them (a resume rewrites the same file)."""
    from nmrl.experiments import baseline_config as bc

    cfg = bc.load_config(path.parent)
    cfg.validate()
    assert cfg.is_task
    assert bc.stored(cfg) == json.loads(path.read_text())


@pytest.mark.slow
def test_a_brax_run_on_a_task_records_the_task_and_its_episode_returns_and_resumes(tmp_path):
    """A short Brax PPO run on Hopper (MuJoCo C): the config names the task, its 0.008 s step and its
    1,000-step limit; each row has the deterministic policy's 10-episode return, whose mean equals
    the mean of the episodes' returns it lists; a resume continues the same run."""
    pytest.importorskip("brax")
    from nmrl.experiments import baseline_brax as bb, baseline_config as bc, baseline_ppo as bp

    cfg = bc.task_config("hopper-v5", num_envs=4, batch_size=4, num_minibatches=2, unroll_length=5,
                         num_updates_per_batch=1, num_timesteps=80, policy_hidden=(8,), value_hidden=(8,),
                         physics="c")
    out = tmp_path / "run"
    rows = bp.run(cfg, out, progress=False, max_iterations=1)
    saved = json.loads((out / "config.json").read_text())
    assert saved["env"] == "hopper-v5" and saved["control_dt"] == 0.008 and saved["episode_cap"] == 1000
    assert [r["step"] for r in rows] == [0, 40]
    for r in rows:
        assert np.isfinite(r["eval_return"]) and 1 <= r["eval_length_mean"] <= 1000 and "eval_avg_reward" not in r
    ev = bb.evaluate_params(cfg, bb.initial_params(cfg))
    assert ev["return"]["mean"] == pytest.approx(np.mean(ev["return"]["each"]))
    assert ev["terminated"] == sum(1 for n in ev["length"] if n < 1000)
    more = bp.run(bc.load_config(out), out, resume=True, progress=False)
    assert [r["step"] for r in more] == [80]
    assert json.loads((out / "config.json").read_text()) == saved
