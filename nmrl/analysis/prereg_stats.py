"""The pre-registered analyses of the studies (docs/exploration-study-2.md, docs/thesis-actor-critic.md).

Decisions are Welch tests, corrected by Holm over the pre-registered family; a "no difference"
claim is a TOST equivalence test within a pre-registered margin; aggregate intervals are the
stratified percentile bootstrap of rliable (Agarwal et al., NeurIPS 2021) with its interquartile
mean; the seeds per cell come from the noncentral t power of the Welch test at the Bonferroni level
of the family (Holm's first step). Plain numpy/scipy; no files, no figures.
"""

from __future__ import annotations

from typing import Callable, NamedTuple, Sequence

import numpy as np
from scipy import stats


class HolmResult(NamedTuple):
    adjusted: np.ndarray  #: Holm-adjusted p-values, in the order given
    reject: np.ndarray  #: adjusted p <= alpha


class WelchResult(NamedTuple):
    diff: float  #: mean(a) - mean(b)
    lo: float  #: lower end of the confidence interval of diff
    hi: float  #: upper end
    p: float  #: two-sided p-value of diff = 0
    dof: float  #: Welch-Satterthwaite degrees of freedom
    se: float  #: standard error of diff


class TostResult(NamedTuple):
    diff: float  #: mean(a) - mean(b)
    p: float  #: the TOST p-value, max(p_lower, p_upper)
    p_lower: float  #: one-sided p of H0: diff <= -margin
    p_upper: float  #: one-sided p of H0: diff >= +margin
    lo: float  #: the (1 - 2 alpha) Welch interval, inside (-margin, margin) exactly when equivalent
    hi: float
    equivalent: bool  #: p <= alpha


def holm(pvalues: Sequence[float], alpha: float = 0.05) -> HolmResult:
    """Holm–Bonferroni step-down adjustment of a family of p-values.

    The i-th smallest p-value is multiplied by (m - i + 1) for i = 1..m, the products are made
    non-decreasing in that order (a running maximum) and capped at 1; a hypothesis is rejected when
    its adjusted p-value is at most ``alpha``. This controls the family-wise error rate at ``alpha``
    under any dependence between the tests, and rejects at least what Bonferroni rejects.
    """
    p = np.asarray(pvalues, float)
    if p.ndim != 1 or np.any(~np.isfinite(p)) or np.any((p < 0) | (p > 1)):
        raise ValueError("p-values must be a 1-D sequence of numbers in [0, 1]")
    m = p.size
    order = np.argsort(p, kind="stable")
    scaled = (m - np.arange(m)) * p[order]
    adjusted = np.empty(m)
    adjusted[order] = np.minimum(np.maximum.accumulate(scaled), 1.0)
    return HolmResult(adjusted, adjusted <= alpha)


def _finite(x) -> np.ndarray:
    x = np.asarray(x, float).ravel()
    return x[np.isfinite(x)]


def _welch_parts(a, b) -> tuple[float, float, float]:
    """(mean(a) - mean(b), its standard error, Welch-Satterthwaite degrees of freedom)."""
    a, b = _finite(a), _finite(b)
    if a.size < 2 or b.size < 2:
        raise ValueError("each sample needs at least 2 finite values")
    va, vb = a.var(ddof=1) / a.size, b.var(ddof=1) / b.size
    se2 = va + vb
    if se2 == 0:
        raise ValueError("both samples are constant: the Welch statistic is undefined")
    dof = se2**2 / (va**2 / (a.size - 1) + vb**2 / (b.size - 1))
    return float(a.mean() - b.mean()), float(np.sqrt(se2)), float(dof)


