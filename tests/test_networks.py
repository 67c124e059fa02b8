"""The perceptrons' arctan (nmrl/paper/networks.py) against NumPy's float64 arctan, and which one a
run uses: new runs the fast one, runs saved before the choice existed XLA's."""
from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nmrl import learners
from nmrl.learners.ac_config import TrainConfig
from nmrl.paper import networks


def _ulps(got: np.ndarray, x: np.ndarray) -> np.ndarray:
    exact = np.arctan(x.astype(np.float64))
    return np.abs(got.astype(np.float64) - exact) / np.spacing(np.abs(exact).astype(np.float32)).astype(np.float64)


def _grid() -> np.ndarray:
    """Dense around 0 and both range-reduction points (tan(pi/8), tan(3pi/8)), logarithmic out to 1e30."""
    lin = np.linspace(-6, 6, 1_200_001)
    edges = np.concatenate([b + np.linspace(-1e-4, 1e-4, 20_001) for b in (0.41421356, 2.41421356)])
    logs = np.logspace(-30, 30, 60_001)
    x = np.concatenate([lin, edges, -edges, logs, -logs]).astype(np.float32)
    return x


def test_the_fast_arctan_is_within_3_ulp_of_the_exact_arctan_everywhere():
    x = _grid()
    fast = np.asarray(jax.jit(networks.arctan_fast)(x))
    assert _ulps(fast, x).max() <= 3.0
    assert np.array_equal(fast, -np.asarray(jax.jit(networks.arctan_fast)(-x)))  # odd
    ends = np.asarray(networks.arctan_fast(jnp.array([np.inf, -np.inf, 0.0], jnp.float32)))
    assert np.array_equal(ends, np.float32([np.pi / 2, -np.pi / 2, 0.0]))
    assert np.isnan(np.asarray(networks.arctan_fast(jnp.float32(np.nan))))


def test_the_fast_arctan_is_at_least_as_accurate_as_xlas():
    x = _grid()
    fast, xla = (np.asarray(jax.jit(f)(x)) for f in (networks.arctan_fast, jnp.arctan))
    assert _ulps(fast, x).max() <= _ulps(xla, x).max()


def test_the_fast_arctans_derivative_is_one_over_one_plus_x_squared():
    x = np.linspace(-20, 20, 4001).astype(np.float32)
    d = np.asarray(jax.vmap(jax.grad(networks.arctan_fast))(x))
    np.testing.assert_allclose(d, 1 / (1 + x.astype(np.float64) ** 2), rtol=2e-7, atol=0)


@pytest.mark.parametrize("arctan", ["fast", "xla"])
def test_the_perceptron_is_w2_arctan_w1_s_plus_b1_plus_b2(arctan):
    net = networks.Perceptron(hidden=7, out=3, arctan=arctan)
    params = net.init(jax.random.PRNGKey(0), jnp.zeros(5))
    params = jax.tree.map(lambda p: jax.random.normal(jax.random.PRNGKey(1), p.shape), params)
    s = np.asarray(jax.random.normal(jax.random.PRNGKey(2), (5,)), np.float64)
    p = jax.tree.map(lambda a: np.asarray(a, np.float64), params["params"])
    want = np.arctan(s @ p["hidden"]["kernel"] + p["hidden"]["bias"]) @ p["output"]["kernel"] + p["output"]["bias"]
    np.testing.assert_allclose(np.asarray(net.apply(params, jnp.asarray(s, jnp.float32))), want, rtol=1e-5, atol=1e-5)


def test_a_new_run_uses_the_fast_arctan_and_a_run_saved_before_the_choice_xlas(tmp_path):
    assert TrainConfig().arctan == "fast"
    saved = learners.config_dict(TrainConfig().resolved())
    del saved["arctan"]
    assert learners.config_from_dict(saved).arctan == "xla"
    from nmrl.runs import identity

    (tmp_path / "config.json").write_text(json.dumps(saved))
    old = identity.load_run_config(tmp_path)
    assert old.arctan == "xla" and "arctan" not in identity.identity_config(old)
    assert identity.identity_config(TrainConfig())["arctan"] == "fast"
