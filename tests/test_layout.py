"""The sweep's layout (issue: the sweep at the speed of the machine) and its continuation states.

* points dealt over the devices in priority order, stepped one after another on each device;
* ``--first``: the named l values run to their budget before the other points start;
* the CLI uses every core by default (a subprocess without XLA_FLAGS sees 2 devices on this
  2-core machine) and says so on its first line; the 2-device sweep equals the 1-device sweep;
* a point continued from its compact state (parameters, counters, key; no traces or environment
  states) equals a run started from those parameters and counters, every environment in a new trial.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nmrl import cli, options
from nmrl.runs import checkpoint, devices, driver as run, store
from nmrl.experiments import sweep
from nmrl.learners.ac_config import TrainConfig
from nmrl.learners.ac_train import make_train

BASE = options.build(TrainConfig, num_envs=8, chunk_steps=25, steps=50, hidden_actor=8, hidden_critic=8,
                   beta_theta=1e-3, beta_v=1e-3)
FLOATS = ("avg_reward", "forward_speed", "td_mean", "td_std", "theta_norm", "v_norm")
INTS = ("step", "trials", "periods", "trials_in_chunk", "periods_in_chunk")


def _close(a, b, what=""):
    assert len(a) == len(b), what
    for ra, rb in zip(a, b):
        assert [ra[k] for k in INTS] == [rb[k] for k in INTS], what
        for k in FLOATS:
            np.testing.assert_allclose(ra[k], rb[k], rtol=1e-5, atol=1e-6, err_msg=f"{what} {k}")


def test_slot_order_deals_priority_round_robin():
    # 5 points on 2 devices, priority 3, 0, 4, 1, 2: device 0 gets ranks 0, 2, 4; device 1 ranks 1, 3
    assert sweep.slot_order(5, 2, [3, 0, 4, 1, 2]) == [3, 4, 2, 0, 1, -1]
    assert sweep.slot_order(4, 1) == [0, 1, 2, 3]
    assert sweep.slot_order(24, 2)[:12] == list(range(0, 24, 2))
    with pytest.raises(ValueError, match="permutation"):
        sweep.slot_order(3, 2, [0, 0, 1])


def test_first_stage_runs_before_the_others(tmp_path):
    spec = sweep.SweepSpec(ls=(1, 3), seeds=2, base=BASE, first=(3,))
    out = tmp_path / "staged"
    sweep.run_sweep(spec, out, progress=False, plot=False, max_chunks=2)
    rows = {(int(r["l"]), int(r["seed"])): int(r["steps"]) for r in sweep.load_results(out)}
    assert rows == {(1, 0): 0, (1, 1): 0, (3, 0): 50, (3, 1): 50}
    sweep.run_sweep(spec, out, resume=True, progress=False, plot=False)
    plain = tmp_path / "plain"
    sweep.run_sweep(dataclasses.replace(spec, first=()), plain, progress=False, plot=False)
    for l in (1, 3):
        for s in (0, 1):
            _close(run.read_metrics(sweep.point_dir(out, l, s)), run.read_metrics(sweep.point_dir(plain, l, s)),
                   (l, s))
    assert json.loads((out / "sweep.json").read_text())["first"] == [3]


def test_bad_first_and_devices(tmp_path, capsys):
    out = tmp_path / "bad"
    assert cli.main(["sweep", "--l", "1", "3", "--first", "2", "--out", str(out)]) == 2
    assert "first=[2]" in capsys.readouterr().err
    assert cli.main(["sweep", "--l", "1", "--devices", "0", "--out", str(out)]) == 2
    assert "--devices='0'" in capsys.readouterr().err
    assert cli.main(["train", "--devices", "two", "--out", str(out)]) == 2
    assert "--devices='two'" in capsys.readouterr().err
    assert not out.exists()
    assert devices.parse("auto") is None and devices.parse("3") == 3
    assert devices.requested(["sweep", "--devices=4"]) == "4"


@pytest.mark.slow  # two cold compiles (~2 min); by default test_sharding checks 2 devices == 1 and test_sweep each point == its run alone
def test_cli_uses_every_core_and_matches_one_device(tmp_path):
    """No XLA_FLAGS: the CLI itself exposes one host device per core (2 here) and says so first."""
    if devices.cpu_cores() < 2:
        pytest.skip("needs 2 cores")
    spec = sweep.SweepSpec(ls=(1, 3), seeds=1, base=BASE)
    one = tmp_path / "one"
    sweep.run_sweep(spec, one, progress=False, plot=False)
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "NMRL_DEVICES")}
    two = tmp_path / "two"
    p = subprocess.run([sys.executable, "-m", "nmrl.cli", "sweep", "--l", "1", "3", "--seeds", "1",
                        "--num-envs", "8", "--chunk-steps", "25", "--steps", "50", "--hidden-actor", "8",
                        "--hidden-critic", "8", "--beta-theta", "1e-3", "--beta-v", "1e-3", "--out", str(two)],
                       env=env, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    first = [ln for ln in p.stderr.splitlines() if ln.startswith("sweep:")][0]
    assert "on 2 cpu device(s), 1 point(s) per device" in first, first
    for l in (1, 3):
        _close(run.read_metrics(sweep.point_dir(one, l, 0)), run.read_metrics(sweep.point_dir(two, l, 0)), l)


def test_compact_state_continues_like_a_run_from_those_parameters(tmp_path):
    spec = sweep.SweepSpec(ls=(3,), seeds=1, base=BASE)
    out = tmp_path / "sw"
    sweep.run_sweep(spec, out, progress=False, plot=False, max_chunks=1)
    d = sweep.point_dir(out, 3, 0)
    cfg = checkpoint.load_config(d)
    trainer = make_train(cfg)
    full = checkpoint.restore(d, trainer)  # the state at step 25, read from the full checkpoint
    assert (d / "compact.npz").stat().st_size < 50_000
    # the published form: no full checkpoints
    shutil.rmtree(d / "checkpoints")
    sweep.run_sweep(spec, out, resume=True, progress=False, plot=False)
    cont = run.read_metrics(d)
    assert [r["step"] for r in cont] == [25, 50]
    # independently: a fresh start (init from the saved key's first half) carrying those parameters
    # and counters, traces zero, every environment at the reset state
    k_init, key = jax.random.split(full.key)
    ts = trainer.init(k_init).replace(theta=full.theta, v=full.v, key=key, step=full.step,
                                      trials=full.trials, periods=full.periods)
    assert all(float(jnp.abs(x).max()) == 0.0 for x in jax.tree.leaves(ts.slots.z))
    reset_qpos = np.asarray(trainer.env.reset(jax.random.PRNGKey(0)).data.qpos)
    np.testing.assert_array_equal(np.asarray(ts.slots.env.data.qpos), np.broadcast_to(reset_qpos, (8, reset_qpos.size)))
    ts, m = jax.jit(trainer.chunk)(ts)
    row = store.to_python(jax.device_get(m))
    _close([cont[1]], [row], "continued chunk")
    # and the compact resume's checkpoint holds the same parameters
    restored = checkpoint.restore(d, trainer)
    for a, b in zip(jax.tree.leaves(restored.theta), jax.tree.leaves(ts.theta)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-6)


def test_compact_state_refuses_corruption_and_other_configs(tmp_path):
    spec = sweep.SweepSpec(ls=(3,), seeds=1, base=BASE)
    out = tmp_path / "sw"
    sweep.run_sweep(spec, out, progress=False, plot=False, max_chunks=1)
    d = sweep.point_dir(out, 3, 0)
    other = make_train(dataclasses.replace(checkpoint.load_config(d), hidden_actor=9))
    with pytest.raises(checkpoint.CheckpointError, match="hidden_actor"):
        checkpoint.restore_compact(d, other)
    raw = bytearray((d / "compact.npz").read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    (d / "compact.npz").write_bytes(bytes(raw))
    with pytest.raises(checkpoint.CheckpointError, match="compact"):
        checkpoint.restore_compact(d, make_train(checkpoint.load_config(d)))


def test_sigterm_saves_every_active_point_and_exits_143(tmp_path):
    """SIGTERM during a sweep: the chunk in flight finishes, every active point is checkpointed
    (full and compact) at its newest metrics row, the exit status is 128 + 15, and --resume goes on."""
    import signal
    import time

    out = tmp_path / "sig"
    cmd = [sys.executable, "-m", "nmrl.cli", "sweep", "--l", "1", "3", "--seeds", "1", "--num-envs", "8",
           "--chunk-steps", "25", "--steps", "100000", "--hidden-actor", "8", "--hidden-critic", "8",
           "--beta-theta", "1e-3", "--beta-v", "1e-3", "--checkpoint-every", "1000", "--devices", "1",
           "--out", str(out)]
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    metrics = sweep.point_dir(out, 1, 0) / "metrics.jsonl"
    deadline = time.time() + 300
    while time.time() < deadline and not (metrics.exists() and metrics.read_text().count("\n") >= 2):
        time.sleep(0.2)
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=300)
    assert p.returncode == 143, err[-2000:]
    assert "every active point was saved" in err
    for l in (1, 3):
        d = sweep.point_dir(out, l, 0)
        last = run.read_metrics(d)[-1]["step"]
        assert checkpoint.latest_step(d) == last  # saved although --checkpoint-every 1000
        assert checkpoint.load_compact(d)[1]["step"] == last
    p = subprocess.run(cmd[:4] + ["--resume", "--steps", str(last + 25), "--devices", "1", "--out", str(out)],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
    assert run.read_metrics(sweep.point_dir(out, 1, 0))[-1]["step"] == last + 25


_POOL_PROBE = """
import sys
from nmrl.runs import devices
devices.configure(2)
import jax, jax.numpy as jnp, numpy as np
m = 9
a = np.random.default_rng(0).normal(size=(2, 4096, m, m)).astype(np.float32)
a = a @ a.transpose(0, 1, 3, 2) + m * np.eye(m, dtype=np.float32)

