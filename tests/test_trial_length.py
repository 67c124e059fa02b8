"""Trial length held in seconds (``--trial-s``): the stop probability per control step is
control_dt / trial_s, so the mean trial lasts trial_s seconds at every control step."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from nmrl import cli, options
from nmrl.learners.ppo_config import PPOConfig
from nmrl.paper.env import EnvConfig, HalfCheetah
from nmrl.learners.ac_config import TrainConfig
from nmrl.runs import identity


@pytest.mark.parametrize("dt,steps", [(0.02, 100), (0.005, 400)])
def test_stops_per_second_are_the_same_at_every_control_step(dt, steps):
    trial_s, n_env = 0.5, 128
    env = HalfCheetah(EnvConfig(control_dt=dt, trial_s=trial_s, physics="c"))  # the stop rule is physics-free
    s = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(1), n_env))
    zero = jnp.zeros((n_env, 6))
    _, done = jax.jit(lambda s: jax.lax.scan(lambda s, _: (lambda n: (n, n.done))(jax.vmap(env.step)(s, zero)),
                                             s, None, length=steps))(s)
    stops = int(np.asarray(done).sum())
    # 2 simulated seconds per environment: Binomial(n_env * steps, dt / trial_s) stops
    lo, hi = stats.binom.interval(0.999, n_env * steps, dt / trial_s)
    assert lo <= stops <= hi, (stops, lo, hi)
    assert stops / (n_env * steps * dt) == pytest.approx(1 / trial_s, rel=0.15)


def test_trial_s_is_checked_and_recorded(tmp_path, capsys):
    for bad in ("0.01", "-1", "nan"):
        out = tmp_path / f"r{bad}"
        assert cli.main(["train", "--trial-s", bad, "--control-dt", "0.02", "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "trial_s" in err[0] and not out.exists()
    assert cli.main(["train", "--trial-s", "5", "--stop-prob", "0.01", "--out", str(tmp_path / "x")]) == 2
    assert "one of them" in capsys.readouterr().err
    assert "trial_s" not in identity.identity_config(TrainConfig())
    assert identity.identity_config(options.build(PPOConfig, trial_s=5.0))["trial_s"] == 5.0
    assert options.build(PPOConfig, trial_s=5.0, control_dt=0.005).environment.env_config().step_stop_prob == pytest.approx(0.001)
