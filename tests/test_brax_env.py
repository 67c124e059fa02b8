"""The paper's Half-Cheetah behind Brax's Env interface (nmrl.adapters.brax_env), and the PPO baseline.

Without Brax (the default install, CI) the adapter's contract is checked against the paper's
environment itself; with Brax (``pip install -e '.[brax]'``) Brax's own training wrappers run over
it, and a tiny Brax PPO run trains, checkpoints, resumes and evaluates through nmrl's run store.
"""

from __future__ import annotations

import dataclasses
import json
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nmrl.adapters import brax_env
from nmrl.paper.env import EnvConfig, HalfCheetah

needs_brax = pytest.mark.skipif(not brax_env.HAVE_BRAX, reason="Brax is optional: pip install -e '.[brax]'")


def _actions(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1.2, 1.2, size=(n, 6)).astype(np.float32)


@pytest.fixture(scope="module")
def pair():
    cfg = EnvConfig(stop_prob=0.05)
    return brax_env.BraxHalfCheetah(cfg), HalfCheetah(dataclasses.replace(cfg, auto_reset=False))


def test_adapter_is_the_papers_env_with_scaled_actions(pair):
    """Brax's interface sizes; every step equals the paper's env stepped with a = 20 clip(u, -1, 1):
    the same observation (Table I), reward (8)-(14), reward terms and stop draws."""
    env, paper = pair
    assert (env.observation_size, env.action_size, env.backend, env.dt) == (31, 6, "mjx", 0.02)
    assert env.unwrapped is env
    key = jax.random.PRNGKey(3)
    s, p = jax.jit(env.reset)(key), jax.jit(paper.reset)(key)
    np.testing.assert_array_equal(s.obs, p.obs)
    step_b, step_p = jax.jit(env.step), jax.jit(paper.step)
    stops = 0
    for u in _actions(40):
        s = step_b(s, jnp.asarray(u))
        p = step_p(p, jnp.asarray(20.0 * np.clip(u, -1, 1)))
        np.testing.assert_array_equal(s.obs, p.obs)
        assert float(s.reward) == float(p.reward)
        for k, v in p.metrics.items():
            assert float(s.metrics[k]) == float(v), k
        assert float(s.metrics["reward_per_step"]) == float(p.reward)
        assert float(s.done) == float(p.done) == float(s.info["stop"])  # finite physics: a stop is the stop rule
        stops += int(p.done)
    assert stops > 0  # stop_prob 0.05 over 40 steps: P(no stop) = 0.13 for a fixed key; this key stops


def test_stop_rule_frequency_monte_carlo():
    """The trial stops after a step with probability stop_prob (Sec. V-C): 8 x 500 draws at 1/250."""
    env = brax_env.BraxHalfCheetah()
    keys = jax.random.split(jax.random.PRNGKey(0), 8)
    s = jax.vmap(env.reset)(keys)

    def body(s, _):
        s = jax.vmap(env.step)(s, jnp.zeros((8, 6)))
        return s, s.info["stop"]

    _, stops = jax.jit(lambda s: jax.lax.scan(body, s, None, length=500))(s)
    n = stops.size
    k = float(stops.sum())
    mean, sd = n / 250, np.sqrt(n * (1 / 250) * (1 - 1 / 250))
    assert abs(k - mean) < 4 * sd, (k, mean, sd)


def test_no_reset_inside_the_adapter():
    """auto-reset is left to the wrappers: after a stop the adapter keeps stepping the same trial."""
    env = brax_env.BraxHalfCheetah(EnvConfig(stop_prob=0.999))
    s = env.reset(jax.random.PRNGKey(0))
    s1 = jax.jit(env.step)(s, jnp.ones(6))
    assert float(s1.done) == 1.0
    assert not np.array_equal(np.asarray(s1.obs), np.asarray(s.obs))  # not put back to the initial pose
    assert int(s1.pipeline_state.time * 1000) == 20


@needs_brax
def test_brax_training_wrappers_auto_reset_and_truncation():
    """Brax's Vmap/Episode/AutoReset wrappers over the adapter: after a stop the next observation is
    the initial one (Brax's reset), the stop is a truncation (not a termination) for the trainers,
    and the episode metric reward_per_step summed by Brax's EpisodeWrapper is the trial's reward sum."""
    env = brax_env.BraxHalfCheetah(EnvConfig(stop_prob=0.05))
    w = brax_env.wrap_for_training(env, episode_length=1000)
    n = 4
    s = jax.jit(w.reset)(jax.random.split(jax.random.PRNGKey(1), n))
    obs0 = np.asarray(s.obs)
    step = jax.jit(w.step)
    sums = np.zeros(n)
    seen = 0
    for u in _actions(80, seed=1).reshape(80, 1, 6).repeat(n, axis=1):
        prev_done = np.asarray(s.done).astype(bool)
        s = step(s, jnp.asarray(u))
        r = np.asarray(s.reward)
        done = np.asarray(s.done).astype(bool)
        sums = np.where(prev_done, 0.0, sums) + r
        np.testing.assert_array_equal(np.asarray(s.info["truncation"]), done.astype(np.float32))
        np.testing.assert_array_equal(np.asarray(s.info["time_out"]), done.astype(np.float32))
        if done.any():
            seen += int(done.sum())
            np.testing.assert_array_equal(np.asarray(s.obs)[done], obs0[done])  # reset by AutoResetWrapper
            ep = s.info["episode_metrics"]
            np.testing.assert_allclose(np.asarray(ep["reward_per_step"])[done], sums[done], rtol=1e-5, atol=1e-4)
            np.testing.assert_allclose(np.asarray(ep["sum_reward"])[done], sums[done], rtol=1e-5, atol=1e-4)
    assert seen >= 5


