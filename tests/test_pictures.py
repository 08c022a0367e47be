"""Pictures with the dies: section plots draw each die where it stands at that instant,
contact profiles run along the die's arc length, the animation has its frames."""

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from jaxform import plot
from jaxform.config import load_config
from jaxform.dies import sample_rounded
from jaxform.driver import animation_rows
from jaxform.postprocess import arc_position, contact_profile, die_outlines
from jaxform.scenes import build_scene

ROOT = Path(__file__).resolve().parents[1]
SMALL = ["mesh.nr=3", "mesh.nz=3"]


def _on_line(points, a, b):
    """Distance of points from the infinite line through a and b."""
    t = (b - a) / np.linalg.norm(b - a)
    rel = points - a
    return np.abs(rel[:, 0] * t[1] - rel[:, 1] * t[0])


def test_section_plots_draw_each_die_where_it_stands(tmp_path):
    """Reference: the closed-die scene's top die at t = 0.6 t_end: its rounded profile
    (dies.sample_rounded of die.profile_mm) shifted down by half the ram speed times t
    (half-height model), computed here from the config; the drawn line must hold it to
    1e-12 mm, its two extra end points on the end segments' lines (the die's infinite
    ends).  The cell, nodal, mesh and flow-line plots label both axes with units and the
    colour bar with the field's name and unit."""
    cfg = load_config(ROOT / "configs" / "closed_die.toml", SMALL)
    sc = build_scene(cfg)
    t = 0.6 * sc.t_end
    d = sc.inputs.die
    expected = sample_rounded(np.asarray(cfg["die"]["profile_mm"]), cfg["die"]["corner_radius_mm"])
    expected = expected - np.array([0.0, 0.5 * cfg["die"]["speed_mm_s"] * t])
    frame = plot.SectionFrame(("r [mm]", "z [mm]"), die_outlines(sc, t))
    coords = np.asarray(sc.inputs.coords)
    el = np.asarray(sc.mesh.elements)
    figs = [
        plot.cell_contours(coords, el, np.arange(len(el), dtype=float), tmp_path / "c.png",
                           "eqps", "equivalent plastic strain [-]", frame),
        plot.nodal_contours(coords, el, coords[:, 1] + 673.0, tmp_path / "n.png", "T",
                            "temperature [K]", frame),
        plot.deformed_mesh(coords, coords, el, tmp_path / "m.png", "mesh", frame),
        plot.flow_lines(coords, el, [coords[:3]], tmp_path / "f.png", "flow lines", frame),
    ]  # fmt: skip
    for fig, bar in zip(figs, ["equivalent plastic strain [-]", "temperature [K]", None, None]):
        lines = plot.die_lines(fig)
        assert list(lines) == ["top"]
        drawn = lines["top"]
        np.testing.assert_allclose(drawn[1:-1], expected, rtol=0, atol=1e-12)
        assert _on_line(drawn[:1], expected[0], expected[1])[0] < 1e-12
        assert _on_line(drawn[-1:], expected[-2], expected[-1])[0] < 1e-12
        ax = fig.axes[0]
        assert (ax.get_xlabel(), ax.get_ylabel()) == ("r [mm]", "z [mm]")
        if bar is not None:
            assert fig.axes[1].get_ylabel() == bar
    assert float(d.travel_at(t)) == pytest.approx(0.5 * cfg["die"]["speed_mm_s"] * t, rel=1e-14)


def test_arc_length_runs_down_a_vertical_die_wall(tmp_path):
    """Reference: the flash scene's lip, the vertical wall r = 6.5 mm from z = 4.5 down to
    3.0 mm (die.profile_mm): nodes on it at one r get arc lengths that rise as z falls,
    one for one (ds = -dz to 1e-9 mm), where r would put them all at one abscissa; the
    contact plot draws them at those arc lengths, in order."""
    sc = build_scene(load_config(ROOT / "configs" / "closed_die_flash.toml", SMALL))
    top = die_outlines(sc, 0.0)["top"]
    z = np.linspace(4.3, 3.35, 7)  # clear of the fillets (corner radius 0.3 mm)
    wall = np.column_stack([np.full_like(z, 6.5), z])
    s, dist = arc_position(top, wall)
    assert np.all(dist < 1e-9)
    assert np.all(np.diff(s) > 0)
    np.testing.assert_allclose(np.diff(s), -np.diff(z), rtol=0, atol=1e-9)
    prof = dict(s_mm=s[::-1], die=np.full(7, "top"), r_mm=wall[::-1, 0],
                pressure_MPa=np.linspace(1.0, 2.0, 7), shear_MPa=np.zeros(7),
                status=np.full(7, 2))  # fmt: skip
    fig = plot.contact_profiles({1.0: prof}, tmp_path / "p.png")
    x = fig.axes[0].get_lines()[0].get_xdata()
    np.testing.assert_allclose(x, np.sort(s), rtol=0, atol=0)
    assert "arc length" in fig.axes[1].get_xlabel()