def welch(a, b, confidence: float = 0.95) -> WelchResult:
    """Welch's unequal-variance comparison of two independent samples: ``mean(a) - mean(b)``, its
    two-sided ``confidence`` interval and the two-sided p-value of no difference.

    The order is scipy's (``ttest_ind(a, b, equal_var=False)``): positive when ``a`` is higher.
    Seeds of two cells are independent and their spreads differ between processes (the first study:
    between-seed SDs from 1 to 89 reward/s), so the variances are not pooled.
    """
    d, se, dof = _welch_parts(a, b)
    h = stats.t.ppf(0.5 + confidence / 2, dof) * se
    p = 2 * stats.t.sf(abs(d) / se, dof)
    return WelchResult(d, d - h, d + h, float(p), dof, se)


def tost(a, b, margin: float, alpha: float = 0.05) -> TostResult:
    """Two one-sided Welch tests (Schuirmann's TOST) of equivalence within ``±margin``.

    H0 is ``|mean(a) - mean(b)| >= margin``; it is rejected, and the two called equivalent, when both
    ``diff > -margin`` and ``diff < +margin`` are shown at level ``alpha`` — the same as the
    ``1 - 2 alpha`` Welch interval lying inside ``(-margin, margin)``. A non-significant Welch test
    says only "not detected"; this is the test that supports "no difference larger than the margin".
    """
    if not margin > 0:
        raise ValueError("the equivalence margin must be positive")
    return _tost(*_welch_parts(a, b), margin, alpha)


def _tost(d: float, se: float, dof: float, margin: float, alpha: float) -> TostResult:
    """The two one-sided t tests of ``|d| >= margin`` for an estimate ``d`` with standard error
    ``se`` and ``dof`` degrees of freedom."""
    p_lower = float(stats.t.sf((d + margin) / se, dof))
    p_upper = float(stats.t.cdf((d - margin) / se, dof))
    h = stats.t.ppf(1 - alpha, dof) * se
    p = max(p_lower, p_upper)
    return TostResult(d, p, p_lower, p_upper, d - h, d + h, bool(p <= alpha))


def _contrast_parts(samples: Sequence, weights: Sequence[float]) -> tuple[float, float, float]:
    """(sum_i w_i mean_i, its standard error, Welch-Satterthwaite degrees of freedom) of independent
    samples with unequal variances."""
    xs = [_finite(x) for x in samples]
    if len(xs) != len(weights) or not xs:
        raise ValueError("one weight per sample")
    if any(x.size < 2 for x in xs):
        raise ValueError("each sample needs at least 2 finite values")
    v = np.array([w * w * x.var(ddof=1) / x.size for w, x in zip(weights, xs)])
    se2 = float(v.sum())
    if se2 == 0:
        raise ValueError("every weighted sample is constant: the Welch statistic is undefined")
    dof = se2**2 / float(sum(vi**2 / (x.size - 1) for vi, x in zip(v, xs) if vi > 0))
    return float(sum(w * x.mean() for w, x in zip(weights, xs))), float(np.sqrt(se2)), float(dof)


def contrast(samples: Sequence, weights: Sequence[float], confidence: float = 0.95) -> WelchResult:
    """The Welch test of a linear contrast ``sum_i w_i mean(samples_i) = 0`` of independent cells:
    its estimate, two-sided ``confidence`` interval and p-value, with Welch-Satterthwaite degrees of
    freedom. Weights (1, -1) give :func:`welch`; (1, -1, -1, 1) over (a at d1, a at d2, b at d1, b
    at d2) the interaction: how much more ``a`` changes from d2 to d1 than ``b`` does (P7)."""
    d, se, dof = _contrast_parts(samples, weights)
    h = stats.t.ppf(0.5 + confidence / 2, dof) * se
    return WelchResult(d, d - h, d + h, float(2 * stats.t.sf(abs(d) / se, dof)), dof, se)


def contrast_tost(samples: Sequence, weights: Sequence[float], margin: float, alpha: float = 0.05) -> TostResult:
    """:func:`tost` for a linear contrast: equivalent when both one-sided Welch tests reject
    ``|sum_i w_i mean_i| >= margin`` at ``alpha``."""
    if not margin > 0:
        raise ValueError("the equivalence margin must be positive")
    return _tost(*_contrast_parts(samples, weights), margin, alpha)


