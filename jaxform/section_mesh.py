"""The boundary polygon of a workpiece section and the element size wanted along it: what
gmsh (:func:`jaxform.mesh.polygon_quads`) meshes when a run remeshes
(:mod:`jaxform.remesh`) or starts on the remesher's own mesh (``remesh.from_start``,
:func:`jaxform.scenes.build_scene`).

Host NumPy only: the polygon is the section's boundary loop (:func:`jaxform.mesh.boundary_polygon`)
with the vertices on straight runs of one set dropped (:func:`simplify`); the size is
``remesh.element_size_mm`` in the bulk and ``remesh.die_size_ratio`` times it where the
boundary touches a die and at sharp corners, and with ``remesh.elements_across`` > 0 at
most the section's local thickness over that many (:func:`element_sizes`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jaxform.config import RemeshConfig
from jaxform.contact import TOUCH_GAP_MM
from jaxform.mesh import boundary_polygon

_CORNER_TURN = np.deg2rad(30.0)  # a sharper turn of the boundary is refined like die contact


@dataclass(frozen=True)
class SizedPolygon:
    """The closed boundary polygon to mesh: its vertices (m, 2) counter-clockwise, each
    edge's set label, whether each vertex touches a die, and the element size wanted at
    each vertex (mm)."""

    points: np.ndarray
    labels: list
    touching: np.ndarray
    sizes: np.ndarray


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
    pts = points[kept]
    touching = _touching(pts, gap_fn)
    if split or settings.elements_across > 0:
        pts, kept_labels, touching = densified(pts, kept_labels, touching,
                                               settings.element_size_mm)  # fmt: skip
    if split:  # the added points lie on the section's straight sides: their own gaps
        touching = _touching(pts, gap_fn)
    return SizedPolygon(pts, kept_labels, touching, element_sizes(pts, touching, settings))


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
