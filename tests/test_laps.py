"""Laps and pockets told apart (jaxform.laps): a crease of the free surface is a lap with
its angle and depth, air between the material and a die is a pocket with its gap and
length; each is reported only where it persists to the end of the run.  Synthetic
sections with closed-form references."""

from pathlib import Path
from types import SimpleNamespace

import jax.numpy as jnp
import numpy as np
import pytest

from jaxform.config import load_config, typed
from jaxform.contact import TOUCH_GAP_MM, Frictionless
from jaxform.dies import RigidDie
from jaxform.laps import (
    POCKETS,
    WEDGES,
    FoldKind,
    columns,
    fold_columns,
    folds,
    laps,
    pockets,
    scene_folds,
    surface_folds,
)
from jaxform.rezone import gap_function
from jaxform.scenes import build_scene

ROOT = Path(__file__).resolve().parents[1]
W, H = 5.0, 3.0  # the synthetic section: a block [0, W] x [0, H], its top face free
ROOT_AT = np.array([2.0, 2.0])  # the crease's root, 1 mm under the top face


def _rot(v, deg):
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def _crease(theta_deg: float, right: tuple[float, ...] = (), bend_deg: float = 20.0):
    """(points, free_out) of the block with a crease of air-side angle theta in its top
    face, walked counter-clockwise: its left flank runs straight from the root to the top
    face (split into 4 collinear edges); its right flank straight to the top face, or,
    with ``right = (a, b)``, a mm along the crease, then b mm bent away from it by
    ``bend_deg``, then horizontally to the block's side."""
    half = np.radians(theta_deg) / 2
    u_left = np.array([-np.sin(half), np.cos(half)])
    u_right = np.array([np.sin(half), np.cos(half)])
    depth = H - ROOT_AT[1]
    left_mouth = ROOT_AT + depth / np.cos(half) * u_left
    left = [ROOT_AT + f * (left_mouth - ROOT_AT) for f in (0.25, 0.5, 0.75, 1.0)]
    if right:
        a, b = right
        bend = ROOT_AT + a * u_right
        mouth = bend + b * _rot(u_right, -bend_deg)  # clockwise: away from the left flank
        flank = [mouth, bend]
    else:
        mouth = ROOT_AT + depth / np.cos(half) * u_right
        flank = [mouth]
    pts = np.array([[0.0, 0.0], [W, 0.0], [W, mouth[1]], *flank, ROOT_AT, *left, [0.0, H]])
    free = np.zeros(len(pts), bool)
    free[2 : len(pts) - 1] = True  # the top face, from the block's side to the axis
    return pts, free


def _no_die(n):
    return np.full(n, np.inf)


def test_a_crease_is_a_wedge_with_its_angle_and_depth():
    """A symmetric crease of air-side angle 8 deg whose root lies 1 mm under the top face:
    a wedge of 8 deg (1e-12 deg) at the root (1e-12 mm), its depth the flank's length
    1 / cos(4 deg) mm (1e-12 mm: the left flank's four collinear edges do not end it, the
    turn onto the top face does).  An asymmetric one, its right flank 0.3 mm along the
    crease then 0.2 mm bent 20 deg away (less than FLANK_TURN_DEG, so the flank runs on)
    before the top face: the depth is the shorter flank, 0.3 + 0.2 mm (1e-12).  No die: no
    pocket, and the narrowest fold is the wedge."""
    pts, free = _crease(8.0)
    f = surface_folds(pts, free, _no_die(len(pts)), TOUCH_GAP_MM)
    assert abs(f.wedge.angle_deg - 8.0) <= 1e-12
    assert np.hypot(f.wedge.r_mm - ROOT_AT[0], f.wedge.z_mm - ROOT_AT[1]) <= 1e-12
    assert abs(f.wedge.depth_mm - 1.0 / np.cos(np.radians(4.0))) <= 1e-12
    assert f.pocket.angle_deg == 180.0 and f.kind == FoldKind.WEDGE
    assert f.narrowest() == (f.wedge.angle_deg, f.wedge.r_mm, f.wedge.z_mm, f.wedge.depth_mm)
    pts, free = _crease(8.0, right=(0.3, 0.2))
    f = surface_folds(pts, free, _no_die(len(pts)), TOUCH_GAP_MM)
    assert abs(f.wedge.angle_deg - 8.0) <= 1e-12
    assert abs(f.wedge.depth_mm - 0.5) <= 1e-12
    pts, free = _crease(8.0, right=(0.3, 0.2), bend_deg=50.0)  # the bend is the mouth
    assert abs(surface_folds(pts, free, _no_die(len(pts)), TOUCH_GAP_MM).wedge.depth_mm
               - 0.3) <= 1e-12  # fmt: skip


