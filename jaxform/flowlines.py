"""Flow lines: material lines of the initial section followed through a run (NumPy).

The grain-flow picture of a forging: a grid of lines drawn on the initial section (lines
of constant z and of constant r, ``spacing`` mm apart, each sampled at a fifth of the
spacing) and the section's free surface (the outermost fibre: each run of boundary that a
die may touch, sampled likewise) move with the material.  Each sample point is a material
point: located once in an element of the mesh (its natural coordinates xi), its position
at every later row is the finite-element interpolation sum_a N_a(xi) x_a of the element's
nodal positions (the interpolated displacement: exact wherever the displacement field is
the element's own).  Where the mesh stops following the material the points are located
again from their current positions: on the new mesh of a remesh (whose reference
coordinates are the deformed shape at the remesh, :meth:`jaxform.simulation.Result.
scene_at`) and on the moved nodes of a rezoning (:class:`jaxform.rezone.RezoneReport`
``positions``).
Vectorized over the points; the loop runs over history rows.

A lap shows as a line folding onto itself (:func:`self_folds`): where the free surface
folds over, the surface line turns back on itself at the lap's root.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jaxform.mesh import boundary_polygon
from jaxform.postprocess import positions
from jaxform.transfer import _shape, locate

SAMPLES_PER_SPACING = 5


@dataclass(frozen=True)
class FlowLines:
    """Sample points of material lines at every history row.

    points: (rows, n, 2) positions (mm); line: (n,) which line each point belongs to
    (points of a line are consecutive, in order along it); family: (n_lines,) 0 for a
    line of constant z in the initial section, 1 for one of constant r, 2 for a run of
    its free surface; level: (n_lines,) that initial z or r (mm; 0 for the surface)."""

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


def surface_lines(scene, spacing: float):
    """(points (n, 2), line (n,)): the free surface of ``scene``'s initial section, each
    run of boundary edges on a set a die may touch (:meth:`Workpiece.contact_sets`) one
    line along the boundary (counter-clockwise), every edge cut into pieces of at most
    spacing / 5 (the section's corners kept)."""
    pos = np.asarray(scene.inputs.coords)
    pts, labels, _ = boundary_polygon(scene.mesh, pos)
    free = np.array([lab in set(scene.workpiece.contact_sets(scene.mesh)) for lab in labels])
    if not free.any():
        return np.empty((0, 2)), np.empty(0, dtype=int)
    if free.all():
        first = 0
    else:  # start the loop at an edge that begins a free run
        first = int(np.nonzero(free & ~np.roll(free, 1))[0][0])
    order = np.roll(np.arange(len(pts)), -first)
    free, a = free[order], pts[order]
    b = np.roll(pts, -1, axis=0)[order]
    run = np.cumsum(free & ~np.roll(free, 1))  # which free run each edge belongs to
    n = np.maximum(np.ceil(np.linalg.norm(b - a, axis=1) / (spacing / SAMPLES_PER_SPACING)), 1)
    out, ids = [], []
    for k in np.unique(run[free]):
        edges = np.nonzero(free & (run == k))[0]
        t = [np.arange(n[e]) / n[e] for e in edges]  # each edge without its end point
        p = np.vstack([a[e] + np.outer(u, b[e] - a[e]) for e, u in zip(edges, t)]
                      + [b[edges[-1]][None]])  # fmt: skip
        out.append(p)
        ids.append(np.full(len(p), k))
    return np.vstack(out), np.concatenate(ids)


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
    surf, runs = surface_lines(scene, spacing)
    if len(surf):
        _, runs = np.unique(runs, return_inverse=True)
        pts, line = np.vstack([pts, surf]), np.concatenate([line, len(family) + runs])
        extra = int(runs.max()) + 1
        family = np.concatenate([family, np.full(extra, 2)])
        level = np.concatenate([level, np.zeros(extra)])
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
    """The largest distance (mm) of a grid line's points (constant z or r at the start)
    from the straight line through its ends at ``row`` (0 for lines that stayed
    straight)."""
    worst = 0.0
    for k, p in enumerate(lines.polylines(row)):
        if len(p) < 3 or lines.family[k] == 2:
            continue
        d = p[-1] - p[0]
        n = np.array([-d[1], d[0]]) / max(np.linalg.norm(d), 1e-300)
        worst = max(worst, float(np.max(np.abs((p - p[0]) @ n))))
    return worst


# a line folds onto itself where its tangent turns by at least this within FOLD_ARC
# spacings of arc length (a hairpin: 180 deg; a die corner or a fillet turns a line by 90)
FOLD_TURN_DEG = 150.0
FOLD_ARC = 1.0


@dataclass(frozen=True)
class LineFold:
    """Where a material line folds onto itself: the line (its index, family, initial
    level), the point at the middle of the turn (r_mm, z_mm), the tangent's turn there
    (turn_deg, over an arc of at most the window), the arc length it turns in (arc_mm)
    and how far the two legs of the line run side by side from there (depth_mm,
    :func:`fold_depth`)."""

    line: int
    family: int
    level: float
    r_mm: float
    z_mm: float
    turn_deg: float
    arc_mm: float
    depth_mm: float


def _turns(p: np.ndarray):
    """(points, theta, s) of the polyline p without repeated points: its points, each
    segment's direction angle unwrapped along the line (rad; segment k joins points k and
    k + 1) and the arc length at each point (mm)."""
    keep = np.concatenate([[True], np.linalg.norm(np.diff(p, axis=0), axis=1) > 0.0])
    p = p[keep]
    d = np.diff(p, axis=0)
    turn = np.arctan2(d[:-1, 0] * d[1:, 1] - d[:-1, 1] * d[1:, 0], np.sum(d[:-1] * d[1:], axis=1))
    theta = np.concatenate([[0.0], np.cumsum(turn)])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(d, axis=1))])
    return p, theta, s


