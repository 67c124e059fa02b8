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
