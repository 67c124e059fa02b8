"""The first exploration study's figures (results/exploration/*.png), drawn from its rows.

``learning_curves.png`` (:func:`draw`), ``summary.png`` (:func:`draw_summary`: the thesis of eq. (1)
in one figure, final rewards and the gradient's SNR against the control step), ``control.png``
(:func:`draw_control`) and ``gaits/best_and_worst.png`` (:func:`draw_gaits`). matplotlib's
pyplot comes from nmrl.analysis.plots (the Agg backend).
"""

from __future__ import annotations

import pathlib
from typing import Sequence

import numpy as np

from nmrl.analysis import gait_pictures, stats
from nmrl.analysis.exploration_answers import cells, finished
from nmrl.paper.control_step import DELTA_0
from nmrl.analysis.exploration_report import ms as _ms
from nmrl.analysis.plots import plt
from nmrl.runs import store


def curves(src: pathlib.Path, rows: Sequence[dict]) -> dict[tuple[float, str], list[tuple[np.ndarray, np.ndarray]]]:
    """``{(control_dt, exploration): [(simulated s summed over environments, avg reward per s)]}``,
    one pair per run of ``rows`` (the grid's points: ``grid/dt{dt}/{exploration}/points/s{seed}``)."""
    out: dict = {}
    for r in rows:
        dt = float(r["control_dt"])
        p = pathlib.Path(src) / "grid" / f"dt{dt:g}" / r["exploration"] / "points" / f"s{int(r['seed'])}"
        m = store.read_metrics(p)
        if not m:
            continue
        n = int(r["control_steps"]) / max(1, int(m[-1]["step"]))  # environments
        x = np.array([q["step"] for q in m], float) * n * dt
        y = np.array([q["avg_reward"] for q in m], float) / DELTA_0
        out.setdefault((dt, r["exploration"]), []).append((x, y))
    return out


