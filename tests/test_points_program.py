"""The points' layout (nmrl/runs/points.py ``points_program``): every point's chunk as if run alone,
in any group size (a group larger than the points vmaps them all), inactive points unchanged."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nmrl.runs import points


def _chunk(traces):
    def chunk(t):
        traces.append(1)
        x = t["x"]
        return {"x": jnp.tanh(x) * 2.0 + x.sum()}, {"m": (x * x).sum()}
    return chunk


@pytest.mark.parametrize("group", [1, 2, 4, 8])
def test_each_point_is_its_chunk_alone_and_inactive_points_stay(group):
    xs = np.random.default_rng(0).normal(size=(4, 3)).astype(np.float32)
    active = jnp.array([True, False, True, True])
    prog = jax.jit(points.points_program(_chunk([]), 1, group))
    out, m = prog({"x": jnp.asarray(xs)}, active)
    for i, x in enumerate(xs):
        want = np.tanh(x) * 2.0 + x.sum() if active[i] else x
        np.testing.assert_allclose(np.asarray(out["x"][i]), want, rtol=1e-6)
        assert float(m["m"][i]) == pytest.approx(float((x * x).sum()) if active[i] else 0.0, rel=1e-6)


def test_a_group_must_be_a_positive_integer():
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="group="):
            points.points_program(_chunk([]), 1, bad)
