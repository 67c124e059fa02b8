"""Figures: the paper's Fig. 3 (average reward against l) and learning curves.

Fig. 3 of the paper plots the average reward after 10^5 trials against the period length l; the
text gives two of its values, 3.28 at l = 1 and 4.59 at l = 10, which are marked for reference.
Intervals are 95% Student-t intervals of the mean over seeds.
"""

from __future__ import annotations

import os
import pathlib

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy import stats  # noqa: E402

#: The values of Fig. 3 that the paper's text states (Sec. V-D).
PAPER_FIG3 = {1: 3.28, 10: 4.59}


def mean_ci95(x: np.ndarray) -> tuple[float, float]:
    """Mean and half-width of the 95% t-interval (0 half-width for a single value)."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return float("nan"), float("nan")
    if x.size == 1:
        return float(x[0]), 0.0
    return float(x.mean()), float(stats.t.ppf(0.975, x.size - 1) * x.std(ddof=1) / np.sqrt(x.size))


def smooth(y: np.ndarray, k: int = 5) -> np.ndarray:
    """Trailing running mean over up to ``k`` points (the first points use what exists)."""
    c = np.cumsum(np.insert(np.asarray(y, float), 0, 0.0))
    i = np.arange(1, len(y) + 1)
    lo = np.maximum(i - k, 0)
    return (c[i] - c[lo]) / (i - lo)


def _save(fig, path: pathlib.Path) -> None:
    tmp = path.with_name(path.stem + ".tmp.png")
    fig.savefig(tmp, dpi=110, bbox_inches="tight")
    plt.close(fig)
    os.replace(tmp, path)


def fig3(out: str | os.PathLike, results: list[dict], path: str | os.PathLike | None = None) -> pathlib.Path:
    """Write fig3.png: reward vs l (mean, 95% CI over seeds, paper's points) and learning curves."""
    from nmrl import run, sweep

    out = pathlib.Path(out)
    path = pathlib.Path(path) if path else out / "fig3.png"
    ls = sorted({int(r["l"]) for r in results})
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(13, 4.8))
    fig.subplots_adjust(wspace=0.32)
    means, halves, divs = [], [], []
    for l in ls:
        rs = [r for r in results if int(r["l"]) == l]
        ok = [float(r["avg_reward"]) for r in rs if str(r["diverged"]) not in ("True", "true", "1")]
        m, h = mean_ci95(np.array(ok)) if ok else (float("nan"), float("nan"))
        means.append(m)
        halves.append(h)
        divs.append(len(rs) - len(ok))
        ax.scatter([l] * len(ok), ok, color="tab:blue", alpha=0.35, s=14)
    ax.errorbar(ls, means, yerr=halves, fmt="o-", color="tab:blue", capsize=4, label="nmrl (mean, 95% CI)")
    for l, d, m in zip(ls, divs, means):
        if d:
            ax.annotate(f"{d} diverged", (l, m if np.isfinite(m) else 0), textcoords="offset points",
                        xytext=(0, 10), ha="center", color="tab:red", fontsize=8)
    ax.scatter(list(PAPER_FIG3), list(PAPER_FIG3.values()), marker="*", s=160, color="tab:orange",
               label="paper (values given in the text)", zorder=5)
    trials = [int(r["trials"]) for r in results]
    ax.set_xlabel("period length l")
    ax.set_ylabel("average reward per step")
    ax.set_title(f"Fig. 3: average reward vs l (after ~{np.median(trials):,.0f} trials)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)

    cmap = plt.get_cmap("viridis")
    for j, l in enumerate(ls):
        curves = []
        for r in results:
            if int(r["l"]) != l:
                continue
            m = run.read_metrics(sweep.point_dir(out, l, int(r["seed"])))
            if m:
                curves.append((np.array([x["trials"] for x in m]), np.array([x["avg_reward"] for x in m])))
        if not curves:
            continue
        n = min(len(c[0]) for c in curves)
        tr = np.mean([c[0][:n] for c in curves], axis=0)
        rw = np.mean([c[1][:n] for c in curves], axis=0)
        ax2.plot(tr, smooth(rw), color=cmap(j / max(1, len(ls) - 1)), label=f"l={l}")
    ax2.set_xlabel("trials")
    ax2.set_ylabel("average reward per step (mean over seeds,\nrunning mean of 5 chunks)")
    ax2.set_title("learning curves")
    ax2.grid(alpha=0.3)
    ax2.legend(fontsize=8, ncol=2)
    _save(fig, path)
    return path


def learning_curve(run_dir: str | os.PathLike, path: str | os.PathLike | None = None) -> pathlib.Path:
    """Average reward and forward speed against trials for one run directory."""
    from nmrl import run

    run_dir = pathlib.Path(run_dir)
    m = run.read_metrics(run_dir)
    path = pathlib.Path(path) if path else run_dir / "learning_curve.png"
    fig, ax = plt.subplots(figsize=(6, 4))
    tr = [x["trials"] for x in m]
    ax.plot(tr, [x["avg_reward"] for x in m], label="average reward per step")
    ax.plot(tr, [x["forward_speed"] for x in m], label="forward speed [m/s]")
    ax.set_xlabel("trials")
    ax.grid(alpha=0.3)
    ax.legend()
    _save(fig, path)
    return path