def _save(fig, path: pathlib.Path) -> pathlib.Path:
    """Write ``fig`` to ``path`` atomically (a reader never sees half a PNG) at its own size and dpi
    (the published figures are not cropped) and close it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        with store.atomic_path(path) as tmp:
            fig.savefig(tmp)
    finally:
        plt.close(fig)
    return path


def draw_control(ctl: dict, path: pathlib.Path) -> pathlib.Path:
    """The samples-per-update control's learning curves (``control.png``): the exploring policy's
    average reward per second of the control and of `white` at the finest and the coarsest control
    step (mean and 95% t-band over seeds), against the PPO iteration (the same Adam steps; the
    control's and the finest step's with the same samples per Adam step) and against one run's
    simulated seconds (the control has ``envs_factor`` times as many per iteration)."""
    series = [("control", f"white {_ms(ctl['coarse'])}, {ctl['envs_factor']}× environments (control)", "C3", "-"),
              ("white_fine", f"white {_ms(ctl['fine'])}", "C0", "-"),
              ("white_coarse", f"white {_ms(ctl['coarse'])}", "C0", "--")]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), dpi=110, sharey=True)
    for key, label, color, ls in series:
        c = (ctl.get("iterations") or {}).get(key) or []
        if not c:
            continue
        it = np.array([r["iteration"] for r in c], float)
        m, h = np.array([r["mean"] for r in c]), np.array([r["ci95"] for r in c])
        for ax, x in zip(axes, (it, it * ctl["seconds_per_iteration"][key])):
            ax.plot(x, m, color=color, ls=ls, lw=2, label=f"{label} ({c[0]['runs']} seeds)")
            ax.fill_between(x, m - h, m + h, color=color, alpha=0.15, lw=0)
    axes[0].set_xlabel("PPO iteration (the same Adam steps)")
    axes[1].set_xlabel("simulated seconds of one run (all environments)")
    axes[0].set_ylabel("average reward per second (exploring)")
    for ax in axes:
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8, loc="lower right")
    fig.suptitle("The samples-per-update control", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def draw(src: pathlib.Path, rows: Sequence[dict], dts: Sequence[float], processes: Sequence[str],
         path: pathlib.Path) -> pathlib.Path:
    """Learning curves, one panel per control step: every process's mean over seeds (thin lines:
    each seed), average reward per second of the exploring policy against simulated seconds."""
    cv = curves(src, rows)
    dts = sorted(dts, reverse=True)
    fig, axes = plt.subplots(1, len(dts), figsize=(5 * len(dts), 4.2), dpi=110, sharey=True, squeeze=False)
    for ax, dt in zip(axes[0], dts):
        for i, p in enumerate(processes):
            runs = cv.get((dt, p), [])
            for x, y in runs:
                ax.plot(x, y, color=f"C{i}", lw=0.6, alpha=0.35)
            if runs:
                k = min(len(x) for x, _ in runs)
                ax.plot(runs[0][0][:k], np.mean([y[:k] for _, y in runs], 0), color=f"C{i}", lw=2,
                        label=f"{p} ({len(runs)} seeds)")
        ax.set_title(f"δ = {dt * 1000:g} ms")
        ax.set_xlabel("simulated seconds (all environments)")
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8, loc="lower right")
    axes[0][0].set_ylabel("average reward per second (exploring)")
    fig.tight_layout()
    return _save(fig, path)


def draw_summary(rows: Sequence[dict], snr: Sequence[dict], dts: Sequence[float], processes: Sequence[str],
                 iterations: int, path: pathlib.Path) -> pathlib.Path:
    """The thesis in one figure (``summary.png``): the exploring and the deterministic policy's
    final average reward per second against the control step, one line per process (mean and 95%
    t-interval over the finished seeds; x: each seed), and the gradient's SNR per second of
    experience and tr Cov (seed 0; solid: mid-training, dashed: initial policy)."""
    done = finished(rows, iterations)
    dts = sorted(dts, reverse=True)
    fig, axes = plt.subplots(1, 4, figsize=(20, 4.6), dpi=110)
    for ax, key, title in ((axes[0], "avg_reward_per_s", "exploring policy, last iteration"),
                           (axes[1], "det_reward_per_s", "deterministic policy, 10 s")):
        c = cells(done, key)
        for i, p in enumerate(processes):
            xs, ms, hs = [], [], []
            for dt in dts:
                v = c.get((dt, p))
                if v is None:
                    continue
                m, h = stats.mean_ci95(v)
                xs.append(dt), ms.append(m), hs.append(h)
                shift = 1 + 0.03 * (i - (len(processes) - 1) / 2)
                ax.scatter([dt * shift] * len(v), v, s=14, color=f"C{i}", alpha=0.5, marker="x")
            if xs:
                ax.errorbar(xs, ms, yerr=hs, marker="o", capsize=4, color=f"C{i}", label=f"{p} (mean, 95% CI)")
        ax.set_title(title)
        ax.set_ylabel("average reward per second")
    for ax, key, title in ((axes[2], "snr_per_s", "gradient SNR per second of experience"),
                           (axes[3], "trcov", "tr Cov of the per-environment gradient")):
        for i, p in enumerate(processes):
            for policy, ls in (("mid", "-"), ("initial", "--")):
                rr = sorted((r for r in snr if r["exploration"] == p and r["policy"] == policy),
                            key=lambda r: -float(r["control_dt"]))
                if rr:
                    ax.errorbar([float(r["control_dt"]) for r in rr], [float(r[key]) for r in rr],
                                yerr=[float(r["trcov_ci"]) for r in rr] if key == "trcov" else None,
                                marker="o", ls=ls, color=f"C{i}", capsize=3, label=f"{p}, {policy}")
        ax.set_yscale("log" if key == "trcov" else "symlog", **({} if key == "trcov" else {"linthresh": 1e-4}))
        ax.set_title(title)
    for ax in axes:
        ax.set_xscale("log")
        ax.set_xticks(dts, [f"{dt * 1000:g}" for dt in dts])
        ax.minorticks_off()
        ax.set_xlim(max(dts) * 1.25, min(dts) / 1.25)  # coarse to fine, every control step in view
        ax.set_xlabel("control step δ [ms]")
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
        else:
            ax.text(0.5, 0.5, "nothing finished yet", ha="center", va="center", transform=ax.transAxes, color="0.4")
    fig.tight_layout()
    return _save(fig, path)


def draw_gaits(gaits: Sequence[tuple[str, pathlib.Path]], path: pathlib.Path, every_s: float = 0.1,
               span_s: float = 3.0) -> pathlib.Path:
    """The strobes of the given gaits (``(title, trajectory.npz)`` as `nmrl eval` writes it) one above
    the other at one scale: every panel spans the same metres in x and y, so how far each robot gets
    in ``span_s`` seconds, and the height it runs at, compare at a glance."""
    runs = []
    for title, f in gaits:
        with np.load(f) as z:
            pos, dt = np.asarray(z["pos"], float), float(z["control_dt"])
        frames = gait_pictures.strobe_frames(pos, dt, every_s, span_s)
        runs.append((title, pos, dt, frames, gait_pictures.strobe_extent(pos, frames)))
    x_lo = min(r[4][0] for r in runs)
    x_hi = max(r[4][1] for r in runs)
    y_hi = max(r[4][2] for r in runs)
    scale = min(1.6, 20.0 / (x_hi - x_lo))  # inches per metre, the widest picture at most 20 in
    fig, axes = plt.subplots(len(runs), 1, squeeze=False, dpi=100,
                             figsize=(scale * (x_hi - x_lo) + 1.0, len(runs) * (scale * (y_hi + 0.1) + 0.9)))
    for ax, (title, pos, dt, frames, _) in zip(axes[:, 0], runs):
        gait_pictures.draw_strobe(ax, pos, frames, dt, (x_lo, x_hi, y_hi), every_s, title)
    fig.tight_layout()
    return _save(fig, path)