def line_fold(p: np.ndarray, window: float) -> tuple[float, np.ndarray, float]:
    """(turn in degrees, where (2,), arc in mm): the largest net turn of the polyline p's
    tangent between two of its segments at most ``window`` mm of arc apart (from the end
    of the first to the start of the second), the point of the line where half of that
    turn is done, and the arc between the two segments.  0 deg (and the first point) for
    a straight line or one of fewer than 3 distinct points."""
    p, theta, s = _turns(p)
    if len(theta) < 2:
        return 0.0, p[0], 0.0
    a, b = np.triu_indices(len(theta), 1)
    arc = s[b] - s[a + 1]
    net = np.where(arc <= window, np.abs(theta[b] - theta[a]), 0.0)
    # the shortest arc over which the line makes its largest turn
    k = int(np.argmin(np.where(net >= net.max() - 1e-12, arc, np.inf)))
    a, b = a[k], b[k]
    half = np.abs(theta[a + 1 : b + 1] - theta[a]) >= 0.5 * net[k]  # segments past half
    v = a + 1 + int(np.argmax(half))  # the vertex where the direction passes half the turn
    return float(np.degrees(net[k])), p[v], float(arc[k])


def _distance_to_polyline(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """The distance (mm) of each point (n, 2) to the polyline ``poly`` (m, 2)."""
    if len(poly) == 1:
        return np.linalg.norm(points - poly[0], axis=1)
    a, d = poly[:-1], np.diff(poly, axis=0)
    t = np.einsum("psi,si->ps", points[:, None] - a[None], d) / np.sum(d * d, axis=1)
    near = a[None] + np.clip(t, 0.0, 1.0)[..., None] * d[None]
    return np.min(np.linalg.norm(points[:, None] - near, axis=2), axis=1)


def fold_depth(p: np.ndarray, where: np.ndarray, gap: float) -> float:
    """How far (mm, along the line) the two legs of the polyline p on either side of its
    point nearest ``where`` (a fold) run within ``gap`` of each other: the shorter of the
    two legs' stretches from the fold whose points all lie within ``gap`` of the other
    leg.  0 where a leg leaves the other at once."""
    p = _turns(p)[0]
    v = int(np.argmin(np.linalg.norm(p - where, axis=1)))
    legs = (p[v::-1], p[v:])
    depth = np.inf
    for leg, other in (legs, legs[::-1]):
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(leg, axis=0), axis=1))])
        far = _distance_to_polyline(leg[1:], other) > gap
        j = int(np.argmax(far)) if far.any() else len(leg) - 1  # leg[1..j] lie within
        depth = min(depth, s[j])
    return float(depth)


def self_folds(
    lines: FlowLines, spacing: float, row: int = -1, turn_deg: float = FOLD_TURN_DEG
) -> list[LineFold]:
    """Where the material lines fold onto themselves at ``row``: every line whose tangent
    turns by at least ``turn_deg`` within an arc of FOLD_ARC x ``spacing`` (mm; the lines'
    spacing), the line running back along itself as it does through material folded
    over at a lap (:func:`line_fold`).  Net turns count, so a zigzag of the sampled line
    cancels; a straight line turns by 0, a line bent round a die corner or fillet by
    about 90 deg.  The depth of each fold is how far its two legs run within a fifth of
    the spacing (the lines' sampling) of each other (:func:`fold_depth`).  Sorted by the
    turn, largest first."""
    out = []
    for k, p in enumerate(lines.polylines(row)):
        turn, where, arc = line_fold(p, FOLD_ARC * spacing)
        if turn >= turn_deg:
            depth = fold_depth(p, where, spacing / SAMPLES_PER_SPACING)
            out.append(LineFold(k, int(lines.family[k]), float(lines.level[k]),
                                float(where[0]), float(where[1]), turn, arc, depth))  # fmt: skip
    return sorted(out, key=lambda f: -f.turn_deg)


def largest_turn(lines: FlowLines, spacing: float, row: int = -1) -> float:
    """The largest net turn (deg) of any line's tangent within FOLD_ARC x ``spacing`` of
    arc at ``row``: the fold measure (:func:`self_folds` reports the lines where it is at
    least FOLD_TURN_DEG)."""
    return max((line_fold(p, FOLD_ARC * spacing)[0] for p in lines.polylines(row)), default=0.0)
