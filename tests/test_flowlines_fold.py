"""The fold measure of the flow lines (jaxform.flowlines.line_fold, self_folds, fold_depth)
on constructed polylines whose turn, fold and depth are known, and (slow) on the lap scene
of experiments/lap_scene.py, where the lap is known from its refinement check."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from experiment_loader import experiment

import jaxform
from jaxform.flowlines import (
    FOLD_TURN_DEG,
    FlowLines,
    flow_lines,
    fold_depth,
    largest_turn,
    line_fold,
    self_folds,
)

ROOT = Path(__file__).resolve().parents[1]
SPACING = 0.5
STEP = SPACING / 5  # the lines' sampling


def _line(*pieces):
    return np.vstack(pieces)


def _straight(p0, p1, step=STEP):
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    n = max(int(np.ceil(np.linalg.norm(p1 - p0) / step)), 1)
    return p0 + np.linspace(0.0, 1.0, n + 1)[:, None] * (p1 - p0)


def _hairpin(gap=0.06, legs=1.5):
    """Out along z = 1 + gap from r = 1 to 1 + legs, round a semicircle of diameter gap,
    back along z = 1: a line folded flat onto itself, the fold's tip at (1 + legs + gap/2,
    1 + gap/2)."""
    out = _straight([1.0, 1.0 + gap], [1.0 + legs, 1.0 + gap])
    phi = np.linspace(0.5 * np.pi, -0.5 * np.pi, 9)[1:-1]
    tip = np.column_stack([1.0 + legs + 0.5 * gap * np.cos(phi),
                           1.0 + 0.5 * gap + 0.5 * gap * np.sin(phi)])  # fmt: skip
    back = _straight([1.0 + legs, 1.0], [1.0, 1.0])
    return _line(out, tip, back)


def test_straight_and_cornered_lines_do_not_fold():
    """A straight line turns by 0 (1e-12 deg); a line bent round a square corner by 90 deg
    (1e-9), round a fillet of radius 0.2 mm by 90 deg (1e-9): none reaches FOLD_TURN_DEG;
    a straight line with a 0.02 mm zigzag of period 2 samples turns by 2 atan(0.2) net
    (1e-9: its turns cancel instead of adding up)."""
    turn, _, _ = line_fold(_straight([0, 0], [3, 1]), SPACING)
    assert abs(turn) <= 1e-12
    corner = _line(_straight([0, 0], [0, 2]), _straight([0, 2], [2, 2])[1:])
    assert abs(line_fold(corner, SPACING)[0] - 90.0) <= 1e-9
    phi = np.linspace(np.pi, 0.5 * np.pi, 8)
    fillet = _line(_straight([0, 0], [0, 2]),
                   np.column_stack([0.2 + 0.2 * np.cos(phi), 2 + 0.2 * np.sin(phi)])[1:],
                   _straight([0.2, 2.2], [2, 2.2])[1:])  # fmt: skip
    assert abs(line_fold(fillet, SPACING)[0] - 90.0) <= 1e-9
    zig = _straight([0, 0], [3, 0])
    zig[1::2, 1] += 0.02
    assert abs(line_fold(zig, SPACING)[0] - np.degrees(2 * np.arctan(0.2))) <= 1e-9


def test_a_hairpin_folds_at_its_tip():
    """A line folded flat onto itself (legs 0.06 mm apart, a semicircular tip) turns by
    180 deg (1e-9) over the tip's 8 chords (1e-9), located at the tip's middle
    (1e-12 mm), its legs side by side (within 0.1 mm) over their 1.5 mm and half the tip
    (1e-9; within 0.05 mm only around the tip); the same hairpin opened to a U of 1 mm
    width turns by 180 deg only over more than a spacing of arc and is no fold."""
    turn, where, arc = line_fold(_hairpin(), SPACING)
    assert abs(turn - 180.0) <= 1e-9
    assert np.linalg.norm(where - [2.53, 1.03]) <= 1e-12
    chord = 0.06 * np.sin(np.pi / 16)  # the tip is sampled by 8 chords of a semicircle
    assert abs(arc - 8 * chord) <= 1e-9
    # its legs run side by side from the tip to their ends: 1.5 mm and half the tip
    assert abs(fold_depth(_hairpin(), where, 0.1) - (1.5 + 4 * chord)) <= 1e-9
    # legs 0.06 mm apart are not within 0.05 mm: the depth stops at the tip's sides
    assert fold_depth(_hairpin(), where, 0.05) < 4 * chord
    assert line_fold(_hairpin(gap=1.0), SPACING)[0] < FOLD_TURN_DEG


def test_self_folds_names_the_folded_line():
    """Three lines, straight, cornered, folded: self_folds reports the folded one only
    (its index, family and level, the tip's position), largest_turn is its 180 deg."""
    corner = _line(_straight([0, 0], [0, 2]), _straight([0, 2], [2, 2])[1:])
    polys = [_straight([0, 0.5], [3, 0.5]), corner, _hairpin()]
    pts = np.vstack(polys)[None]
    line = np.concatenate([np.full(len(p), k) for k, p in enumerate(polys)])
    lines = FlowLines(pts, line, np.array([0, 1, 0]), np.array([0.5, 0.0, 1.0]))
    (fold,) = self_folds(lines, SPACING)
    assert (fold.line, fold.family, fold.level) == (2, 0, 1.0)
    assert np.hypot(fold.r_mm - 2.53, fold.z_mm - 1.03) <= 1e-12
    assert abs(fold.depth_mm - (1.5 + 4 * 0.06 * np.sin(np.pi / 16))) <= 1e-9
    assert abs(largest_turn(lines, SPACING) - 180.0) <= 1e-9


@pytest.mark.slow  # the lap scene (experiments/lap_scene.py, 0.25 mm, 0.5 s): ~2-10 min
def test_the_boss_folds_over_into_a_lap_and_its_surface_line_folds_there(tmp_path):
    """A boss on a disk upset by a sticking die folds over onto the shoulder (the square
    root, 0.25 mm elements, 0.5 s steps, to a stroke of 1.64 mm): laps() reports one lap,
    from a stroke of 1.59 mm, at the boss's root near (2.69, 1.37) mm (the run of
    2026-11-26: 0.05 mm and 0.05 mm slack), and the flow lines fold there: only the surface
    line, at the lap's place at the end of the run (the root is a node of the mesh and a
    sample point of the line: 1e-9 mm), by 175 deg (2 deg), its legs side by side over
    0.25 mm (0.05 mm); no grid line turns by 150 deg.  The lap's depth (the wedge's shorter
    flank, jaxform.laps) is 0.21 mm (the run of 2026-11-26: 0.213; 0.05 mm slack), and the
    run has no pocket."""
    scene = experiment("lap_scene")
    args = scene.main_args(["run", "--out", str(tmp_path)])
    quiet = ["output.plots=false", "output.fields=false"]
    res = jaxform.run(str(scene.write_scene(tmp_path, args)), quiet)
    h = res.history
    (lap,) = res.laps
    assert abs(lap["stroke_mm"] - 1.59) <= 0.05
    assert np.hypot(lap["r_mm"] - 2.69, lap["z_mm"] - 1.37) <= 0.05
    lines = flow_lines(res, args.spacing)
    (fold,) = self_folds(lines, args.spacing)
    assert fold.family == 2 and abs(fold.turn_deg - 175.0) <= 2.0
    assert abs(fold.depth_mm - 0.25) <= 0.05
    assert np.hypot(fold.r_mm - h["wedge_r_mm"][-1], fold.z_mm - h["wedge_z_mm"][-1]) <= 1e-9
    assert abs(lap["depth_mm"] - 0.21) <= 0.05 and not res.pockets  # a lap, no pocket
