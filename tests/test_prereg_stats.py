"""The pre-registered analysis (nmrl.analysis.prereg_stats) against independent computations:
Holm by closed testing and by hand, Welch and TOST by scipy's t tests, the stratified bootstrap by
rliable's resampling scheme written out, by its exact bootstrap variance and by Monte Carlo coverage,
the power by textbook sample sizes and by simulated tests."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy import stats as sps

from nmrl.analysis import prereg_stats as ps

# ------------------------------------------------------------------------------ Holm


def _closed_testing(p, alpha):
    """Holm as closed testing with Bonferroni local tests, by brute force over every subset: H_i is
    rejected when every intersection containing it is; its adjusted p is the largest local p."""
    m = len(p)
    adj = np.zeros(m)
    for size in range(1, m + 1):
        for subset in itertools.combinations(range(m), size):
            local = min(1.0, size * min(p[j] for j in subset))
            for i in subset:
                adj[i] = max(adj[i], local)
    return adj, adj <= alpha


def test_holm_textbook_examples():
    # four tests at alpha 0.05: 0.005 <= 0.05/4, 0.01 <= 0.05/3, 0.03 > 0.05/2 -> stop
    r = ps.holm([0.01, 0.04, 0.03, 0.005])
    np.testing.assert_allclose(r.adjusted, [0.03, 0.06, 0.06, 0.02])
    assert r.reject.tolist() == [True, False, False, True]
    # Holm (1979)-style: all below alpha/(m - i + 1) -> all rejected; adjusted never above 1
    r = ps.holm([0.001, 0.002, 0.003, 0.04])
    np.testing.assert_allclose(r.adjusted, [0.004, 0.006, 0.006, 0.04])
    assert r.reject.all()
    np.testing.assert_allclose(ps.holm([0.5, 0.9, 0.7]).adjusted, [1.0, 1.0, 1.0])
    assert ps.holm([0.03]).adjusted.tolist() == [0.03]


def test_holm_equals_closed_testing_and_beats_bonferroni():
    rng = np.random.default_rng(1)
    for _ in range(300):
        m = int(rng.integers(1, 7))
        p = np.where(rng.random(m) < 0.5, rng.random(m) * 0.05, rng.random(m))
        if rng.random() < 0.2:
            p[0] = p[-1]  # ties
        r = ps.holm(p)
        adj, rej = _closed_testing(p.tolist(), 0.05)
        np.testing.assert_allclose(r.adjusted, adj, rtol=1e-12, atol=0)
        assert r.reject.tolist() == rej.tolist()
        assert np.all(r.reject >= (np.minimum(m * p, 1) <= 0.05))


def test_holm_refuses_non_probabilities():
    for bad in ([0.1, 1.2], [np.nan], [[0.1]]):
        with pytest.raises(ValueError):
            ps.holm(bad)


# ------------------------------------------------------------------------------ Welch and TOST


def _samples():
    rng = np.random.default_rng(2)
    for na, nb in ((3, 3), (8, 8), (8, 5), (12, 4)):
        yield rng.normal(100, 40, na), rng.normal(80, 10, nb)


def test_welch_is_scipys_unequal_variance_t_test():
    for a, b in _samples():
        r = ps.welch(a, b)
        t = sps.ttest_ind(a, b, equal_var=False)
        lo, hi = t.confidence_interval(0.95)
        assert np.isclose(r.diff, a.mean() - b.mean()) and np.isclose(r.p, t.pvalue)
        assert np.isclose(r.lo, lo) and np.isclose(r.hi, hi) and np.isclose(r.dof, t.df)
        lo90, hi90 = t.confidence_interval(0.90)
        r90 = ps.welch(a, b, confidence=0.90)
        assert np.isclose(r90.lo, lo90) and np.isclose(r90.hi, hi90)
    with pytest.raises(ValueError):
        ps.welch([1.0], [1.0, 2.0])


def test_tost_is_two_shifted_one_sided_welch_tests():
    for a, b in _samples():
        for margin in (10.0, 40.0, 80.0):
            r = ps.tost(a, b, margin)
            lower = sps.ttest_ind(a + margin, b, equal_var=False, alternative="greater").pvalue
            upper = sps.ttest_ind(a - margin, b, equal_var=False, alternative="less").pvalue
            assert np.isclose(r.p_lower, lower) and np.isclose(r.p_upper, upper)
            assert np.isclose(r.p, max(lower, upper))
            lo, hi = sps.ttest_ind(a, b, equal_var=False).confidence_interval(0.90)
            assert np.isclose(r.lo, lo) and np.isclose(r.hi, hi)
            assert r.equivalent == (-margin < lo and hi < margin) == (max(lower, upper) <= 0.05)
    a = np.array([10.0, 11, 9, 10.5, 9.5, 10, 10.2, 9.8])
    assert ps.tost(a, a + 0.1, 2.0).equivalent and not ps.tost(a, a + 0.1, 0.1).equivalent
    with pytest.raises(ValueError):
        ps.tost(a, a, 0.0)


# ------------------------------------------------------------------------------ IQM and bootstrap


def test_iqm_is_rliables_trimmed_mean():
    assert ps.iqm(np.arange(1.0, 9.0)) == 4.5  # drop 2 of 8 at each end: mean(3, 4, 5, 6)
    assert ps.iqm(np.arange(1.0, 11.0)) == 5.5  # int(2.5) = 2 of 10 at each end
    x = np.array([[0.0, 100.0], [1.0, 2.0], [3.0, -50.0], [4.0, 5.0]])  # runs x tasks
    assert ps.iqm(x) == np.mean([1.0, 2.0, 3.0, 4.0])  # rliable's aggregate_iqm: all runs pooled
    s = [x[:, 0], x[:, 1]]
    assert ps.iqm_of_strata([v[None, :] for v in s])[0] == ps.iqm(x)


def _rliable_bootstrap(scores, func, reps, seed):
    """rliable's StratifiedBootstrap (task_bootstrap=False) as its source writes it: for a
    (runs x tasks) matrix, an index matrix of random runs of the same shape, the task index fixed
    by an open grid, one replicate at a time."""
    rs = np.random.RandomState(seed)
    n, m = scores.shape
    _, tasks = np.ogrid[0:n, 0:m]
    return np.array([func(scores[rs.choice(n, (n, m), replace=True), tasks]) for _ in range(reps)])


def test_bootstrap_matches_rliables_scheme():
    rng = np.random.default_rng(3)
    scores = rng.normal([0.0, 50.0, 200.0], [5.0, 30.0, 60.0], size=(8, 3))  # 8 runs x 3 tasks
    theirs = _rliable_bootstrap(scores, lambda s: sps.trim_mean(s, 0.25, axis=None), 4000, 0)
    point, lo, hi = ps.stratified_bootstrap_ci(scores, ps.iqm_of_strata, reps=20000, seed=1)
    assert point == sps.trim_mean(scores, 0.25, axis=None)
    ref_lo, ref_hi = np.percentile(theirs, [2.5, 97.5])
    width = ref_hi - ref_lo
    assert abs(lo - ref_lo) < 0.06 * width and abs(hi - ref_hi) < 0.06 * width
    # the columns of a matrix and a list of strata are the same data
    as_list = ps.stratified_bootstrap_ci([scores[:, j] for j in range(3)], ps.iqm_of_strata, reps=500, seed=4)
    assert as_list == ps.stratified_bootstrap_ci(scores, ps.iqm_of_strata, reps=500, seed=4)


def test_bootstrap_resamples_within_strata_only():
    a, b = np.array([0.0, 1.0, 2.0]), np.array([100.0, 101.0, 102.0, 103.0, 104.0])
    seen = []

    def record(s):
        seen.append([x.copy() for x in s])
        return s[1].mean(-1) - s[0].mean(-1)

    ps.stratified_bootstrap([a, b], record, reps=700, seed=5, chunk=300)
    sa = np.concatenate([s[0] for s in seen])
    sb = np.concatenate([s[1] for s in seen])
    assert sa.shape == (700, 3) and sb.shape == (700, 5)
    assert set(np.unique(sa)) == set(a) and set(np.unique(sb)) == set(b)


def test_bootstrap_variance_of_a_contrast_is_the_exact_one():
    """The bootstrap variance of mean(b) - mean(a) is, exactly, var0(a)/n_a + var0(b)/n_b (ddof 0)."""
    rng = np.random.default_rng(6)
    a, b = rng.normal(0, 3, 8), rng.normal(5, 1, 12)
    boot = ps.stratified_bootstrap([a, b], lambda s: s[1].mean(-1) - s[0].mean(-1), reps=40000, seed=7)
    exact = a.var() / a.size + b.var() / b.size
    assert abs(boot.var() / exact - 1) < 0.03  # Monte Carlo error of a variance from 4e4 draws: ~0.7%
    assert abs(boot.mean() - (b.mean() - a.mean())) < 4 * np.sqrt(exact / 40000)


def test_bootstrap_interval_covers_at_about_its_level():
    """Monte Carlo coverage: the IQM over 3 strata x 20 normal runs whose pooled distribution is
    symmetric about 0 (its IQM is 0); 300 data sets, 1000 replicates each."""
    rng = np.random.default_rng(8)
    hits = 0
    for k in range(300):
        strata = [rng.normal(mu, 1.0, 20) for mu in (-1.0, 0.0, 1.0)]
        _, lo, hi = ps.stratified_bootstrap_ci(strata, ps.iqm_of_strata, reps=1000, seed=k)
        hits += lo <= 0.0 <= hi
    assert 0.90 <= hits / 300 <= 0.985  # nominal 0.95; binomial SD over 300 sets ~0.013


@pytest.mark.parametrize("weights", [(1.0, -1.0), (1.0, -1.0, -1.0, 1.0)])
def test_a_contrasts_bootstrap_interval_is_scipys_percentile_bootstrap(weights):
    """A linear contrast of cell means (a difference, and an interaction of four cells of 8): its
    stratified percentile interval against scipy.stats.bootstrap, which resamples each of several
    samples on its own; the two differ only by Monte Carlo error (50,000 replicates each)."""
    rng = np.random.default_rng(31)
    samples = [rng.normal(10 * i, 5 + 10 * i, 8) for i in range(len(weights))]
    lo, hi = ps.contrast_bootstrap_ci(samples, weights, reps=50_000, seed=0)

    def stat(*xs, axis=-1):
        return sum(w * x.mean(axis=axis) for w, x in zip(weights, xs))

    ref = sps.bootstrap(samples, stat, n_resamples=50_000, method="percentile", vectorized=True,
                        random_state=np.random.default_rng(1)).confidence_interval
    width = ref.high - ref.low
    assert lo == pytest.approx(ref.low, abs=0.02 * width) and hi == pytest.approx(ref.high, abs=0.02 * width)
    # narrower than Welch's with 8 runs a cell (the percentile interval's undercoverage, documented)
    welch = ps.contrast(samples, weights)
    assert welch.lo < lo < welch.diff < hi < welch.hi


def test_a_familys_rows_carry_the_bootstrap_interval_when_asked():
    rng = np.random.default_rng(32)
    cells = {"a": rng.normal(0, 1, 8), "b": rng.normal(1, 1, 8)}
    fam = [("D", {"a": 1.0, "b": -1.0})]
    assert "boot_lo" not in ps.family(cells, fam, margin=1.0)[0]
    row = ps.family(cells, fam, margin=1.0, bootstrap_reps=20_000)[0]
    assert (row["boot_lo"], row["boot_hi"]) == ps.contrast_bootstrap_ci([cells["a"], cells["b"]], (1.0, -1.0), 20_000)


def test_bootstrap_refuses_an_empty_stratum():
    with pytest.raises(ValueError):
        ps.stratified_bootstrap_ci([np.array([1.0, 2.0]), np.array([])])


# ------------------------------------------------------------------------------ power


def test_power_seeds_textbook_sample_sizes():
    # two-sample t, two-sided alpha 0.05, power 0.8 (Cohen 1988; G*Power): d = 1 -> 17, 0.8 -> 26,
    # 0.5 -> 64 per group
    assert ps.power_seeds(1.0, 1.0) == 17
    assert ps.power_seeds(10.0, 8.0) == 26
    assert ps.power_seeds(2.0, 1.0) == 64
    # Bonferroni over m tests is the single test at alpha / m
    assert ps.power_seeds(40.0, 25.0, m_tests=10) == ps.power_seeds(40.0, 25.0, alpha=0.005)


def test_power_matches_simulated_welch_tests():
    rng = np.random.default_rng(9)
    sd, delta, level = 40.0, 60.0, 0.05 / 10
    n = ps.power_seeds(sd, delta, m_tests=10)
    for k, target in ((n, 0.8), (n - 1, None)):
        a = rng.normal(0.0, sd, (20000, k))
        b = rng.normal(delta, sd, (20000, k))
        sim = np.mean(sps.ttest_ind(a, b, axis=1, equal_var=False).pvalue <= level)
        assert abs(sim - ps.welch_power(k, sd, delta, level)) < 0.015
        if target:
            assert sim > target - 0.015
        else:
            assert sim < 0.8 + 0.015


def test_power_of_an_interaction_matches_simulation():
    """Four cells, (c1 - c0) - (c3 - c2), Welch-Satterthwaite degrees of freedom written out."""
    rng = np.random.default_rng(10)
    sd, delta, n, level = 30.0, 70.0, 8, 0.01
    x = rng.normal(0.0, sd, (20000, 4, n))
    x[:, 1] += delta
    w = np.array([-1.0, 1.0, 1.0, -1.0])
    est = np.einsum("c,rc->r", w, x.mean(-1))
    v = x.var(-1, ddof=1) / n
    se2 = v.sum(-1)
    dof = se2**2 / (v**2 / (n - 1)).sum(-1)
    sim = np.mean(2 * sps.t.sf(np.abs(est) / np.sqrt(se2), dof) <= level)
    assert abs(sim - ps.welch_power(n, sd, delta, level, cells=4)) < 0.02


def test_pooled_sd_and_its_upper_limit():
    cells = [np.array([1.0, 3.0]), np.array([10.0, 14.0, 12.0]), np.array([7.0])]
    ss = 2.0 + 8.0  # (1-2)^2 + (3-2)^2, (10-12)^2 + (14-12)^2
    assert ps.pooled_sd(cells) == (pytest.approx(np.sqrt(ss / 3)), 3)
    rng = np.random.default_rng(11)
    covered = 0
    for _ in range(2000):
        s, dof = ps.pooled_sd([rng.normal(0, 5.0, 4) for _ in range(3)])
        covered += ps.sd_upper(s, dof, 0.8) >= 5.0
    assert abs(covered / 2000 - 0.8) < 0.03


def test_a_two_cell_contrast_is_scipys_welch_test_and_its_tost():
    rng = np.random.default_rng(21)
    a, b = rng.normal(3.0, 2.0, 8), rng.normal(1.0, 5.0, 6)
    r = ps.contrast([a, b], [1.0, -1.0])
    ref = sps.ttest_ind(a, b, equal_var=False)
    assert r.p == pytest.approx(ref.pvalue, rel=1e-10) and r.diff == pytest.approx(a.mean() - b.mean())
    lo, hi = ref.confidence_interval(0.95)
    assert (r.lo, r.hi) == (pytest.approx(lo, rel=1e-10), pytest.approx(hi, rel=1e-10))
    assert ps.contrast_tost([a, b], [1.0, -1.0], 4.0) == ps.tost(a, b, 4.0)


def test_an_interaction_contrast_covers_at_its_level_and_its_tost_holds_its_size():
    """Four cells with unequal spreads, 8 seeds each: the 95% interval of (c0 - c1) - (c2 - c3)
    covers the true interaction in 95% of simulated studies (Monte Carlo, 4,000 studies), and
    TOST at a margin equal to the true effect rejects in at most 5% (its size)."""
    rng = np.random.default_rng(22)
    sds, means = np.array([60.0, 25.0, 60.0, 25.0]), np.array([10.0, 40.0, 0.0, 0.0])
    w = [1.0, -1.0, -1.0, 1.0]
    truth = float(np.dot(w, means))  # -30
    cover, equiv = 0, 0
    n_studies = 4000
    for _ in range(n_studies):
        cells = [rng.normal(m, s, 8) for m, s in zip(means, sds)]
        r = ps.contrast(cells, w)
        cover += r.lo <= truth <= r.hi
        equiv += ps.contrast_tost(cells, w, margin=abs(truth)).equivalent
    assert abs(cover / n_studies - 0.95) < 0.015
    assert equiv / n_studies <= 0.05 + 0.012


def test_a_family_is_decided_by_holm_over_all_its_contrasts():
    rng = np.random.default_rng(23)
    cells = {"w20": rng.normal(100, 30, 8), "w25": rng.normal(20, 10, 8), "n25": rng.normal(21, 10, 8),
             "o25": rng.normal(60, 10, 8)}
    fam = [("P1", {"w25": 1.0, "w20": -1.0}), ("P3", {"o25": 1.0, "w25": -1.0}), ("P6", {"n25": 1.0, "w25": -1.0})]
    rows = ps.family(cells, fam, margin=50.0)
    raw = [sps.ttest_ind(cells[a], cells[b], equal_var=False).pvalue for a, b in (("w25", "w20"), ("o25", "w25"),
                                                                                   ("n25", "w25"))]
    h = ps.holm(raw)
    assert [r["p_holm"] for r in rows] == pytest.approx(list(h.adjusted))
    assert [r["decision"] for r in rows] == ["behind", "ahead", "equivalent"]
    # a contrast without data: the whole family waits, the estimates that exist are kept
    rows = ps.family({k: v for k, v in cells.items() if k != "n25"}, fam, margin=50.0)
    assert {r["decision"] for r in rows} == {"pending"} and "estimate" in rows[0] and "estimate" not in rows[2]
