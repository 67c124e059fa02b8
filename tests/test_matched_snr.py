"""The gradient's SNR at matched policies: the period-wise gradient estimate against a dense-Gaussian
computation (nmrl/experiments/ppo_gradsnr.py), the matched states against the compact files
(nmrl/experiments/matched_snr.py), and the study's measurement step and its summary
(nmrl/experiments/exploration2.py, its report in exploration2_analysis.py)."""

from __future__ import annotations

import csv
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.flatten_util import ravel_pytree

from nmrl import options
from nmrl.experiments import exploration2, exploration2_analysis, exploration2_cells, matched_snr, ppo_gradsnr
from nmrl.learners import ppo, ppo_config
from nmrl.learners import ppo_losses as L
from nmrl.learners import ppo_networks as nn_
from nmrl.runs import compact
from tests.test_explore import dense_cov
from tests.test_ppo import TINY
from tests.tiny_env import TinyEnv

PERIODIC = dict(TINY, num_envs=2, batch_size=4, unroll_s=0.12, exploration="nm-periods", sigma=0.8, period_s=0.06,
                corr_time_s=0.0896, period_wise=True)  # T = 6 steps, periods of 3


def test_the_period_wise_gradient_estimate_is_the_periods_dense_density_times_their_advantage():
    """g_e = grad (1/UT) sum_p A_p log pi(period p), the period's density from the dense covariance
    (5) of its noise (no filter) and the change of variables, against make_batch's sums."""
    cfg = options.build(ppo_config.PPOConfig, **PERIODIC).resolved()
    env = TinyEnv(stop_prob=0.0)  # no trial resets: every unroll starts a period (6 = 2 periods)
    tr = ppo.make_ppo(cfg, env)
    st = tr.init(jax.random.PRNGKey(3))
    st = st.replace(obs_stats=st.obs_stats._replace(mean=st.obs_stats.mean + 0.2))
    key = jax.random.PRNGKey(11)
    _, (n, g_sum, g_sq) = jax.jit(ppo_gradsnr.make_batch(cfg, env))(st, key)
    (_, _, _), data = jax.jit(tr.rollout)(st, key)
    N, U, T = data.reward.shape
    assert np.array_equal(np.asarray(data.fresh), np.broadcast_to([1, 0, 0, 1, 0, 0], (N, U, T)).astype(bool))
    h = st.hyper
    obs_n = nn_.normalize(st.obs_stats, data.obs)
    v = nn_.value(tr.nets, st.value, obs_n)
    boot = nn_.value(tr.nets, st.value, nn_.normalize(st.obs_stats, data.next_obs))
    start = np.zeros((T, U), np.float32)
    start[[0, 3]] = 1.0
    adv = np.stack([np.asarray(L.period_gae(data.reward[e].T * h.reward_scale, v[e].T, boot[e], data.termination[e].T,
                                            data.truncation[e].T, start, h.gamma, h.lam)[1]).T for e in range(N)])
    w = np.broadcast_to(start.T, adv.shape) > 0
    a = adv[w]
    adv = np.where(w, (adv - a.mean()) / (a.std() + 1e-8), 0.0)
    C = dense_cov(cfg.noise.spec().process(cfg.environment.control_dt), np.array([1, 0, 0], bool))
    Cinv, (_, logdet) = np.linalg.inv(C), np.linalg.slogdet(2 * np.pi * C)
    grads = []
    for e in range(N):
        def obj(p):
            mu, std = nn_.mean_std(tr.nets, p, obs_n[e], cfg.min_std)  # (U, T, n)
            xi = (data.x[e] - mu) / std
            total = 0.0
            for s0 in (0, 3):
                seg = xi[:, s0:s0 + 3, :]  # (U, 3, n)
                quad = jnp.einsum("uin,ij,ujn->u", seg, jnp.asarray(Cinv, jnp.float32), seg)
                lp = -0.5 * quad - 0.5 * seg.shape[-1] * logdet - jnp.sum(jnp.log(std[:, s0:s0 + 3]), axis=(1, 2))
                total = total + jnp.sum(jnp.asarray(adv[e][:, s0], jnp.float32) * lp)
            return total / (U * T)
        grads.append(np.asarray(ravel_pytree(jax.grad(obj)(st.policy))[0], np.float64))
    grads = np.stack(grads)
    assert float(n) == N
    np.testing.assert_allclose(np.asarray(g_sum), grads.sum(0), rtol=2e-3, atol=1e-5)
    np.testing.assert_allclose(float(g_sq), np.sum(grads ** 2), rtol=2e-3)


def _point(tmp_path, cfg, st, name="p"):
    d = tmp_path / name
    d.mkdir()
    (d / "config.json").write_text(json.dumps(options.flat(cfg)))
    compact.save_compact(d, st, cfg)
    return d


