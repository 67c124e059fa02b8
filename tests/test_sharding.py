"""A training run split over two CPU devices equals the 1-device run (up to float rounding)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np

from nmrl import options
from nmrl.runs import driver as run
from nmrl.learners.ac_config import TrainConfig

CFG = options.build(TrainConfig, num_envs=8, chunk_steps=20, steps=40, hidden_actor=8, hidden_critic=8,
                  beta_theta=1e-3, beta_v=1e-3, l=3)
KEYS = ("avg_reward", "theta_norm", "v_norm", "td_mean", "forward_speed")


def test_two_devices_match_one(tmp_path):
    one = run.train(CFG, tmp_path / "one", progress=False)
    code = (
        "import json, sys; from nmrl.runs import driver as run; from nmrl.learners.ac_config import TrainConfig; import jax;"
        "assert len(jax.devices()) == 2, jax.devices();"
        f"from nmrl import options; rows = run.train(options.build(TrainConfig, **json.loads(sys.argv[1])), sys.argv[2], progress=False);"
        "print(json.dumps(rows))"
    )
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2", "JAX_PLATFORMS": "cpu"}
    p = subprocess.run([sys.executable, "-c", code, json.dumps(options.flat(CFG)), str(tmp_path / "two")],
                       env=env, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    two = json.loads(p.stdout.strip().splitlines()[-1])
    assert len(one) == len(two) == 2
    for a, b in zip(one, two):
        assert (a["step"], a["trials"], a["periods"]) == (b["step"], b["trials"], b["periods"])
        for k in KEYS:
            np.testing.assert_allclose(a[k], b[k], rtol=1e-4, atol=1e-5, err_msg=k)