DECISIONS = ("ahead", "behind", "equivalent", "not detected", "pending")


def family(cells: dict[str, Sequence[float]], contrasts: Sequence[tuple[str, dict[str, float]]],
           margin: float, alpha: float = 0.05, bootstrap_reps: int = 0) -> list[dict]:
    """A pre-registered family of linear contrasts between cells, decided together: per contrast
    ``(name, {cell: weight})`` its estimate with the 95% Welch interval and raw p, the Holm-adjusted
    p over the family (:func:`holm`), the TOST p within ``±margin`` and its Holm adjustment over the
    same family, and the decision: "ahead" / "behind" (Holm rejects; the sign of the estimate),
    "equivalent" (TOST rejects after Holm), else "not detected". While any contrast lacks a cell
    with 2 finite values, every decision is "pending" (a family is corrected as a whole) and the
    estimates that exist are given. ``bootstrap_reps`` > 0 adds each contrast's stratified bootstrap
    interval (:func:`contrast_rows`)."""
    return decide(contrast_rows(cells, contrasts, margin, bootstrap_reps), alpha)


def contrast_rows(cells: dict[str, Sequence[float]], contrasts: Sequence[tuple[str, dict[str, float]]],
                  margin: float, bootstrap_reps: int = 0) -> list[dict]:
    """:func:`family`'s rows before the decision: per contrast its cells, their sizes, and, where every
    cell has 2 finite values, the estimate, the 95% Welch interval, the raw p and the TOST p within
    ``±margin``; with ``bootstrap_reps`` > 0 also ``boot_lo``/``boot_hi``, the 95% stratified
    percentile bootstrap interval of the same estimate (:func:`contrast_bootstrap_ci`, seed 0),
    reported beside Welch's and deciding nothing. A family over several endpoints (each with its
    cells and margin) is the rows of each endpoint joined, then :func:`decide`."""
    out = []
    for name, weights in contrasts:
        samples = [_finite(cells.get(c, ())) for c in weights]
        row = {"contrast": name, "cells": " ".join(f"{w:+g}*{c}" for c, w in weights.items()),
               "n": " ".join(str(s.size) for s in samples)}
        try:
            r = contrast(samples, list(weights.values()))
            e = contrast_tost(samples, list(weights.values()), margin)
        except ValueError:
            out.append(row)
            continue
        boot = {}
        if bootstrap_reps > 0:
            boot = dict(zip(("boot_lo", "boot_hi"),
                            contrast_bootstrap_ci(samples, list(weights.values()), bootstrap_reps)))
        out.append({**row, "estimate": r.diff, "lo": r.lo, "hi": r.hi, **boot, "p": r.p, "tost_p": e.p})
    return out


def decide(rows: list[dict], alpha: float = 0.05) -> list[dict]:
    """Holm over every row's raw p and, apart, over every row's TOST p, and each row's decision
    (:func:`family`); every decision "pending" while a row has no estimate."""
    if any("p" not in r for r in rows):
        return [{**r, "decision": "pending"} for r in rows]
    out = [dict(r) for r in rows]
    reject = holm([r["p"] for r in out], alpha)
    equiv = holm([r["tost_p"] for r in out], alpha)
    for r, pa, rj, pe, eq in zip(out, reject.adjusted, reject.reject, equiv.adjusted, equiv.reject):
        r.update(p_holm=float(pa), tost_p_holm=float(pe),
                 decision=("ahead" if r["estimate"] > 0 else "behind") if rj else "equivalent" if eq else "not detected")
    return out


# ------------------------------------------------------------------------------ bootstrap