def test_a_matched_state_holds_the_points_networks_at_another_control_step(tmp_path):
    env = TinyEnv(stop_prob=0.1)
    cfg = options.build(ppo_config.PPOConfig, **dict(TINY, exploration="white", seed=5)).resolved()
    st = ppo.make_ppo(cfg, env).init(jax.random.PRNGKey(99))  # networks unlike seed 5's
    st = st.replace(obs_stats=st.obs_stats._replace(mean=st.obs_stats.mean + 0.3))
    d = _point(tmp_path, cfg, st)
    saved = np.load(d / "compact.npz")
    at = matched_snr.config_at(cfg, 0.01, {"exploration": "nm-periods", "sigma": 0.5, "period_s": 0.04})
    assert at.environment.control_dt == 0.01 and at.reward_scale == pytest.approx(0.5) and at.unroll_length == 10
    m = matched_snr.matched_state(at, d, env=env)
    for part in ("policy", "value", "obs_stats"):
        leaves = jax.tree.leaves(getattr(m, part))
        keys = sorted(k for k in saved.files if k.split("/")[0] == part or k.startswith(part))
        assert sorted(float(np.sum(x)) for x in leaves) == pytest.approx(sorted(float(np.sum(saved[k])) for k in keys))
    assert float(m.hyper.process.sigma) == pytest.approx(0.5)
    first = matched_snr.matched_state(at, d, initial=True, env=env)
    fresh = ppo.make_ppo(cfg, env).init(jax.random.PRNGKey(5))  # the run's own initial networks
    np.testing.assert_array_equal(ravel_pytree(first.policy)[0], ravel_pytree(fresh.policy)[0])
    np.testing.assert_array_equal(first.obs_stats.mean, st.obs_stats.mean)


def test_the_measurement_writes_every_group_once_and_continues(tmp_path, monkeypatch):
    env = TinyEnv(stop_prob=0.1)
    cfg = options.build(ppo_config.PPOConfig, **dict(TINY, exploration="white", seed=0)).resolved()
    pts = {s: _point(tmp_path, options.replace(cfg, seed=s), ppo.make_ppo(cfg, env).init(jax.random.PRNGKey(s)),
                     f"s{s}") for s in (0, 1)}
    arms = {"white": {0.02: {"exploration": "white", "sigma": 1.0}, 0.01: {"exploration": "white", "sigma": 1.0}}}
    path = tmp_path / "snr.csv"
    rows = matched_snr.measure({0: pts, 4: pts}, arms, path, dts=(0.02, 0.01), batches=2, env=env)
    got = list(csv.DictReader(open(path)))
    assert len(rows) == len(got) == 2 * 2 * 2  # iterations x control steps x seeds
    assert {(r["iteration"], r["control_dt"], r["seed"]) for r in got} == \
        {(i, d, s) for i in ("0", "4") for d in ("0.02", "0.01") for s in ("0", "1")}
    assert all(np.isfinite(float(r["trcov"])) and float(r["trcov"]) > 0 for r in got)

    def fail(*a, **k):
        raise AssertionError("measured again")

    monkeypatch.setattr(ppo_gradsnr, "measure_many", fail)
    assert len(matched_snr.measure({0: pts, 4: pts}, arms, path, dts=(0.02, 0.01), batches=2, env=env)) == 8


def _complete(cell, seeds, tmp, cfg=None):
    out = []
    for s in range(seeds):
        d = tmp / cell / "points" / f"s{s}"
        d.mkdir(parents=True)
        (d / "config.json").write_text(json.dumps(cfg or {"seed": s}))
        out.append({"cell": cell, "point": f"s{s}", "seed": s, "steps": 1, "budget": 1, "diverged": False,
                    "det_reward_per_s": 0.0})
    return out


def test_the_studys_snr_waits_for_its_cells_then_measures_white_and_nmp_at_every_step(tmp_path, monkeypatch):
    calls = []
    monkeypatch.setattr(matched_snr, "measure", lambda *a, **k: calls.append(a))
    nmp20 = {"exploration": "nm-periods", "sigma": 0.4, "period_s": 0.06, "period_wise": True, "seed": 0}
    nmp25 = dict(nmp20, sigma=1.0, period_s=0.02)
    rows = (_complete("grid/dt0.02/white", 8, tmp_path, {"exploration": "white", "sigma": 0.16, "seed": 0})
            + _complete("grid/dt0.02/nmp", 8, tmp_path, nmp20) + _complete("grid/dt0.0025/nmp", 8, tmp_path, nmp25))
    for it in (1, 4):
        rows += _complete(f"snr/dt0.02/white_it{it}", 3, tmp_path)
    exploration2.snr(tmp_path, rows)
    assert calls == []  # iteration 8's policies are missing
    rows += _complete("snr/dt0.02/white_it8", 3, tmp_path)
    exploration2.snr(tmp_path, rows)
    (by_it, arms, path), = calls
    assert sorted(by_it) == [0, 4, 8, 16] and sorted(by_it[16]) == [0, 1, 2]
    assert by_it[0][2] == tmp_path / "snr/dt0.02/white_it1/points/s2"
    assert arms["white"][0.0025]["sigma"] == 0.16 and arms["nmp"][0.02]["period_s"] == 0.06
    assert arms["nmp"][0.005]["period_s"] == 0.02 and arms["nmp"][0.005]["period_wise"] is True
    assert path == tmp_path / exploration2_cells.SNR_CSV


