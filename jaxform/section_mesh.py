"""The boundary polygon of a workpiece section, the element size wanted along it, and the
all-quad mesh gmsh makes of it (:func:`quads_of`, with its fallbacks) when a run remeshes
(:mod:`jaxform.remesh`), starts on the remesher's own mesh (``remesh.from_start``,
:func:`jaxform.scenes.build_scene`) or trims its part (:mod:`jaxform.process`).

Host NumPy and gmsh only: the polygon is the section's boundary loop
(:func:`jaxform.mesh.boundary_polygon`), where dies are without the bunches of vertices
material leaves at die corners (:func:`thinned`) and without what a die reaches into
(:func:`off_dies`; the volume given back to the free surface, :func:`volume_back`), with
the vertices on straight runs of one set dropped (:func:`simplify`) and any loop it
makes by crossing itself cut off (:func:`untangled`: a fold pressed over); the size is
``remesh.element_size_mm`` in the bulk and ``remesh.die_size_ratio`` times it where the
boundary touches a die and at sharp corners, and with ``remesh.elements_across`` > 0 at
most the section's local thickness over that many (:func:`element_sizes`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jaxform.config import RemeshConfig
from jaxform.contact import TOUCH_GAP_MM
from jaxform.geometry import near_weights, polygon_measure, with_volume
from jaxform.mesh import MeshError, boundary_polygon, polygon_quads

_CORNER_TURN = np.deg2rad(30.0)  # a sharper turn of the boundary is refined like die contact


@dataclass(frozen=True)
class SizedPolygon:
    """The closed boundary polygon to mesh: its vertices (m, 2) counter-clockwise, each
    edge's set label, whether each vertex touches a die, the element size wanted at each
    vertex (mm), and the area (mm^2) cut off where the boundary crossed itself
    (:func:`untangled`)."""

    points: np.ndarray
    labels: list
    touching: np.ndarray
    sizes: np.ndarray
    cut: float = 0.0


@dataclass(frozen=True)
class MesherHelp:
    """What gmsh needed beyond its first try at the wanted sizes (:func:`quads_of`) and
    what the polygon lost where it crossed itself; falsy where nothing was needed."""

    size_factor: float = 1.0  # the factor of the wanted sizes that gave all quads
    split: bool = False  # every element split into quads (no factor of SIZE_RETRIES did)
    fold_cut_mm2: float = 0.0  # the area cut off where the boundary crossed itself

    def __bool__(self) -> bool:
        return self.size_factor != 1.0 or self.split or self.fold_cut_mm2 > 0.0

    def kinds(self) -> tuple[str, ...]:
        """The kinds of help, as the run's note counts them."""
        named = (("finer sizes", self.size_factor != 1.0), ("split into quads", self.split),
                 ("a fold cut", self.fold_cut_mm2 > 0.0))  # fmt: skip
        return tuple(name for name, needed in named if needed)

    def __str__(self) -> str:
        tried = ", ".join(f"{f:g}" for f in SIZE_RETRIES)
        parts = [
            f"a fold crossed the boundary: {self.fold_cut_mm2:.3g} mm^2 cut"
            if self.fold_cut_mm2 > 0.0 else "",
            f"split (gmsh left triangles at sizes x {tried})" if self.split else "",
            f"sizes x {self.size_factor:g}" if self.size_factor != 1.0 else "",
        ]  # fmt: skip
        return "; ".join(filter(None, parts))


# element sizes tried, as factors of the wanted ones, when gmsh leaves triangles
SIZE_RETRIES = (1.0, 0.8, 0.65)


def quads_of(points, labels, sizes) -> tuple:
    """(mesh, :class:`MesherHelp`): :func:`jaxform.mesh.polygon_quads`, again with finer
    sizes (SIZE_RETRIES) where its recombination leaves triangles (a thin flash whose edges
    split into few, uneven segments can defeat every algorithm at one size and not at
    another), and last at the wanted sizes with every element split into quadrilaterals
    (an acute tip of material, the fin a closing pocket leaves along a die, keeps a
    triangle at every size).  Raises the MeshError of the last try, naming the tries."""
    errors = []
    for factor in SIZE_RETRIES:
        try:
            return polygon_quads(points, labels, factor * np.asarray(sizes)), MesherHelp(factor)
        except MeshError as err:
            errors.append(f"x {factor:g}: {err}")
    try:
        mesh = polygon_quads(points, labels, np.asarray(sizes), split=True)
    except MeshError as err:
        errors.append(f"split: {err}")
        raise MeshError(f"at the wanted sizes {'; '.join(errors)}") from None
    return mesh, MesherHelp(split=True)