def f(x):
    body = lambda c: (c[0] + 1, c[1] + 1e-3 * jnp.linalg.cholesky(c[1]))
    return jax.lax.while_loop(lambda c: c[0] < 2, body, (0, x))[1]

print(len(jax.devices()), float(jax.pmap(f)(a).sum()))
"""


def test_two_devices_get_a_thread_pool_in_which_a_batched_lapack_kernel_finishes(monkeypatch):
    """jaxlib's batched Cholesky (MJX's Newton solver) splits a large batch into tasks on XLA's CPU
    pool and blocks until they finish; with one pool thread per device both devices block and the
    program never ends (4,096 9 x 9 matrices per device inside a loop, as in a 4,096-environment
    run). With the pool devices.configure sets, the same program finishes."""
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "PJRT_NPROC", "NPROC")}
    p = subprocess.run([sys.executable, "-c", _POOL_PROBE], env=env, capture_output=True, text=True,
                       timeout=120)
    assert p.returncode == 0, p.stderr[-2000:]
    n, total = p.stdout.split()
    assert n == "2" and np.isfinite(float(total))
    monkeypatch.delenv("PJRT_NPROC", raising=False)
    monkeypatch.delenv("NPROC", raising=False)
    if devices.cpu_cores() <= 2:
        assert devices.pool_threads(2) == 3
    assert devices.pool_threads(1) is None