def test_the_snr_summary_is_the_mean_and_t_interval_over_the_seeds(tmp_path):
    from scipy import stats

    vals = {0: [1.0, 2.0, 4.5], 16: [0.5, 0.25, 0.0]}
    with open(tmp_path / exploration2_cells.SNR_CSV, "w", newline="") as fh:
        w = csv.DictWriter(fh, matched_snr.COLUMNS)
        w.writeheader()
        for it, xs in vals.items():
            for s, x in enumerate(xs):
                w.writerow({"seed": s, "iteration": it, "control_dt": 0.0025, "arm": "white", "snr_per_s": x})
    exploration2_analysis._snr_report(tmp_path)
    got = {r["iteration"]: r for r in csv.DictReader(open(tmp_path / exploration2_analysis.SNR_SUMMARY_CSV))}
    x = np.array(vals[0])
    lo, hi = stats.t.interval(0.95, 2, loc=x.mean(), scale=stats.sem(x))
    assert float(got["0"]["mean"]) == pytest.approx(2.5) and float(got["0"]["ci_lo"]) == pytest.approx(lo)
    assert float(got["16"]["ci_hi"]) == pytest.approx(stats.t.interval(0.95, 2, loc=0.25, scale=stats.sem(vals[16]))[1])
    assert (tmp_path / exploration2_analysis.SNR_FIGURE).stat().st_size > 0


def test_the_snr_figure_draws_each_seeds_policy_across_the_steps_and_the_t_interval(tmp_path, saved_figures):
    """snr.png: a panel per arm and iteration; in each, every seed's values at 20, 5 and 2.5 ms (one
    line per seed's policy) and at each step the mean with scipy's 95% t interval, from 0 up."""
    from scipy import stats

    rng = np.random.default_rng(4)
    vals = {(a, it, dt): 10.0 ** rng.uniform(-4, -1, 3) for a in ("white", "nmp") for it in (0, 16)
            for dt in (0.02, 0.005, 0.0025)}
    with open(tmp_path / exploration2_cells.SNR_CSV, "w", newline="") as fh:
        w = csv.DictWriter(fh, matched_snr.COLUMNS)
        w.writeheader()
        for (a, it, dt), xs in vals.items():
            for s, x in enumerate(xs):
                w.writerow({"seed": s, "iteration": it, "control_dt": dt, "arm": a, "snr_per_s": x})
    exploration2_analysis._snr_report(tmp_path)
    (path, fig), = saved_figures
    assert path == tmp_path / exploration2_analysis.SNR_FIGURE
    assert [ax.get_title() for ax in fig.axes] == ["white, policy after 0 iterations", "white, policy after 16 iterations",
                                                   "nmp, policy after 0 iterations", "nmp, policy after 16 iterations"]
    for ax, (a, it) in zip(fig.axes, [("white", 0), ("white", 16), ("nmp", 0), ("nmp", 16)]):
        ms = [2.5, 5.0, 20.0]
        seeds = [ln for ln in ax.get_lines() if len(ln.get_xdata()) == 3 and ln.get_marker() == "o"]
        assert [list(ln.get_xdata()) for ln in seeds] == [ms] * 3
        assert [list(ln.get_ydata()) for ln in seeds] == [[vals[a, it, dt / 1000][s] for dt in ms] for s in range(3)]
        (bars,) = ax.containers
        (xs, ys), segs = bars.lines[0].get_data(), bars.lines[2][0].get_segments()
        for x, y, seg in zip(xs, ys, segs):
            v = vals[a, it, x / 1000]
            lo, hi = stats.t.interval(0.95, 2, loc=v.mean(), scale=stats.sem(v))
            assert y == pytest.approx(v.mean()) and sorted([seg[0][1], seg[1][1]]) == [pytest.approx(lo), pytest.approx(hi)]
        assert ax.get_ylim()[0] <= 0.0 and ax.get_xscale() == "log"
        assert [t.get_text() for t in ax.get_xticklabels()] == ["2.5", "5", "20"]