def _touching(points: np.ndarray, gap_fn) -> np.ndarray:
    """Whether each point touches a die (gap <= TOUCH_GAP_MM); none without dies."""
    if gap_fn is None:
        return np.zeros(len(points), dtype=bool)
    return gap_fn(points)[0] <= TOUCH_GAP_MM


def sized_polygon(
    mesh, pos: np.ndarray, gap_fn, settings: RemeshConfig, axisymmetric: bool, split: bool = False
) -> SizedPolygon:
    """The polygon of ``mesh``'s section with its nodes at ``pos`` and the sizes wanted
    along it; ``gap_fn`` (:func:`jaxform.rezone.gap_function`, None without dies) tells
    which vertices touch a die (gap <= TOUCH_GAP_MM).  Its edges are split at the bulk
    size where ``remesh.elements_across`` > 0 (the thickness is measured along every
    edge) or ``split`` (a start mesh: a straight side, a single edge, is fine only at its
    corners and where a die touches it, not all along).  Where a die reaches into the
    section (:func:`off_dies`) the polygon is the part outside it, with the volume kept.
    ``axisymmetric``: volumes by Pappus (True) or areas (plane strain)."""
    points, labels, _ = boundary_polygon(mesh, pos)
    die_size = settings.element_size_mm * settings.die_size_ratio
    if gap_fn is not None:
        target = float(polygon_measure(points, axisymmetric))
        kept = thinned(points, labels, THIN * die_size)
        thin = (points[kept], [labels[i] for i in kept])
        cleared = off_dies(*thin, gap_fn, die_size)
        if cleared is not None or len(kept) < len(points):
            before = points
            points, labels = thin if cleared is None else cleared
            # the volume the dies cut off, or the dropped vertices, back to the free
            # surface near where it was taken
            sites = changed_at(before, points, 1e-9 * max(1.0, float(np.abs(before).max())))
            points = volume_back(points, labels, gap_fn, target, axisymmetric,
                                 near=(sites, PUT_BACK_REACH * die_size))  # fmt: skip
    kept, kept_labels = simplify(points, labels, 1e-6 * settings.element_size_mm)
    pts, kept_labels, cut = fold_cut(points[kept], kept_labels, THIN * die_size)
    touching = _touching(pts, gap_fn)
    if split or settings.elements_across > 0:
        pts, kept_labels, touching = densified(pts, kept_labels, touching,
                                               settings.element_size_mm)  # fmt: skip
    if split:  # the added points lie on the section's straight sides: their own gaps
        touching = _touching(pts, gap_fn)
    return SizedPolygon(pts, kept_labels, touching, element_sizes(pts, touching, settings), cut)


HELD = ("axis", "symmetry")  # boundary sets held by Dirichlet conditions: never moved
WRAP_PASSES = 4  # times an edge across a convex die arc is split onto the arc, at most
_FRACTIONS = np.arange(1, 8) / 8.0  # where along an edge its depth into a die is sampled
DEEP = 0.1  # an edge is split onto a die where it passes this times the die size into it
THIN = 0.3  # boundary vertices closer than this times the die size to the one before merge
PUT_BACK_REACH = 4.0  # a volume a remesh cuts goes back within about this x the die size


def _held(labels: list[str]) -> np.ndarray:
    """Whether each vertex of the polygon ends an edge of a HELD set."""
    on = np.isin(np.asarray(labels, dtype=object), HELD)
    return on | np.roll(on, 1)  # the edges from and to each vertex


def thinned(points: np.ndarray, labels: list[str], min_gap: float) -> np.ndarray:
    """Indices of the vertices of the closed polygon to keep: each vertex where the set
    changes, and each other one at least ``min_gap`` (mm) from the last kept one (and from
    the first).  Material that flows into a die corner, or along a die past it, bunches
    its boundary nodes there; every remesh keeps every boundary vertex as a node, so the
    bunch passes from mesh to mesh, gmsh fans tiny elements out of it, their quality sets
    the trigger off again at once, and the meshes grow (the two-stage disk design at blocker
    friction 0.29: 479 -> 597 -> 779 -> 1819 -> 2091 nodes over the finisher's last 3 um
    of stroke, 126 boundary edges under 0.05 mm, until a first step failed)."""
    n = len(points)
    corner = np.array([labels[i - 1] != labels[i] for i in range(n)])
    start = int(np.argmax(corner)) if corner.any() else 0
    kept = [start]
    for i in (np.arange(1, n) + start) % n:
        if corner[i] or np.linalg.norm(points[i] - points[kept[-1]]) >= min_gap:
            kept.append(int(i))
    if (
        len(kept) > 1
        and not corner[kept[-1]]
        and (np.linalg.norm(points[kept[-1]] - points[kept[0]]) < min_gap)
    ):
        kept.pop()
    return np.sort(np.asarray(kept))