@needs_brax
def test_tally_reports_every_reward_of_the_learning():
    """brax_env.Tally's sink receives, every ``every`` steps, the sums of exactly the rewards, speeds
    and stops the wrapped batch produced (compared with the states' own values, step by step)."""
    got = []
    env = brax_env.BraxHalfCheetah(EnvConfig(stop_prob=0.05))
    w = brax_env.wrap_for_training(env, episode_length=1000, tally=lambda *a: got.append(np.array(a, float)),
                                   tally_every=10)
    n = 4
    s = jax.jit(w.reset)(jax.random.split(jax.random.PRNGKey(2), n))
    step = jax.jit(w.step)
    want = np.zeros(4)
    for u in _actions(30, seed=2).reshape(30, 1, 6).repeat(n, axis=1):
        s = step(s, jnp.asarray(u))
        want += [float(np.sum(s.reward)), float(np.sum(s.metrics["forward_speed"])), float(np.sum(s.done)), n]
    jax.effects_barrier()
    assert len(got) == 3
    np.testing.assert_allclose(np.sum(got, axis=0), want, rtol=1e-5)
    assert [g[3] for g in got] == [40, 40, 40]


@needs_brax
def test_ppo_baseline_trains_checkpoints_resumes_and_evaluates(tmp_path, capsys):
    """A tiny Brax PPO run through ``nmrl baseline``: rows per iteration, a checkpoint each, the
    resume continues from the newest step (a changed config is refused by name), evaluation reads it."""
    from nmrl import cli
    from nmrl.experiments import baseline_brax as bb, baseline_config as bc, baseline_ppo as bp
    from nmrl.runs import checkpoint, store

    out = tmp_path / "ppo"
    tiny = ["--num-envs", "4", "--batch-size", "4", "--num-minibatches", "2", "--unroll-length", "5", "--quiet"]
    # the tiny networks are not a CLI option: run the first call through the API, then the CLI resumes it
    cfg = bc.BaselineConfig(num_timesteps=4 * 2 * 5 * 3, num_envs=4, batch_size=4, num_minibatches=2,
                            unroll_length=5, num_updates_per_batch=1, policy_hidden=(4,), value_hidden=(4,),
                            eval_seconds=0.2)
    rows = bp.run(cfg, out, progress=False, max_iterations=2)
    assert [r["step"] for r in rows] == [0, 40, 80]
    assert checkpoint.all_steps(out)[-1] == 80
    assert all(np.isfinite(r["eval_avg_reward"]) for r in rows)
    assert [r["train_steps_tallied"] for r in rows] == [0, 40, 40]  # exactly each iteration's steps
    assert all(np.isfinite(r["train_reward_per_step"]) for r in rows[1:])
    assert cli.main(["baseline", "ppo", "--out", str(out), "--resume", "--num-envs", "8", *tiny[2:]]) == 2
    assert "num_envs: run 4 vs given 8" in capsys.readouterr().err
    # a fresh clone of the published run: no checkpoints/, only the committed files (compact.npz)
    clone = tmp_path / "clone"
    clone.mkdir()
    for name in (store.CONFIG_FILE, store.METRICS_FILE, store.COMPACT_FILE):
        shutil.copy(out / name, clone / name)
    assert cli.main(["baseline", "ppo", "--out", str(out), "--resume", "--quiet"]) == 0
    assert cli.main(["baseline", "ppo", "--out", str(clone), "--resume", "--quiet"]) == 0
    # the compact state holds the newest checkpoint's arrays, so the clone continues exactly as the run
    keep = ("step", "train_reward_per_step", "trials_ended", "eval_avg_reward", "eval_forward_speed")
    assert ([{k: r[k] for k in keep} for r in store.read_metrics(clone)]
            == [{k: r[k] for k in keep} for r in store.read_metrics(out)])
    steps = [r["step"] for r in store.read_metrics(out)]
    assert steps == [0, 40, 80, 120]
    (resume,) = store.read_jsonl(out / store.RESUMES_FILE)
    assert resume["from_step"] == 80
    # a finished run: --resume has nothing to do and writes nothing (no resume record, same rows)
    rows_before = (out / store.METRICS_FILE).read_bytes()
    assert cli.main(["baseline", "ppo", "--out", str(out), "--resume", "--quiet"]) == 0
    assert len(store.read_jsonl(out / store.RESUMES_FILE)) == 1
    assert (out / store.METRICS_FILE).read_bytes() == rows_before
    # a finished seed is published without parameters (config, metrics, resumes): on a fresh clone
    # its --resume is the same no-op; asked for more steps, it names what is missing and why
    done = tmp_path / "published_finished"
    done.mkdir()
    for name in (store.CONFIG_FILE, store.METRICS_FILE, store.RESUMES_FILE):
        shutil.copy(out / name, done / name)
    published = {f.name: f.read_bytes() for f in done.iterdir()}
    assert cli.main(["baseline", "ppo", "--out", str(done), "--resume", "--quiet"]) == 0
    assert {f.name: f.read_bytes() for f in done.iterdir()} == published
    assert cli.main(["baseline", "ppo", "--out", str(done), "--resume", "--quiet", "--num-timesteps", "160"]) == 2
    err = capsys.readouterr().err
    assert "no checkpoint (or compact.npz)" in err and "reach 120 control steps" in err and "160" in err
    assert {f.name: f.read_bytes() for f in done.iterdir()} == published
    assert cli.main(["baseline", "eval", str(done), "--no-render", "--out", str(tmp_path / "ev0")]) == 2
    assert "no parameters to evaluate" in capsys.readouterr().err
    assert cli.main(["baseline", "eval", str(out), "--seconds", "0.5", "--no-render", "--out", str(tmp_path / "ev")]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["step"] == 120 and np.isfinite(res["deterministic"]["avg_reward"])
    # the published form (compact.npz, no checkpoints/) evaluates the same policy
    shutil.rmtree(clone / "checkpoints")
    assert cli.main(["baseline", "eval", str(clone), "--seconds", "0.5", "--no-render", "--out", str(tmp_path / "ev2")]) == 0
    res2 = json.loads(capsys.readouterr().out)
    assert res2["step"] == 120 and res2["deterministic"] == res["deterministic"]
    assert cli.main(["baseline", "eval", str(clone), "--step", "80", "--no-render", "--out", str(tmp_path / "ev3")]) == 2
    assert "not 80" in capsys.readouterr().err
    # the evaluation is the saved policy's: the same rollout from the restored parameters
    meta, params = checkpoint.restore_tree(out, bb.initial_params(cfg))
    again = bb.evaluate_params(cfg, params, seconds=0.5)
    assert again["avg_reward"] == res["deterministic"]["avg_reward"]
    assert cli.main(["baseline", "ppo", "--out", str(out), "--num-envs", "4"]) == 2  # a fresh run over a run
    assert "already holds a run" in capsys.readouterr().err


def test_ppo_config_errors_name_the_value():
    from nmrl.experiments import baseline_config as bc

    with pytest.raises(ValueError, match="num_envs=7"):
        bc.BaselineConfig(num_envs=7).validate()
    with pytest.raises(ValueError, match="discounting=1.5"):
        bc.BaselineConfig(discounting=1.5).validate()
    with pytest.raises(ValueError, match="policy_hidden"):
        bc.BaselineConfig(policy_hidden=()).validate()
    with pytest.raises(ValueError, match="multiple of the 2 device"):
        bc.BaselineConfig(num_envs=1, batch_size=1, num_minibatches=1).validate(n_devices=2)
    cfg = bc.BaselineConfig()
    assert cfg.steps_per_iteration == 512 * 32 * 20 and cfg.iterations == 77  # 77 x 327,680 >= 2.5e7


@needs_brax
@pytest.mark.slow
def test_sigterm_stops_the_baseline_after_its_iterations_save(tmp_path):
    """``nmrl baseline ppo`` under the command's signal guard: a SIGTERM during training stops the run
    after the iteration in flight is saved (exit 143, "continue with --resume"), every metrics row
    has its checkpoint, and --resume continues from the newest one."""
    import os
    import signal
    import subprocess
    import sys
    import time

    from nmrl.runs import checkpoint, store

    out = tmp_path / "ppo"
    argv = [sys.executable, "-m", "nmrl.cli", "baseline", "ppo", "--out", str(out), "--num-envs", "4",
            "--batch-size", "4", "--num-minibatches", "2", "--unroll-length", "5", "--num-timesteps", "400000",
            "--policy-hidden", "4", "--value-hidden", "4", "--quiet"]
    p = subprocess.Popen(argv, stderr=subprocess.PIPE, text=True, env=dict(os.environ))
    t_end = time.time() + 600
    while time.time() < t_end and len(store.read_metrics(out) if (out / store.METRICS_FILE).exists() else []) < 2:
        assert p.poll() is None, p.communicate()[1]
        time.sleep(0.2)
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=300)
    assert p.returncode == 143, err
    assert "continue with --resume" in err
    rows = store.read_metrics(out)
    assert checkpoint.all_steps(out)[-1] == rows[-1]["step"] < 400000
    r = subprocess.run([*argv[:7], "--resume", "--max-iterations", "1", "--quiet"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert store.read_metrics(out)[-1]["step"] > rows[-1]["step"]
