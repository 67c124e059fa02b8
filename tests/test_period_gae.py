"""Period-wise GAE and segment sums (nmrl/learners/ppo_losses.py) against a direct computation:
each period as one transition, its advantage the lambda-return written out with Python loops."""

from __future__ import annotations

import numpy as np
import pytest

from nmrl import options
from nmrl.learners import ppo_losses as L


def _segments(start):
    s = list(np.flatnonzero(start)) if start[0] else [0] + list(np.flatnonzero(start))
    return [(a, b) for a, b in zip(s, s[1:] + [len(start)])]


def _direct(r, v, boot, term, trunc, start, gamma, lam):
    """The period-level GAE from its definition, one environment, loops only."""
    segs = _segments(start)
    P = len(segs)
    R = [sum(gamma ** (k - a) * r[k] for k in range(a, b)) for a, b in segs]
    n = [b - a for a, b in segs]
    V = [v[a] for a, _ in segs] + [boot]
    c = [1 - term[b - 1] for _, b in segs]
    m = [1 - trunc[b - 1] for _, b in segs]
    delta = [m[p] * (R[p] + gamma ** n[p] * c[p] * V[p + 1] - V[p]) for p in range(P)]
    A = [0.0] * (P + 1)
    for p in reversed(range(P)):
        A[p] = delta[p] + (gamma * lam) ** n[p] * c[p] * m[p] * A[p + 1]
    adv = np.zeros(len(r))
    vs = np.zeros(len(r))
    VS = [A[p] + V[p] for p in range(P)] + [boot]
    for p, (a, _) in enumerate(segs):
        adv[a] = m[p] * (R[p] + gamma ** n[p] * c[p] * VS[p + 1] - V[p])
        vs[a] = VS[p]
    return vs, adv


def test_period_gae_with_one_step_periods_is_gae():
    rng = np.random.default_rng(7)
    T, B = 9, 4
    r, v, boot = rng.normal(size=(T, B)), rng.normal(size=(T, B)), rng.normal(size=B)
    term = (rng.random((T, B)) < 0.1).astype(float)
    trunc = (rng.random((T, B)) < 0.1).astype(float) * (1 - term)
    args = [np.asarray(x, np.float32) for x in (r, v, boot, term, trunc)]
    a = L.period_gae(*args, np.ones((T, B), np.float32), 0.95, 0.9)
    b = L.gae(*args, 0.95, 0.9)
    for x, y in zip(a, b):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("seed", range(6))
def test_period_gae_equals_the_direct_computation(seed):
    rng = np.random.default_rng(seed)
    T, B = 17, 5
    r, v = rng.normal(size=(T, B)), rng.normal(size=(T, B))
    boot = rng.normal(size=B)
    start = (rng.random((T, B)) < 0.3).astype(np.float32)
    term = np.zeros((T, B))
    trunc = np.zeros((T, B))
    for b in range(B):  # a stop ends a period: the step after it starts one
        for t in np.flatnonzero(start[:, b])[1:]:
            u = rng.random()
            if u < 0.2:
                term[t - 1, b] = 1
            elif u < 0.4:
                trunc[t - 1, b] = 1
    gamma, lam = 0.97, 0.9
    vs, adv = L.period_gae(*(np.asarray(x, np.float32) for x in (r, v, boot, term, trunc, start)), gamma, lam)
    for b in range(B):
        vs_d, adv_d = _direct(r[:, b], v[:, b], boot[b], term[:, b], trunc[:, b], start[:, b], gamma, lam)
        np.testing.assert_allclose(np.asarray(adv)[:, b], adv_d, rtol=1e-4, atol=1e-4)
        np.testing.assert_allclose(np.asarray(vs)[:, b], vs_d, rtol=1e-4, atol=1e-4)


def test_segment_sums_are_the_sums_over_each_period():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(12, 3)).astype(np.float32)
    start = (rng.random((12, 3)) < 0.35).astype(np.float32)
    got = np.asarray(L.segment_sums(x, start))
    for b in range(3):
        want = np.zeros(12)
        for a, e in _segments(start[:, b]):
            want[a] = x[a:e, b].sum()
        np.testing.assert_allclose(got[:, b], want, rtol=1e-5, atol=1e-5)


def test_period_wise_ppo_with_one_step_periods_is_the_per_step_ppo():
    """With periods of one control step every step starts a period: the period-wise loss is then the
    per-step PPO's term by term, so one iteration gives the same parameters (up to float rounding,
    which Adam's normalised steps carry to ~1e-5 after 4 updates: the losses sum in another order)."""
    import dataclasses

    import jax

    from nmrl.learners.ppo import make_ppo
    from nmrl.learners.ppo_config import PPOConfig

    cfg = options.build(PPOConfig, exploration="nm-periods", period_s=0.02, corr_time_s=0.0896, num_envs=4, batch_size=4,
                    num_minibatches=2, epochs=2, value_layers=1, value_width=8, policy_layers=1, policy_width=8,
                    unroll_s=0.1, physics="c")
    out = []
    for pw in (False, True):
        tr = make_ppo(dataclasses.replace(cfg, period_wise=pw))
        st, m = jax.jit(tr.chunk)(tr.init(jax.random.PRNGKey(0)))
        out.append((st, m))
    (a, ma), (b, mb) = out
    for x, y in zip(jax.tree.leaves((a.policy, a.value)), jax.tree.leaves((b.policy, b.value))):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-4, atol=3e-5)
    assert float(ma["clip_frac"]) == pytest.approx(float(mb["clip_frac"]), abs=1e-6)


def test_period_wise_ppo_learns_on_longer_periods_and_is_refused_without_periods():
    import jax

    from nmrl.learners.ppo import make_ppo
    from nmrl.learners.ppo_config import PPOConfig

    cfg = options.build(PPOConfig, exploration="nm-periods", period_s=0.1, num_envs=4, batch_size=4, num_minibatches=1,
                    epochs=1, value_layers=1, value_width=8, policy_layers=1, policy_width=8, period_wise=True,
                    physics="c")
    tr = make_ppo(cfg)
    st0 = tr.init(jax.random.PRNGKey(0))
    st, m = jax.jit(tr.chunk)(st0)
    assert np.isfinite(float(m["policy_loss"])) and not bool(st.diverged)
    assert not np.allclose(np.asarray(jax.tree.leaves(st.policy)[0]), np.asarray(jax.tree.leaves(st0.policy)[0]))
    with pytest.raises(ValueError, match="period_wise"):
        options.build(PPOConfig, exploration="white", period_wise=True).validate()