def off_dies(points: np.ndarray, labels: list[str], gap_fn, die_size: float):
    """(points, labels) of the closed counter-clockwise polygon without the part of it
    that a die reaches into; None where no die reaches into it.

    Node contact holds the nodes off a die, not the edges between them: a convex die arc
    (a flash land's entry, a punch's nose) that the material flows round reaches across
    the edge between the last contact node before it and the first after it, and the
    deformed section's boundary, and a new mesh of it, overlaps the die (0.13 mm deep
    across a 0.58 mm edge at a 0.3 mm arc, the two-stage disk's finisher: the first step
    on such a mesh starts with its nodes inside the die and does not converge).  Here
    every vertex inside a die (gap < -TOUCH_GAP_MM) moves to its closest point on it; an
    edge that passes through a die (the deepest of 7 points along it more than DEEP times
    the die size inside) gets that point, moved onto the die, where the point is at least
    THIN times the die size from both ends (at most WRAP_PASSES times: the polygon wraps
    the arc, and follows a die face that a vertex moved onto; an edge along a die face that
    dips a few um into it stays, and no new vertex bunches with one it has); the axis and
    the mid-plane are never moved.  The volume it cuts off is
    given back by :func:`volume_back`."""
    pts, labs = np.array(points, dtype=float), list(labels)
    g, n = gap_fn(pts)
    inside = (g < -TOUCH_GAP_MM) & ~_held(labs)
    changed = bool(inside.any())
    pts[inside] -= g[inside][:, None] * n[inside]
    for _ in range(WRAP_PASSES):
        nxt = np.roll(pts, -1, axis=0)
        # each edge's deepest point into a die of the _FRACTIONS points along it
        along = pts[:, None] + _FRACTIONS[None, :, None] * (nxt - pts)[:, None]
        gs, ns = (np.asarray(a).reshape(len(pts), len(_FRACTIONS), -1)
                  for a in gap_fn(along.reshape(-1, 2)))  # fmt: skip
        k = np.argmin(gs[..., 0], axis=1)
        rows = np.arange(len(pts))
        gk, nk, at_k = gs[rows, k, 0], ns[rows, k], along[rows, k]
        ends = np.minimum(np.linalg.norm(at_k - pts, axis=1), np.linalg.norm(nxt - at_k, axis=1))
        split = (
            (gk < -max(TOUCH_GAP_MM, DEEP * die_size))
            & (ends >= THIN * die_size)
            & ~np.isin(np.asarray(labs, dtype=object), HELD)
        )
        if not split.any():
            break
        changed = True
        at = np.nonzero(split)[0]
        onto = at_k[at] - gk[at][:, None] * nk[at]
        pts = np.insert(pts, at + 1, onto, axis=0)
        labs = list(np.insert(np.asarray(labs, dtype=object), at + 1, [labs[i] for i in at]))
    return (pts, labs) if changed else None


def volume_back(
    points: np.ndarray, labels: list[str], gap_fn, target: float, axisymmetric: bool, near=None
):
    """The closed counter-clockwise polygon with its measure ``target`` again: its free
    vertices (off the dies, the axis and the mid-plane) moved along their outward normals
    by one distance (:func:`jaxform.geometry.with_volume`); a free vertex that this pushes
    into a die goes onto it and the rest move again.  ``near`` = (sites (m, 2), reach mm):
    the distance falls off as exp(-(d / reach)^2) with a vertex's distance d from the
    sites where the volume was cut (:func:`jaxform.geometry.near_weights`), and the ends
    of a free edge that lie on a die or the mid-plane slide along it (:func:`_slides`): a
    flash's tip, whose face runs from the land to the mid-plane, has no free vertex.
    Spread evenly over the free vertices instead, the volume a convex die corner cut at a
    flash land's entry went into the only free surface left, a pocket of the cavity far
    from it, and a remesh closed it (docs/remeshing.md)."""
    g, n = gap_fn(points)
    free = (g > TOUCH_GAP_MM) & ~_held(labels)
    slides = None if near is None else _slides(points, labels, (g, n), gap_fn, free)
    sliding = np.zeros(len(points), bool) if slides is None else np.abs(slides).sum(axis=1) > 0
    pts = points
    for _ in range(WRAP_PASSES):
        weights = None if near is None else near_weights(pts, *near)
        pts = with_volume(pts, free, target, axisymmetric, weights, slides)
        g, n = gap_fn(pts)
        # a free vertex pushed into a die goes onto it and stays; a sliding one goes back
        # onto the die it slides along
        pushed = free & (g < -TOUCH_GAP_MM)
        into = pushed | (sliding & (g < -TOUCH_GAP_MM))
        if not into.any():
            break
        pts[into] -= g[into][:, None] * n[into]
        free &= ~pushed
    return pts


