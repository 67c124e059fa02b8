"""The Python front door (nmrl/runs/api.py): ``import nmrl`` loads no JAX; ``nmrl.config`` refuses
what the command line refuses; ``nmrl.train`` writes the run ``nmrl train`` writes for the same
options (the same identity: its ``--resume`` continues it); ``nmrl.make_train``'s first chunk is
that run's first metrics row."""

from __future__ import annotations

import json
import subprocess
import sys

import jax
import numpy as np
import pytest

import nmrl
from nmrl.runs import store

FIELDS = dict(preset="fast_clip", num_envs=4, steps=100, chunk_steps=50, l=5, physics="c")


def test_import_nmrl_loads_no_jax():
    code = "import sys, nmrl; assert 'jax' not in sys.modules, 'jax'; print(sorted(nmrl.__all__))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "['config', 'make_train', 'train']"


@pytest.mark.parametrize("fields, error", [(dict(num_envs=0), ValueError), (dict(l=0), ValueError),
                                           (dict(physics="gpu"), ValueError), (dict(no_such_field=1), TypeError)])
def test_config_refuses_bad_fields(fields, error):
    with pytest.raises(error) as e:
        nmrl.config("ac", **fields)
    name = next(iter(fields))
    assert name in str(e.value)


def test_train_writes_the_run_of_the_command_line(tmp_path):
    cfg = nmrl.config("ac", **FIELDS)
    rows = nmrl.train(cfg, tmp_path / "api", progress=False)
    assert [r["step"] for r in rows] == [50, 100]
    cli = [sys.executable, "-m", "nmrl", "train", "--preset", "fast_clip", "--num-envs", "4", "--steps", "100",
           "--chunk-steps", "50", "--l", "5", "--physics", "c", "--out", str(tmp_path / "cli")]
    out = subprocess.run(cli, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    api_cfg = json.loads((tmp_path / "api" / store.CONFIG_FILE).read_text())
    cli_cfg = json.loads((tmp_path / "cli" / store.CONFIG_FILE).read_text())
    assert api_cfg == cli_cfg
    cli_rows = [json.loads(l) for l in (tmp_path / "cli" / "metrics.jsonl").read_text().splitlines()]
    # the same run, up to float rounding where the two processes split the environments over devices
    np.testing.assert_allclose([r["avg_reward"] for r in cli_rows], [r["avg_reward"] for r in rows], rtol=1e-5)
    trainer = nmrl.make_train(cfg)
    ts = jax.jit(trainer.init)(jax.random.PRNGKey(cfg.budget.seed))
    _, m = jax.jit(trainer.chunk)(ts)
    np.testing.assert_allclose(float(m["avg_reward"]), rows[0]["avg_reward"], rtol=1e-6)


def test_python_m_nmrl_exits_with_the_commands_status(tmp_path):
    out = subprocess.run([sys.executable, "-m", "nmrl", "train", "--physics", "gpu", "--out", str(tmp_path / "r")],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 2 and out.stderr.strip().splitlines() == [
        "nmrl: error: physics='gpu' is invalid: choose one of mjx, c"] and not (tmp_path / "r").exists()