def test_contact_profile_arc_length_on_a_flat_die_is_the_radius():
    """Reference: the seed scene's flat top die starts on the axis and runs along +r, so a
    top-face node's arc length is its r (1e-12 mm); its die is 'top'."""
    sc = build_scene(load_config(ROOT / "configs" / "upsetting_seed.toml", SMALL))
    lay = sc.model.layout
    n_c = lay.n_contact
    prof = contact_profile(sc, np.zeros(lay.n_dofs), np.zeros(n_c), np.ones(n_c, int), 3.0)
    on_top = prof["z_mm"] == prof["z_mm"].max()
    np.testing.assert_allclose(prof["s_mm"][on_top], prof["r_mm"][on_top], rtol=0, atol=1e-12)
    assert set(prof["die"]) == {"top"}


def test_animation_has_one_frame_per_chosen_row(tmp_path):
    """Reference: 11 history rows and at most 4 frames: rows 0, 3, 7, 10 (first and last
    kept); the GIF read back by Pillow has that many frames, the dies drawn in each."""
    rows = animation_rows(11, 4)
    assert rows.tolist() == [0, 3, 7, 10]
    coords = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    el = np.array([[0, 1, 2, 3]])
    frames = [
        (0.1 * k, 0.01 * k, coords * [1 + 0.01 * k, 1 - 0.01 * k], el, np.array([0.01 * k]),
         {"top": np.array([[-1.0, 1.0 - 0.01 * k], [2.0, 1.0 - 0.01 * k]])})
        for k in rows
    ]  # fmt: skip
    n = plot.animation(frames, tmp_path / "a.gif", "eqps", "equivalent plastic strain [-]")
    assert n == 4
    with Image.open(tmp_path / "a.gif") as gif:
        assert gif.n_frames == 4


def test_force_stroke_draws_each_die_and_each_blow(tmp_path):
    """Reference: the history columns given: one curve per die beside the ram's, and with
    a blow column one curve per blow, each from the row before its first (the stroke the
    blow starts from) to its last."""
    stroke = np.array([0.0, 0.1, 0.2, 0.3, 0.4])
    force = np.array([0.0, 10.0, 12.0, 15.0, 16.0])
    fig = plot.force_stroke(stroke, force, tmp_path / "f.png", "t",
                            per_die={"top": force, "bottom": 0.5 * force})  # fmt: skip
    labels = [line.get_label() for line in fig.axes[0].get_lines()]
    assert labels == ["jaxform", "top die", "bottom die"]
    blows = np.array([0, 1, 1, 2, 2])
    fig = plot.force_stroke(stroke, force, tmp_path / "b.png", "t", blows=blows)
    lines = fig.axes[0].get_lines()
    assert [line.get_label() for line in lines] == ["blow 1", "blow 2"]
    np.testing.assert_array_equal(lines[0].get_xdata(), [0.0, 0.1, 0.2])
    np.testing.assert_array_equal(lines[1].get_xdata(), [0.2, 0.3, 0.4])


def test_contact_profile_names_the_die_each_node_faces():
    """Reference: the seed billet at full height between flat dies: the bottom die's
    profile is walked from the outside to the axis ([1, z] to [0, z], jaxform.scenes), so
    a bottom-face node's arc length is 1 - r and a top-face node's is r (1e-12 mm)."""
    sc = build_scene(load_config(ROOT / "configs" / "upsetting_seed.toml",
                                 SMALL + ["billet.full_height=true"]))  # fmt: skip
    lay = sc.model.layout
    n_c = lay.n_contact
    prof = contact_profile(sc, np.zeros(lay.n_dofs), np.zeros(n_c), np.ones(n_c, int), 0.0)
    top = prof["z_mm"] == prof["z_mm"].max()
    bottom = prof["z_mm"] == prof["z_mm"].min()
    assert set(prof["die"][top]) == {"top"} and set(prof["die"][bottom]) == {"bottom"}
    np.testing.assert_allclose(prof["s_mm"][top], prof["r_mm"][top], rtol=0, atol=1e-12)
    np.testing.assert_allclose(prof["s_mm"][bottom], 1.0 - prof["r_mm"][bottom], rtol=0,
                               atol=1e-12)  # fmt: skip
