"""Figures: a field uniform to round-off is drawn uniform, and plotting has no global
side effects on matplotlib (backend, pyplot's figure registry)."""

import subprocess
import sys

import numpy as np

from jaxform import plot


def _grid(n: int):
    """An n x n mesh of unit squares: node coordinates and element node ids."""
    x, y = np.meshgrid(np.arange(n + 1.0), np.arange(n + 1.0))
    coords = np.column_stack([x.ravel(), y.ravel()])
    i, j = np.meshgrid(np.arange(n), np.arange(n))
    a = (j * (n + 1) + i).ravel()
    return coords, np.column_stack([a, a + 1, a + n + 2, a + n + 1])


def _colour_bar(fig):
    fig.canvas.draw()
    bar = fig.axes[1]
    ticks = [t.get_text() for t in bar.get_yticklabels() if t.get_text()]
    return ticks, bar.yaxis.get_offset_text().get_text()


def test_round_off_field_is_drawn_uniform(tmp_path):
    """The seed scene's final eqps: 0.827470779 everywhere, with round-off of 1e-15 in a
    checkerboard.  Reference: the field is uniform (spread 1e-15 < 1e-9 x 0.83), so one
    face colour and a colour bar whose one tick reads the value, with no offset text."""
    coords, el = _grid(4)
    checker = (np.arange(16) + np.arange(16) // 4) % 2
    values = 0.827470779 + 1e-15 * checker
    fig = plot.cell_contours(coords, el, values, tmp_path / "eqps.png", "t", "eqps")
    faces = fig.axes[0].collections[0].get_facecolors()
    assert len(np.unique(faces, axis=0)) == 1
    ticks, offset = _colour_bar(fig)
    assert ticks == ["0.827470779"] and offset == ""
    assert (tmp_path / "eqps.png").stat().st_size > 5_000
    # an all-zero field (e.g. eqps of an elastic run) too
    fig0 = plot.cell_contours(coords, el, np.zeros(16), tmp_path / "zero.png", "t", "eqps")
    assert _colour_bar(fig0) == (["0"], "")


def test_real_variation_keeps_its_colours(tmp_path):
    """A spread of 1e-6 of the magnitude is not round-off: the checkerboard is drawn in
    two colours (the extremes of the colour map)."""
    coords, el = _grid(4)
    checker = (np.arange(16) + np.arange(16) // 4) % 2
    fig = plot.cell_contours(coords, el, 0.8 + 1e-6 * checker, tmp_path / "v.png", "t", "v")
    faces = fig.axes[0].collections[0].get_facecolors()
    assert len(np.unique(faces, axis=0)) == 2


def test_plotting_changes_no_global_matplotlib_state(tmp_path):
    """Reference: the backend chosen before importing jaxform.plot ('svg', not Agg) is the
    backend after importing it and drawing a figure; pyplot keeps no figure open."""
    script = f"""
import matplotlib
matplotlib.use("svg")
import numpy as np
import jaxform.plot as p
import matplotlib.pyplot as plt
p.force_stroke(np.arange(3.0), np.arange(3.0), {str(tmp_path / "f.png")!r}, "t")
print(matplotlib.get_backend(), len(plt.get_fignums()))
"""
    out = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120, check=False
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["svg", "0"]
    assert (tmp_path / "f.png").stat().st_size > 5_000