def _history(rows, stroke=None):
    h = columns(rows)
    h["stroke_mm"] = np.arange(len(rows), dtype=float) if stroke is None else stroke
    return h


def test_a_persisting_crease_is_a_lap_and_one_that_reopens_is_not():
    """A crease narrowing 30 -> 8 -> 6 -> 5 deg in place is one lap from row 1 (the first
    below output.lap_angle_deg = 10), angle 8 -> 5 deg and depth 1 / cos(2.5 deg) at the
    end (1e-12); narrowing to 6 deg and opening to 12 deg again it is a fold but no lap.
    Neither is a pocket."""
    closing = [surface_folds(*p, _no_die(len(p[0])), TOUCH_GAP_MM)
               for p in (_crease(a) for a in (30.0, 8.0, 6.0, 5.0))]  # fmt: skip
    h = _history(closing)
    np.testing.assert_array_equal(h["fold_kind"], [FoldKind.WEDGE] * 4)
    (lap,) = laps(h, 10.0)
    assert (lap["row"], lap["last_row"]) == (1, 3)
    assert abs(lap["angle_deg"] - 8.0) <= 1e-12 and abs(lap["end_angle_deg"] - 5.0) <= 1e-12
    assert abs(lap["depth_mm"] - 1.0 / np.cos(np.radians(2.5))) <= 1e-12
    assert pockets(h, 10.0) == []
    reopening = closing[:3] + [
        surface_folds(*p, _no_die(len(p[0])), TOUCH_GAP_MM) for p in [_crease(12.0)]
    ]
    h = _history(reopening)
    assert [(f["row"], f["last_row"], f["persists"]) for f in folds(h, 10.0, WEDGES)] == [
        (1, 2, False)
    ]
    assert laps(h, 10.0) == [] and pockets(h, 10.0) == []


@pytest.fixture(scope="module")
def seed():
    """The seed section on 2 x 2 (R = 2.5 mm, half height 3.75 mm, a flat die on the top
    face at t = 0)."""
    cfg = load_config(ROOT / "configs" / "upsetting_seed.toml",
                      ["output.plots=false", "mesh.nr=2", "mesh.nz=2"])  # fmt: skip
    return build_scene(typed(cfg))


def test_a_pocket_under_a_flat_die_is_a_pocket_and_closing_it_leaves_none(seed):
    """The top face's middle node 0.1 mm off the flat die between two nodes on it: a
    pocket of gap 0.1 mm (1e-12) and length 2 hypot(1.25, 0.1) along the surface (1e-12),
    angle atan(0.1 / hypot(1.25, 0.1)) (1e-12 deg), at that node; the narrowest fold is
    the pocket, and no wedge is below 170 deg.  Kept to the end it is a persisting pocket
    and no lap; closed onto the die in the last row (its contact fronts meet) it is
    neither."""
    pos = np.asarray(seed.inputs.coords).copy()
    top = seed.mesh.node_sets["top"]
    mid = top[np.argsort(pos[top, 0])][1]
    r = pos[:, 0].max()
    rows = []
    for g in (0.1, 0.1, 0.05, 0.0):
        p = pos.copy()
        p[mid, 1] -= g
        rows.append(p)
    f = scene_folds(seed, rows[0], 0.0)
    assert abs(f.pocket.gap_mm - 0.1) <= 1e-12
    assert abs(f.pocket.length_mm - 2.0 * np.hypot(r / 2, 0.1)) <= 1e-12
    assert abs(f.pocket.angle_deg - np.degrees(np.arctan(0.1 / np.hypot(r / 2, 0.1)))) <= 1e-12
    assert (f.pocket.r_mm, f.pocket.z_mm) == tuple(rows[0][mid])
    assert f.kind == FoldKind.POCKET and f.wedge.angle_deg > 170.0
    h = fold_columns(seed, np.stack(rows), np.zeros(len(rows)))
    h["stroke_mm"] = np.zeros(len(rows))
    np.testing.assert_array_equal(h["fold_kind"], [2, 2, 2, 0])
    assert pockets(h, 10.0) == [] and laps(h, 10.0) == []  # closed at the end
    (fold,) = folds(h, 10.0, POCKETS)
    assert (fold["row"], fold["last_row"], fold["persists"]) == (0, 2, False)
    kept = {k: v[:3] for k, v in h.items()}
    (pocket,) = pockets(kept, 10.0)
    assert abs(pocket["gap_mm"] - 0.05) <= 1e-12 and laps(kept, 10.0) == []