def iqm(x, axis=None):
    """The interquartile mean as rliable defines it (``metrics.aggregate_iqm``): the 25% trimmed mean
    of all runs pooled (``axis=None``: the flattened runs of every task), trimming
    ``int(0.25 n)`` values from each end — not an interpolated quartile mean. Robust to a diverged or
    a standing seed, yet uses half of the runs, unlike the median."""
    return stats.trim_mean(np.asarray(x, float), 0.25, axis=axis)


def iqm_of_strata(samples: Sequence[np.ndarray]) -> np.ndarray:
    """The IQM over the runs of all strata pooled, per replicate: ``samples`` as
    :func:`stratified_bootstrap` passes them (one array per stratum, replicates on the first axis)."""
    return iqm(np.concatenate(samples, axis=-1), axis=-1)


def _strata(scores) -> list[np.ndarray]:
    if isinstance(scores, np.ndarray) and scores.ndim == 2:  # rliable's layout: runs x tasks
        out = [scores[:, j] for j in range(scores.shape[1])]
    else:
        out = [np.asarray(s, float).ravel() for s in scores]
    out = [np.asarray(s, float) for s in out]
    if not out or any(s.size == 0 or not np.all(np.isfinite(s)) for s in out):
        raise ValueError("every stratum needs at least one run, all finite")
    return out


def stratified_bootstrap(scores, statistic: Callable[[list[np.ndarray]], np.ndarray], reps: int,
                         seed: int, chunk: int = 5000) -> np.ndarray:
    """``reps`` bootstrap replicates of ``statistic`` under stratified resampling: in each replicate
    the runs of every stratum (a task, or a cell of the grid) are drawn with replacement from that
    stratum alone, keeping its size, as rliable's ``StratifiedBootstrap`` does with
    ``task_bootstrap=False``. The strata stay fixed — the uncertainty is that of rerunning the
    seeds, not of choosing other tasks — and strata of different sizes are allowed.

    ``scores``: a sequence of 1-D arrays (one per stratum) or rliable's (runs x tasks) matrix.
    ``statistic`` receives one array per stratum of shape (replicates, runs) and returns one value
    per replicate (e.g. :func:`iqm_of_strata`, or ``lambda s: s[0].mean(-1) - s[1].mean(-1)``).
    Replicates are drawn ``chunk`` at a time to bound memory; ``seed`` makes them reproducible.
    """
    strata = _strata(scores)
    rng = np.random.default_rng(seed)
    out = []
    for start in range(0, reps, chunk):
        r = min(chunk, reps - start)
        draws = [s[rng.integers(0, s.size, size=(r, s.size))] for s in strata]
        out.append(np.asarray(statistic(draws), float).reshape(r))
    return np.concatenate(out)


def stratified_bootstrap_ci(scores, statistic: Callable[[list[np.ndarray]], np.ndarray] = iqm_of_strata,
                            reps: int = 50_000, seed: int = 0,
                            confidence: float = 0.95) -> tuple[float, float, float]:
    """(point estimate, lower, upper): the statistic of the data and its percentile interval over
    :func:`stratified_bootstrap` replicates, rliable's default method (``get_interval_estimates``
    with ``method='percentile'``; its default is 50,000 replicates and the IQM).

    The percentile interval covers less than its nominal level with few runs per stratum (measured
    over 2,000 normal data sets: 89% for the mean of 8 runs, 91.5% for a difference of two cells of
    8, against Welch's 95%), so the study decides with Welch tests and reports these beside them.
    """
    point = float(np.asarray(statistic([s[None, :] for s in _strata(scores)])).ravel()[0])
    boot = stratified_bootstrap(scores, statistic, reps, seed)
    lo, hi = np.quantile(boot, [(1 - confidence) / 2, (1 + confidence) / 2])
    return point, float(lo), float(hi)


