"""The boundary polygon of a workpiece section, the element size wanted along it, and the
all-quad mesh gmsh makes of it (:func:`quads_of`, with its fallbacks) when a run remeshes
(:mod:`jaxform.remesh`), starts on the remesher's own mesh (``remesh.from_start``,
:func:`jaxform.scenes.build_scene`) or trims its part (:mod:`jaxform.process`).

Host NumPy and gmsh only: the polygon is the section's boundary loop
(:func:`jaxform.mesh.boundary_polygon`) with the vertices on straight runs of one set
dropped (:func:`simplify`) and any loop it makes by crossing itself cut off
(:func:`untangled`: a fold pressed over); the size is ``remesh.element_size_mm`` in the
bulk and ``remesh.die_size_ratio`` times it where the boundary touches a die and at
sharp corners, and with ``remesh.elements_across`` > 0 at most the section's local
thickness over that many (:func:`element_sizes`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jaxform.config import RemeshConfig
from jaxform.contact import TOUCH_GAP_MM
from jaxform.geometry import polygon_measure
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
    mesh, pos: np.ndarray, gap_fn, settings: RemeshConfig, split: bool = False
) -> SizedPolygon:
    """The polygon of ``mesh``'s section with its nodes at ``pos`` and the sizes wanted
    along it; ``gap_fn`` (:func:`jaxform.rezone.gap_function`, None without dies) tells
    which vertices touch a die (gap <= TOUCH_GAP_MM).  Its edges are split at the bulk
    size where ``remesh.elements_across`` > 0 (the thickness is measured along every
    edge) or ``split`` (a start mesh: a straight side, a single edge, is fine only at its
    corners and where a die touches it, not all along)."""
    points, labels, _ = boundary_polygon(mesh, pos)
    kept, kept_labels = simplify(points, labels, 1e-6 * settings.element_size_mm)
    pts, kept_labels, cut = untangled(points[kept], kept_labels)  # gmsh hangs on a crossing
    touching = _touching(pts, gap_fn)
    if split or settings.elements_across > 0:
        pts, kept_labels, touching = densified(pts, kept_labels, touching,
                                               settings.element_size_mm)  # fmt: skip
    if split:  # the added points lie on the section's straight sides: their own gaps
        touching = _touching(pts, gap_fn)
    return SizedPolygon(pts, kept_labels, touching, element_sizes(pts, touching, settings), cut)


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


def untangled(points: np.ndarray, labels: list[str]):
    """(points, labels, area cut (mm^2)) of the closed counter-clockwise polygon with
    every loop its boundary makes by crossing itself cut off.

    Where a fold of the free surface has been pressed under its neighbour (a fin that a
    closing pocket leaves along a die, turned over by the next steps) the deformed
    section's boundary crosses itself, and gmsh, given it, never returns.  At the first
    crossing, of edges i < j at x, the loop splits into (.., points[i], x, points[j + 1],
    ..) and (x, points[i + 1], .., points[j]); the one of the larger signed area stays
    (the other: the fold's tip beyond the neck where its sides crossed, or, turned
    clockwise, material the fold counts twice), until no edge crosses another.  x takes
    the labels of both edges it joins."""
    pts, labs, cut = np.asarray(points, dtype=float), list(labels), 0.0
    while (crossing := first_crossing(pts)) is not None:
        i, j, x = crossing
        outer = (np.vstack([pts[: i + 1], x, pts[j + 1 :]]), labs[: i + 1] + labs[j:])
        inner = (np.vstack([x, pts[i + 1 : j + 1]]), [labs[i], *labs[i + 1 : j + 1]])
        area = [float(polygon_measure(p[None], False)[0]) for p, _ in (outer, inner)]
        keep = int(area[1] > area[0])
        (pts, labs), cut = (outer, inner)[keep], cut + abs(area[1 - keep])
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