def test_a_pocket_along_a_rounded_die_corner():
    """A flat punch whose edge (2, 1) is rounded by an arc of radius 0.5 mm (centre (1.5,
    1.5)); the material wraps around it, its surface on the punch's face, on the arc at
    -10 and -80 deg and on the wall, and one vertex at -45 deg 0.02 mm off the arc: a
    pocket of gap 0.02 mm (the die's gap there, |x - c| - 0.5, to 1e-12), its length the
    two chords from the touching vertices (1e-12); an arc vertex at -45 deg on the die
    instead: no pocket."""
    die = RigidDie(points=jnp.array([[0.0, 1.0], [2.0, 1.0], [2.0, 3.0]]),
                   path_time_s=jnp.array([0.0, 1.0]), path_travel_mm=jnp.array([0.0, 0.0]),
                   friction=Frictionless(), corner_radius=jnp.asarray(0.5))  # fmt: skip
    c, rho, g = np.array([1.5, 1.5]), 0.5, 0.02

    def arc(deg, radius=rho):
        return c + radius * np.array([np.cos(np.radians(deg)), np.sin(np.radians(deg))])

    def section(off: float):
        # counter-clockwise, the material below and right of the punch: bottom, right
        # side, top, down the punch's wall, round the arc, along its face, down the axis
        pts = np.array([[0.0, -2.0], [4.0, -2.0], [4.0, 3.0], [2.0, 3.0], [2.0, 2.0],
                        arc(-10.0), arc(-45.0, rho + off), arc(-80.0), [1.0, 1.0],
                        [0.0, 1.0]])  # fmt: skip
        free = np.zeros(len(pts), bool)
        free[3:9] = True  # from (2, 3) to (0, 1): the surface the punch may touch
        return pts, free

    pts, free = section(g)
    gap = gap_function(die, 0.0)(pts)[0]
    assert np.all(np.abs(np.delete(gap, [0, 1, 2, 6, 9])) <= 1e-12)  # the others touch
    f = surface_folds(pts, free, np.asarray(gap), TOUCH_GAP_MM)
    assert abs(f.pocket.gap_mm - g) <= 1e-12
    chords = np.linalg.norm(pts[6] - pts[5]) + np.linalg.norm(pts[7] - pts[6])
    assert abs(f.pocket.length_mm - chords) <= 1e-12
    assert (f.pocket.r_mm, f.pocket.z_mm) == tuple(pts[6]) and f.kind == FoldKind.POCKET
    pts, free = section(0.0)
    closed = surface_folds(pts, free, gap_function(die, 0.0)(pts)[0], TOUCH_GAP_MM)
    assert closed.pocket.angle_deg == 180.0


def test_the_command_line_and_the_plot_tell_laps_from_pockets(tmp_path):
    """One line per lap (with its depth) and per pocket (gap in micrometres, length, 'not
    a lap'), in a process headed by its operation; the deformed-mesh plot marks a pocket
    with its own marker and legend entry."""
    from jaxform import plot
    from jaxform.cli import fold_lines

    lap = dict(stroke_mm=1.59, end_r_mm=2.7, end_z_mm=1.37, angle_deg=9.0, end_angle_deg=5.1,
               depth_mm=0.25)  # fmt: skip
    pocket = dict(stroke_mm=4.7, end_r_mm=2.113, end_z_mm=3.13, gap_mm=0.0062, length_mm=1.68)
    lines = fold_lines(SimpleNamespace(laps=[lap], pockets=[pocket]))
    assert len(lines) == 2
    assert lines[0].startswith("lap: ") and "depth 0.25 mm" in lines[0]
    assert lines[1].startswith("pocket (underfill along the die): ")
    assert "gap 6.2 um" in lines[1] and "1.68 mm long" in lines[1] and "not a lap" in lines[1]
    # in a process each is headed by the operation to whose end it persists
    tagged = fold_lines(SimpleNamespace(laps=[], pockets=[{**pocket, "operation": "blocker"}]))
    assert tagged == ["blocker: " + lines[1]]
    coords = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    fig = plot.deformed_mesh(coords, coords, np.array([[0, 1, 2, 3]]), tmp_path / "m.png",
                             "mesh", marks=plot.Marks(((0.5, 1.0),), ((1.0, 0.5),)))  # fmt: skip
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert labels == ["lap", "pocket (underfill)"]