def _slides(points: np.ndarray, labels: list[str], gaps, gap_fn, free: np.ndarray) -> np.ndarray:
    """(n, 2) for each vertex that ends a free edge (its midpoint off the dies, not on the
    axis or the mid-plane) but is not free itself, its move per unit outward move of that
    edge: along the tangent of the die it touches, or along the axis or mid-plane edge it
    ends, by the free edge's outward normal's component there; 0 rows elsewhere (and for
    a vertex on a die and the axis or mid-plane at once).  ``gaps``: gap_fn(points)."""
    nxt = np.roll(points, -1, axis=0)
    lab = np.asarray(labels, dtype=object)
    held_edge = np.isin(lab, HELD)
    free_edge = (gap_fn(0.5 * (points + nxt))[0] > TOUCH_GAP_MM) & ~held_edge
    front = ~free & (free_edge | np.roll(free_edge, 1))
    g, n = gaps
    edge = nxt - points
    edge = edge / np.maximum(np.linalg.norm(edge, axis=1), 1e-300)[:, None]
    held_in, held_out = np.roll(held_edge, 1), held_edge
    out = np.zeros_like(points)
    on_die = front & (g <= TOUCH_GAP_MM) & ~(held_in | held_out)
    out[on_die] = np.stack([-n[on_die, 1], n[on_die, 0]], axis=1)
    line = front & (held_in ^ held_out) & (g > TOUCH_GAP_MM)
    out[line] = np.where(held_out[line][:, None], edge[line], np.roll(edge, 1, axis=0)[line])
    # the free edge's outward unit normal (counter-clockwise: the edge turned clockwise)
    normal = np.stack([edge[:, 1], -edge[:, 0]], axis=1)
    n_free = np.where(free_edge[:, None], normal, np.roll(normal, 1, axis=0))
    return out * np.sum(out * n_free, axis=1)[:, None]


def changed_at(before: np.ndarray, after: np.ndarray, tol: float) -> np.ndarray:
    """(m, 2) the points where a polygon changed: the vertices of ``before`` with no vertex
    of ``after`` within ``tol`` (dropped or moved) and those of ``after`` with none of
    ``before`` (moved there or added)."""
    d = np.linalg.norm(before[:, None] - after[None], axis=2)
    gone = before[d.min(axis=1) > tol]
    new = after[d.min(axis=0) > tol]
    return np.concatenate([gone, new]).reshape(-1, 2)


def simplify(points: np.ndarray, labels: list[str], tol: float):
    """The loop without the vertices that lie within ``tol`` (mm) of the chord between the
    kept vertices around them on the same set: (kept indices, their edge labels).  Every
    vertex where the set changes stays."""
    n = len(points)
    corners = [i for i in range(n) if labels[i - 1] != labels[i]] or [0]
    kept = []
    for c0, c1 in zip(corners, corners[1:] + [corners[0] + n]):
        run = [i % n for i in range(c0, c1 + 1)]  # one set's vertices, both ends included
        keep = [run[0]]
        dropped: list[int] = []
        for k in range(1, len(run) - 1):
            a, b = points[keep[-1]], points[run[k + 1]]
            chord = b - a
            length = max(float(np.hypot(*chord)), 1e-300)
            test = points[dropped + [run[k]]] - a
            dist = np.abs(test[:, 0] * chord[1] - test[:, 1] * chord[0]) / length
            if dist.max() <= tol:
                dropped.append(run[k])
            else:
                keep.append(run[k])
                dropped = []
        kept += keep
    kept = np.asarray(kept)
    return kept, [labels[i] for i in kept]


