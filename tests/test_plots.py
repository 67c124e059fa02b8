"""nmrl.analysis.plots.save, the one figure save of the project: the picture holds the options it was
given (its size in pixels is figsize x dpi, read back with Pillow), the figure is closed, nothing
but the picture is left in its folder, and a save that fails leaves the old picture as it was."""

from __future__ import annotations

import pytest
from PIL import Image

from nmrl.analysis.plots import plt, save


def test_save_writes_the_picture_with_its_options_and_closes_the_figure(tmp_path):
    fig, ax = plt.subplots(figsize=(3.0, 2.0))
    ax.plot([0, 1], [1, 0])
    path = save(fig, tmp_path / "a.png", dpi=40)
    assert path == tmp_path / "a.png"
    with Image.open(path) as img:
        assert img.format == "PNG" and img.size == (120, 80)
    assert fig.number not in plt.get_fignums()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png"]


def test_a_failed_save_leaves_the_old_picture_and_closes_the_figure(tmp_path):
    path = tmp_path / "a.png"
    path.write_bytes(b"the old picture")
    fig, _ = plt.subplots()
    with pytest.raises(ValueError):
        save(fig, path, format="no-such-format")
    assert path.read_bytes() == b"the old picture"
    assert fig.number not in plt.get_fignums()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png"]


@pytest.mark.parametrize("trials, reduced", [(205, True), (100_016, False)])
def test_fig3_says_when_a_run_is_far_below_the_papers_budget(tmp_path, monkeypatch, trials, reduced):
    from nmrl.analysis import plots

    seen = {}
    monkeypatch.setattr(plots, "_save", lambda fig, path: seen.setdefault("labels", [
        t.get_text() for ax in fig.axes if ax.get_legend() for t in ax.get_legend().get_texts()]))
    rows = [{"l": l, "seed": s, "trials": trials, "avg_reward": 0.1 * l + s, "diverged": False}
            for l in (1, 10) for s in (0, 1)]
    curves = {l: [[{"trials": trials, "avg_reward": 0.1}]] for l in (1, 10)}
    plots.fig3(rows, curves, tmp_path / "fig3.png")
    paper = next(t for t in seen["labels"] if t.startswith("paper"))
    assert ("not comparable" in paper and f"this run: {trials:,}" in paper) == reduced