def contrast_bootstrap_ci(samples: Sequence, weights: Sequence[float], reps: int = 50_000, seed: int = 0,
                          confidence: float = 0.95) -> tuple[float, float]:
    """The percentile interval of a linear contrast of cell means ``sum_i w_i mean(samples_i)`` under
    :func:`stratified_bootstrap`: each cell a stratum whose runs are redrawn from that cell alone, as
    rerunning its seeds would. Reported beside :func:`contrast`'s Welch interval (it covers less than
    its level with 8 runs a cell: :func:`stratified_bootstrap_ci`)."""
    w = np.asarray(weights, float)
    if len(samples) != w.size:
        raise ValueError("one weight per sample")
    _, lo, hi = stratified_bootstrap_ci([_finite(x) for x in samples],
                                        lambda s: sum(wi * si.mean(axis=-1) for wi, si in zip(w, s)),
                                        reps, seed, confidence)
    return lo, hi


# ------------------------------------------------------------------------------ power


def welch_power(n: int, sd: float, delta: float, alpha: float, cells: int = 2) -> float:
    """Power of a two-sided t test of a contrast of ``cells`` independent cells with weights ±1,
    ``n`` seeds each, a common between-seed SD ``sd``, at level ``alpha``, when the true contrast is
    ``delta``: a difference of two cells for ``cells=2``, the interaction (a − b at δ1) − (a − b at
    δ2) for ``cells=4``.

    The statistic is noncentral t with noncentrality ``delta / (sd sqrt(cells / n))`` and, the
    variances being equal, Welch-Satterthwaite degrees of freedom ``cells (n - 1)``; power is the
    mass of that distribution beyond ``±t_{1 - alpha/2}``.
    """
    if n < 2:
        return 0.0
    dof = cells * (n - 1)
    nc = abs(delta) / (sd * np.sqrt(cells / n))
    tc = stats.t.ppf(1 - alpha / 2, dof)
    return float(stats.nct.sf(tc, dof, nc) + stats.nct.cdf(-tc, dof, nc))


def power_seeds(sd: float, delta: float, alpha: float = 0.05, power: float = 0.8, m_tests: int = 1,
                cells: int = 2, n_max: int = 10_000) -> int:
    """The fewest seeds per cell for which :func:`welch_power` at level ``alpha / m_tests`` reaches
    ``power``: the seeds a contrast needs to detect ``delta`` inside a family of ``m_tests`` under
    Holm. Holm tests its smallest p-value at ``alpha / m`` and the later ones at larger levels, so
    this Bonferroni level is the conservative one: each contrast has at least this power whatever the
    other contrasts do.
    """
    if not (sd > 0 and delta != 0 and 0 < alpha < 1 and 0 < power < 1 and m_tests >= 1):
        raise ValueError("need sd > 0, delta != 0, alpha and power in (0, 1), m_tests >= 1")
    level = alpha / m_tests
    for n in range(2, n_max + 1):
        if welch_power(n, sd, delta, level, cells) >= power:
            return n
    raise ValueError(f"more than {n_max} seeds per cell")


def pooled_sd(samples: Sequence[np.ndarray]) -> tuple[float, int]:
    """The between-seed SD pooled over cells (each cell's variance about its own mean, weighted by
    its degrees of freedom) and those degrees of freedom: the spread a power calculation needs when
    every cell has only a few seeds."""
    xs = [_finite(x) for x in samples]
    xs = [x for x in xs if x.size >= 2]
    dof = sum(x.size - 1 for x in xs)
    if dof == 0:
        raise ValueError("no cell has 2 finite values")
    ss = sum(float(((x - x.mean()) ** 2).sum()) for x in xs)
    return float(np.sqrt(ss / dof)), int(dof)


def sd_upper(sd: float, dof: int, level: float = 0.8) -> float:
    """The one-sided ``level`` upper confidence limit of an SD estimated with ``dof`` degrees of
    freedom (chi-square): sizing with it rather than the estimate keeps the planned power with
    probability ``level`` when the estimate comes from few seeds."""
    return float(sd * np.sqrt(dof / stats.chi2.ppf(1 - level, dof)))