def first_crossing(points: np.ndarray):
    """(i, j, x) of the first pair of edges i < j of the closed polygon ``points`` that are
    not neighbours and cross or touch, x the point where they meet; None for a simple
    polygon.  Edge k runs from points[k] to points[k + 1]."""
    a, b = points, np.roll(points, -1, axis=0)
    n = len(a)
    i, j = np.triu_indices(n, k=2)
    keep = ~((i == 0) & (j == n - 1))  # the last edge and the first share points[0]
    i, j = i[keep], j[keep]
    di, dj, w = b[i] - a[i], b[j] - a[j], a[j] - a[i]
    den = di[:, 0] * dj[:, 1] - di[:, 1] * dj[:, 0]
    safe = np.where(den == 0.0, 1.0, den)
    s = (w[:, 0] * dj[:, 1] - w[:, 1] * dj[:, 0]) / safe
    t = (w[:, 0] * di[:, 1] - w[:, 1] * di[:, 0]) / safe
    hit = np.nonzero((den != 0.0) & (s >= 0.0) & (s <= 1.0) & (t >= 0.0) & (t <= 1.0))[0]
    if hit.size == 0:
        return None
    k = hit[0]
    return int(i[k]), int(j[k]), a[i[k]] + s[k] * di[k]


def first_touch(points: np.ndarray, gap: float):
    """(i, j) of the first two vertices i < j of the closed polygon ``points`` closer than
    ``gap`` (mm) that have at least one vertex between them both ways round (not
    neighbours); None where there is none."""
    n = len(points)
    i, j = np.triu_indices(n, k=2)
    keep = (j - i) <= n - 2  # j - i = n - 1: the last vertex and the first are neighbours
    i, j = i[keep], j[keep]
    hit = np.nonzero(np.linalg.norm(points[j] - points[i], axis=1) < gap)[0]
    return None if hit.size == 0 else (int(i[hit[0]]), int(j[hit[0]]))


def untangled(points: np.ndarray, labels: list[str], touch: float = 0.0):
    """(points, labels, area cut (mm^2)) of the closed counter-clockwise polygon with
    every loop its boundary makes by crossing itself cut off, and (``touch`` > 0, mm)
    every loop closed where two of its vertices have come closer than ``touch``.

    Where a fold of the free surface has been pressed under its neighbour (a fin that a
    closing pocket leaves along a die, turned over by the next steps) the deformed
    section's boundary crosses itself, and gmsh, given it, never returns.  At the first
    crossing, of edges i < j at x, the loop splits into (.., points[i], x, points[j + 1],
    ..) and (x, points[i + 1], .., points[j]); the one of the larger signed area stays
    (the other: the fold's tip beyond the neck where its sides crossed, or, turned
    clockwise, material the fold counts twice), until no edge crosses another.  x takes
    the labels of both edges it joins.

    A fold whose two sides have closed on each other without crossing (a slit: vertices
    i < j a hair apart, the fold's tip between them) is cut the same way at their
    midpoint m: (.., points[i - 1], m, points[j + 1], ..) and the slit (points[i], ..,
    points[j]), closed across its mouth.  Kept as it was, a slit goes into the new mesh,
    whose elements there are poor from the start (the quality trigger then waits until
    they are 10 % worse), and the next steps press its sides across each other: with no
    contact of the material with itself the section then overlaps itself, and what is
    read off its boundary (the die fill) counts the overlap's stretch along the die twice
    (generated die 29, 2026-11-28: fill 97.25 % at the end where the material filled
    99.8 %)."""
    pts, labs, cut = np.asarray(points, dtype=float), list(labels), 0.0
    while True:
        if (crossing := first_crossing(pts)) is not None:
            i, j, x = crossing
            outer = (np.vstack([pts[: i + 1], x, pts[j + 1 :]]), labs[: i + 1] + labs[j:])
            inner = (np.vstack([x, pts[i + 1 : j + 1]]), [labs[i], *labs[i + 1 : j + 1]])
        elif touch > 0.0 and (pair := first_touch(pts, touch)) is not None:
            i, j = pair
            m = 0.5 * (pts[i] + pts[j])
            outer = (np.vstack([pts[:i], m, pts[j + 1 :]]), labs[:i] + labs[j:])
            inner = (pts[i : j + 1], labs[i : j + 1])  # the slit, closed across its mouth
        else:
            return pts, labs, cut
        area = [float(polygon_measure(p[None], False)[0]) for p, _ in (outer, inner)]
        keep = int(area[1] > area[0])
        (pts, labs), cut = (outer, inner)[keep], cut + abs(area[1 - keep])


