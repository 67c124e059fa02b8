"""Pictures of a gait from its joint positions (``pos``: (T+1, 10, 2), (x, y) per control step,
frame 0 the initial pose, as :mod:`nmrl.analysis.evaluate` records them): the Fig.-4-like strobe,
one stick figure every 0.1 s with joints sized by their mass (Sec. V-A), and a real-time animation
with the camera on the trunk. matplotlib's Agg backend only; no JAX, so published trajectories
can be redrawn without building the robot."""

from __future__ import annotations

import math
import os
import pathlib
from typing import Sequence

import numpy as np

from nmrl.paper import geometry as g
from nmrl.runs.store import atomic_path

GIF_FPS = 25.0


def pyplot():
    """matplotlib's pyplot on the Agg backend (nmrl.analysis.plots), imported when first drawn."""
    from nmrl.analysis.plots import plt

    return plt


def _marker_sizes(scale: float) -> np.ndarray:
    return scale * g.MASSES  # heavier joints bigger (hip 4 kg, head 2 kg)


def strobe_frames(pos: np.ndarray, control_dt: float, every_s: float = 0.1, span_s: float = 3.0) -> list[int]:
    """The frames a strobe shows: one every ``every_s`` seconds of the first ``span_s``, poses with a
    non-finite joint left out (frame 0 alone if none is finite)."""
    k = max(1, int(round(every_s / control_dt)))
    last = min(len(pos) - 1, int(round(span_s / control_dt)))
    return [i for i in range(0, last + 1, k) if np.all(np.isfinite(pos[i]))] or [0]


#: the most poses one strobe draws (beyond it they overlap into a smear)
STROBE_POSES = 30


def strobe_every(span_s: float) -> float:
    """The spacing [s] of a strobe over ``span_s`` seconds: the paper's Fig. 4 spacing of 0.1 s up to
    3 s, beyond it the next multiple of 0.05 s that draws at most :data:`STROBE_POSES` poses."""
    return max(0.1, math.ceil(span_s / STROBE_POSES * 20 - 1e-9) / 20)


def strobe_extent(pos: np.ndarray, frames: Sequence[int]) -> tuple[float, float, float]:
    """``(x_lo, x_hi, y_hi)`` [m] that hold the given frames' poses with a margin."""
    P = pos[list(frames)]
    if not np.isfinite(P).any():
        return -1.0, 1.0, 1.0
    return (float(np.nanmin(P[..., 0])) - 0.2, float(np.nanmax(P[..., 0])) + 0.2,
            max(1.0, float(np.nanmax(P[..., 1])) + 0.15))


def draw_strobe(ax, pos: np.ndarray, frames: Sequence[int], control_dt: float, extent: tuple[float, float, float],
                every_s: float = 0.1, title: str | None = None) -> None:
    """The stick figure of each frame on ``ax`` (colour by time, joints sized by mass, Sec. V-A), the
    ground, and equal metres on both axes within ``extent`` (:func:`strobe_extent`)."""
    plt = pyplot()
    cmap = plt.get_cmap("viridis")
    sizes = _marker_sizes(10.0)
    for j, i in enumerate(frames):
        c = cmap(j / max(1, len(frames) - 1))
        p = pos[i]
        ax.plot(p[:, 0], p[:, 1], "-", color=c, lw=1.2, alpha=0.85)
        ax.scatter(p[:, 0], p[:, 1], s=sizes, color=c, zorder=3, edgecolors="none")
    x_lo, x_hi, y_hi = extent
    ax.axhline(0.0, color="0.3", lw=1.5)
    ax.set_xlim(x_lo, x_hi)
    ax.set_ylim(-0.1, y_hi)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    dt_frames = max(1, int(round(every_s / control_dt))) * control_dt
    ax.set_title((title + "\n" if title else "") + f"every {dt_frames:.2f} s, "
                 f"t = 0 to {frames[-1] * control_dt:.2f} s", fontsize=9)


def plot_strobe(
    pos: np.ndarray,
    control_dt: float,
    path: str | os.PathLike,
    *,
    every_s: float = 0.1,
    span_s: float = 3.0,
    title: str | None = None,
) -> pathlib.Path:
    """A Fig.-4-like strobe: the stick figure every ``every_s`` seconds of the first ``span_s``.

    ``pos``: (T+1, 10, 2) joint positions (x, y) per control step, frame 0 the initial pose.
    """
    plt = pyplot()
    path = pathlib.Path(path)
    frames = strobe_frames(pos, control_dt, every_s, span_s)
    extent = strobe_extent(pos, frames)
    x_lo, x_hi, y_hi = extent
    width = min(24.0, max(5.0, 2.0 * (x_hi - x_lo) + 1.0))
    fig, ax = plt.subplots(figsize=(width, 0.25 + 2.0 * (y_hi + 0.1) + 0.6), dpi=100)
    draw_strobe(ax, pos, frames, control_dt, extent, every_s, title)
    fig.tight_layout()
    from nmrl.analysis.plots import save

    return save(fig, path)


def write_gif(
    pos: np.ndarray,
    control_dt: float,
    path: str | os.PathLike,
    *,
    fps: float = GIF_FPS,
    half_width: float = 1.5,
) -> pathlib.Path:
    """An animation of the stick figure in real time (about ``fps`` frames/s), the camera on the trunk."""
    import imageio.v3 as iio

    plt = pyplot()
    path = pathlib.Path(path)
    stride = max(1, int(round(1.0 / (fps * control_dt))))
    duration_ms = 1000.0 * stride * control_dt
    idx = list(range(0, len(pos), stride))
    fig, ax = plt.subplots(figsize=(5.0, 2.0), dpi=80)  # 3 m x 1.2 m at equal aspect
    fig.subplots_adjust(left=0.0, right=1.0, bottom=0.0, top=1.0)
    ax.set_axis_off()
    ax.set_aspect("equal")
    ax.set_xlim(-half_width, half_width)
    ax.set_ylim(-0.15, 1.05)
    (ground,) = ax.plot([], [], color="0.3", lw=1.5)
    (ticks,) = ax.plot([], [], "|", color="0.3", ms=6)
    (line,) = ax.plot([], [], "-", color="tab:blue", lw=2)
    dots = ax.scatter(np.zeros(10), np.zeros(10), s=_marker_sizes(8.0), color="tab:red", zorder=3)
    text = ax.text(0.02, 0.92, "", transform=ax.transAxes, fontsize=8)
    frames = []
    last_cx = 0.0
    try:
        for i in idx:
            p = pos[i]
            cx = 0.5 * (p[3, 0] + p[4, 0])
            cx = float(cx) if np.isfinite(cx) else last_cx
            last_cx = cx
            lo, hi = cx - half_width, cx + half_width
            ax.set_xlim(lo, hi)
            ground.set_data([lo, hi], [0.0, 0.0])
            tx = np.arange(math.floor(lo * 2) / 2, hi + 0.5, 0.5)  # ground marks every 0.5 m
            ticks.set_data(tx, np.zeros_like(tx))
            line.set_data(p[:, 0], p[:, 1])
            dots.set_offsets(p)
            text.set_text(f"t = {i * control_dt:5.2f} s")
            fig.canvas.draw()
            frames.append(np.asarray(fig.canvas.buffer_rgba())[..., :3].copy())
    finally:
        plt.close(fig)
    with atomic_path(path) as tmp:
        iio.imwrite(tmp, np.stack(frames), duration=duration_ms, loop=0)
    return path
