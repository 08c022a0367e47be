"""Flow lines: material lines of the initial section followed through a run (NumPy).

The grain-flow picture of a forging: a grid of lines drawn on the initial section (lines
of constant z and of constant r, ``spacing`` mm apart, each sampled at a fifth of the
spacing) moves with the material.  Each sample point is a material point: located once in
an element of the mesh (its natural coordinates xi), its position at every later row is
the finite-element interpolation sum_a N_a(xi) x_a of the element's nodal positions (the
interpolated displacement: exact wherever the displacement field is the element's own).
Where the mesh stops following the material the points are located again from their
current positions: on the new mesh of a remesh (whose reference coordinates are the
deformed shape at the remesh, :meth:`jaxform.simulation.Result.scene_at`) and on the
moved nodes of a rezoning (:class:`jaxform.rezone.RezoneReport` ``positions``).
Vectorized over the points; the loop runs over history rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jaxform.postprocess import positions
from jaxform.transfer import _shape, locate

SAMPLES_PER_SPACING = 5


@dataclass(frozen=True)
class FlowLines:
    """Sample points of material lines at every history row.

    points: (rows, n, 2) positions (mm); line: (n,) which line each point belongs to
    (points of a line are consecutive, in order along it); family: (n_lines,) 0 for a
    line of constant z in the initial section, 1 for one of constant r; level: (n_lines,)
    that initial z or r (mm)."""

    points: np.ndarray
    line: np.ndarray
    family: np.ndarray
    level: np.ndarray

    def polylines(self, row: int = -1) -> list[np.ndarray]:
        """The lines at ``row`` as a list of (m, 2) polylines."""
        cuts = np.nonzero(np.diff(self.line))[0] + 1
        return np.split(self.points[row], cuts)

    def segments(self) -> np.ndarray:
        """(n_segments, 2) point index pairs joining consecutive points of each line."""
        i = np.arange(len(self.line) - 1)
        keep = self.line[i] == self.line[i + 1]
        return np.column_stack([i[keep], i[keep] + 1])


def _inside(points: np.ndarray, pos: np.ndarray, elements: np.ndarray, tol: float = 1e-9):
    """Element, natural coordinates and whether each point lies in the mesh (its
    interpolated position reproduces it)."""
    e, xi = locate(points, pos, elements)
    back = np.einsum("pa,pai->pi", _shape(xi), pos[elements[e]])
    size = np.ptp(pos, axis=0).max()
    return e, xi, np.linalg.norm(back - points, axis=1) <= tol * size


def seed_lines(pos: np.ndarray, elements: np.ndarray, spacing: float):
    """(points (n, 2), line (n,), family, level): lines of constant z and constant r at
    multiples of ``spacing`` across the section (pos, elements), sampled every
    spacing / 5 and cut to the parts inside the section."""
    lo, hi = pos.min(axis=0), pos.max(axis=0)
    pts, line, family, level = [], [], [], []
    for fam, (axis, other) in enumerate(((1, 0), (0, 1))):  # z = const, then r = const
        levels = np.arange(np.ceil(lo[axis] / spacing), np.floor(hi[axis] / spacing) + 1)
        levels = levels * spacing
        n = max(int(np.ceil((hi[other] - lo[other]) / spacing * SAMPLES_PER_SPACING)), 1)
        along = np.linspace(lo[other], hi[other], n + 1)
        for lev in levels:
            p = np.empty((len(along), 2))
            p[:, axis], p[:, other] = lev, along
            pts.append(p)
            line.append(np.full(len(p), len(family)))
            family.append(fam)
            level.append(lev)
    if not pts:
        raise ValueError(f"flow lines: spacing {spacing} mm leaves no line in the section")
    points, ids = np.vstack(pts), np.concatenate(line)
    _, _, inside = _inside(points, pos, elements)
    return points[inside], ids[inside], np.asarray(family), np.asarray(level)


def flow_lines(result, spacing: float) -> FlowLines:
    """The material lines of ``result``'s initial section (``spacing`` mm apart) at every
    history row (see the module docstring)."""
    rows = len(result.history["time_s"])
    segments = result.segments or []
    starts = [s.first_row for s in segments[1:]]
    rezoned = [k for k in np.nonzero(np.asarray(result.history.get("rezoned", [])))[0]]
    moved = iter([r.positions for r in result.rezones if r.improved])
    scene = result.scene_at(0)
    pos0 = np.asarray(scene.inputs.coords)
    elements = np.asarray(scene.mesh.elements)
    pts, line, family, level = seed_lines(pos0, elements, spacing)
    out = np.empty((rows, len(pts), 2))
    ref = pos0
    current = pts
    e, xi, _ = _inside(current, ref, elements)
    for k in range(rows):
        if k in starts:  # a new mesh: its reference is the deformed shape it was made on
            scene = result.scene_at(k)
            elements = np.asarray(scene.mesh.elements)
            e, xi, _ = _inside(current, np.asarray(scene.inputs.coords), elements)
        nodes = positions(scene, result.fields["x"][k])
        current = np.einsum("pa,pai->pi", _shape(xi), nodes[elements[e]])
        out[k] = current
        if k in rezoned:  # the nodes moved over the material: locate the points again
            e, xi, _ = _inside(current, next(moved), elements)
    return FlowLines(out, line, family, level)


def straightness(lines: FlowLines, row: int = -1) -> float:
    """The largest distance (mm) of a line's points from the straight line through its
    ends at ``row`` (0 for lines that stayed straight)."""
    worst = 0.0
    for p in lines.polylines(row):
        if len(p) < 3:
            continue
        d = p[-1] - p[0]
        n = np.array([-d[1], d[0]]) / max(np.linalg.norm(d), 1e-300)
        worst = max(worst, float(np.max(np.abs((p - p[0]) @ n))))
    return worst