def fold_cut(points: np.ndarray, labels: list[str], min_gap: float):
    """(points, labels, area cut (mm^2)): :func:`untangled` (gmsh hangs on a crossing; a
    fold whose sides are within TOUCH_GAP_MM of each other counts as closed), then, where
    it cut a loop, the vertices closer than ``min_gap`` (mm) to the one kept before them
    dropped (:func:`thinned`).  A crossing point can fall a hair from a
    vertex: generated die 29 (:mod:`jaxform.generated_dies`) left the crossing 5.5 um
    from the fold's next vertex, a needle turning by 145 and 157 degrees, which gmsh's
    recombination left as a triangle and the split made into quadrilaterals of corner
    quality 0.019, on which the next step failed (the run stopped at 4.068 of its mm)."""
    pts, labs, cut = untangled(points, labels, touch=TOUCH_GAP_MM)
    if cut > 0.0:
        near = thinned(pts, labs, min_gap)
        pts, labs = pts[near], [labs[i] for i in near]
    return pts, labs, cut


def local_thickness(points: np.ndarray) -> np.ndarray:
    """The section's thickness at each vertex of the closed polygon ``points`` (mm): the
    distance to the nearest part of the boundary that faces it across the material, i.e.
    to the nearest edge whose distance along the boundary is more than twice its straight
    distance (the vertex's own sides and the legs of a corner it sits in are not across:
    along them the boundary is about as long as the straight line).  Where no edge faces
    it, inf."""
    a, b = points, np.roll(points, -1, axis=0)
    d = b - a
    length = np.linalg.norm(d, axis=1)
    s = np.einsum("pmi,mi->pm", points[:, None] - a[None], d) / np.maximum(length**2, 1e-300)
    s = np.clip(s, 0.0, 1.0)
    dist = np.linalg.norm(points[:, None] - (a[None] + s[..., None] * d[None]), axis=2)
    arc = np.concatenate([[0.0], np.cumsum(length)])
    total = arc[-1]
    along = np.abs(arc[None, :-1] + s * length[None] - arc[:-1, None])
    along = np.minimum(along, total - along)
    across = np.where(along > 2.0 * dist, dist, np.inf)
    return across.min(axis=1)


def densified(points: np.ndarray, labels: list[str], touching: np.ndarray, spacing: float):
    """(points, labels, touching) of the closed polygon with its edges split into equal
    pieces no longer than ``spacing``: each piece keeps its edge's label, and a point
    added on an edge between two vertices that touch a die touches it too (it lies on the
    chord, off a curved die by the sagitta; :func:`onto_dies` moves such nodes on)."""
    nxt = np.roll(points, -1, axis=0)
    pieces = np.maximum(1, np.ceil(np.linalg.norm(nxt - points, axis=1) / spacing)).astype(int)
    both = touching & np.roll(touching, -1)
    out, out_labels, out_touching = [], [], []
    for p, q, n, lab, t0, t_edge in zip(points, nxt, pieces, labels, touching, both):
        f = np.arange(n)[:, None] / n
        out.append(p + f * (q - p))
        out_labels += [lab] * n
        out_touching += [t0] + [t_edge] * (n - 1)
    return np.vstack(out), out_labels, np.asarray(out_touching, dtype=bool)


def element_sizes(points: np.ndarray, touching: np.ndarray, settings: RemeshConfig) -> np.ndarray:
    """The element size wanted at each vertex: fine at die contact and sharp corners, and
    with ``remesh.elements_across`` > 0 at most the local thickness over that many (a
    flash or a thin web gets elements across it, not one squeezed element)."""
    d_in = points - np.roll(points, 1, axis=0)
    d_out = np.roll(points, -1, axis=0) - points
    turn = np.abs(
        np.arctan2(
            d_in[:, 0] * d_out[:, 1] - d_in[:, 1] * d_out[:, 0], np.sum(d_in * d_out, axis=1)
        )
    )
    fine = touching | (turn > _CORNER_TURN)
    h = settings.element_size_mm
    sizes = np.where(fine, settings.die_size_ratio * h, h)
    if settings.elements_across > 0:
        # never finer than a quarter of the die size: a gap that closes to nothing (the
        # flash's last step) must not ask for an unbounded number of elements
        floor = 0.25 * settings.die_size_ratio * h
        thin = np.maximum(local_thickness(points) / settings.elements_across, floor)
        sizes = np.minimum(sizes, thin)
    return sizes
