"""Plane geometry of the section: polygon areas and volumes of revolution.

One formula serves every measure of the workpiece section: the shoelace area and, for
axisymmetric sections, Pappus' volume of revolution about the axis r = 0
(V = 2 pi * integral of r dA).  Written with indexing and array methods only, so the
same function takes NumPy arrays (set-up, post-processing, rezoning) and JAX arrays
(inside differentiable objectives); it imports no JAX.
"""

from __future__ import annotations

import numpy as np


def polygon_measure(p, axisymmetric: bool):
    """Signed measure (..., ) of polygons with vertices ``p`` (..., m, 2) in order: the
    area (mm^2; plane strain: volume per mm of depth) or, axisymmetric, the volume of
    revolution about r = 0 (mm^3).  Positive for counter-clockwise polygons."""
    m = p.shape[-2]
    nxt = (np.arange(m) + 1) % m
    x, y = p[..., 0], p[..., 1]
    xn, yn = x[..., nxt], y[..., nxt]
    cross = x * yn - xn * y
    if axisymmetric:
        return 2.0 * np.pi * (cross * (x + xn)).sum(axis=-1) / 6.0
    return 0.5 * cross.sum(axis=-1)


def vertex_normals(p: np.ndarray, axisymmetric: bool):
    """(unit outward normals (n, 2), surface shares (n,)) at the vertices of the closed
    counter-clockwise polygon p: the share is half of each adjacent edge's length (times
    2 pi r in an axisymmetric section), the volume a unit outward move of the vertex adds."""
    e_out = np.roll(p, -1, axis=0) - p
    length = np.linalg.norm(e_out, axis=1)
    normal_out = np.stack([e_out[:, 1], -e_out[:, 0]], axis=1)  # |edge| x outward unit
    nrm = normal_out + np.roll(normal_out, 1, axis=0)
    share = 0.5 * (length + np.roll(length, 1))
    if axisymmetric:
        share = share * 2.0 * np.pi * p[:, 0]
    return nrm / np.maximum(np.linalg.norm(nrm, axis=1), 1e-300)[:, None], share


def with_volume(
    p: np.ndarray, free: np.ndarray, target: float, axisymmetric: bool, weights=None, slides=None
):
    """The closed counter-clockwise polygon p with its ``free`` vertices moved along their
    outward normals by one distance (times each vertex's ``weights``, default 1) so that
    its measure is ``target`` (to 1e-13): Newton steps on the distance, its derivative the
    free vertices' weighted surface share (exact to first order where the outward normals
    are the edges'; at a corner of the free surface it converges linearly: by 0.29 a step
    where one free vertex is a right-angled corner).  ``slides`` (n, 2): the move, per
    unit distance, of the other vertices with a nonzero row (a vertex on a die along its
    surface, one on the mid-plane along it).  Unchanged where no vertex moves."""
    p = np.array(p, dtype=float)
    s = np.zeros_like(p) if slides is None else np.asarray(slides, dtype=float)
    slide = ~free & (np.abs(s).sum(axis=1) > 0.0)
    if not (free.any() or slide.any()):
        return p
    w = np.ones(len(p)) if weights is None else np.asarray(weights, dtype=float)
    for _ in range(40):
        change = float(polygon_measure(p, axisymmetric)) - target
        if abs(change) <= 1e-13 * abs(target):
            break
        unit, share = vertex_normals(p, axisymmetric)
        move = np.where(free[:, None], unit, s) * (free | slide)[:, None]
        rate = float(np.sum(share * w * np.sum(move * unit, axis=1)))
        if rate <= 0.0:
            break
        p -= change / rate * w[:, None] * move
    return p


def near_weights(p: np.ndarray, sites: np.ndarray, reach: float, floor: float = 1e-3):
    """(n,) weights of the vertices p (n, 2) by their distance d to the nearest of the
    points ``sites`` (m, 2): exp(-(d / reach)^2), at least ``floor`` (so that a volume
    with no free vertex near its site still goes somewhere); all 1 where there is no
    site.  With :func:`with_volume`, a volume a remesh cut or added at the sites goes back
    where it was taken, not across the section (a pocket far away is not closed by it)."""
    sites = np.asarray(sites, dtype=float).reshape(-1, 2)
    if len(sites) == 0:
        return np.ones(len(p))
    d = np.min(np.linalg.norm(np.asarray(p)[:, None] - sites[None], axis=2), axis=1)
    return np.maximum(np.exp(-((d / reach) ** 2)), floor)


_NEXT = np.array([1, 2, 3, 0])
_PREV = np.array([3, 0, 1, 2])


def corner_qualities(pos, elements):
    """(..., 4) quality of each element corner: 2 det[a, b] / (|a|^2 + |b|^2) with a, b
    the two edges leaving the corner (1 for a square, sin(angle) for a rhombus, 2k/(1+k^2)
    for a 1:k rectangle, 0 for a degenerate corner, < 0 for a non-convex quad).  ``pos``
    (n, 2) with ``elements`` (..., 4), or element corner positions (..., 4, 2) with
    ``elements`` None.  Works on NumPy and JAX arrays."""
    p = pos if elements is None else pos[elements]
    a = p[..., _NEXT, :] - p
    b = p[..., _PREV, :] - p
    cross = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    norm2 = (a * a).sum(axis=-1) + (b * b).sum(axis=-1)
    return 2.0 * cross / norm2.clip(min=1e-300)


def min_quality(pos, elements):
    """The mesh quality that triggers rezoning and remeshing: the worst corner of any
    element."""
    return corner_qualities(pos, elements).min()


def tributary_areas(pos, facets, axisymmetric: bool, counted=None, xp=np):
    """Contact area of each node (mm^2; plane strain: per mm of depth): the integral of its
    shape function over the facets around it (x 2 pi r for an axisymmetric section).

    pos: (n, 2) positions; facets: (n_f, 2) node indices into pos; counted: optional
    (n_f,) 0/1 weights (which facets count, e.g. those in contact); ``xp``: NumPy (host,
    nothing compiled) or ``jax.numpy`` (traced)."""
    a, b = pos[facets[:, 0]], pos[facets[:, 1]]
    length = xp.sqrt(xp.sum((b - a) ** 2, axis=1))
    if counted is not None:
        length = length * counted
    if axisymmetric:
        wa = 2.0 * np.pi * length * (2.0 * a[:, 0] + b[:, 0]) / 6.0
        wb = 2.0 * np.pi * length * (a[:, 0] + 2.0 * b[:, 0]) / 6.0
    else:
        wa = wb = 0.5 * length
    n = pos.shape[0]
    if xp is np:
        return np.bincount(facets[:, 0], wa, n) + np.bincount(facets[:, 1], wb, n)
    return xp.zeros(n, dtype=pos.dtype).at[facets[:, 0]].add(wa).at[facets[:, 1]].add(wb)


def nearest_on_segments(points, a, b, xp=np):
    """For each of the points (p, 2), the nearest of the segments a -> b (m, 2): (its index
    (p,), the parameter along it (p,) in [0, 1], the distance (p,), mm).  ``xp``: NumPy
    (host) or ``jax.numpy`` (traced; the index carries no derivative)."""
    d = b - a
    s = xp.einsum("pmi,mi->pm", points[:, None] - a[None], d) / xp.maximum(
        xp.sum(d * d, axis=1), 1e-300
    )
    s = xp.clip(s, 0.0, 1.0)
    dist = xp.linalg.norm(points[:, None] - (a[None] + s[..., None] * d[None]), axis=2)
    k = xp.argmin(dist, axis=1)
    rows = xp.arange(points.shape[0])
    return k, s[rows, k], dist[rows, k]


def mesh_change(pos, elements, new_pos, new_elements, axisymmetric: bool):
    """What a new mesh of the section changes (a remesh or a rezoning reports it): (the
    worst corner quality before, after, the relative change of the material volume)."""
    v0 = float(np.sum(polygon_measure(pos[elements], axisymmetric)))
    v1 = float(np.sum(polygon_measure(new_pos[new_elements], axisymmetric)))
    before = float(min_quality(pos, elements))
    return before, float(min_quality(new_pos, new_elements)), v1 / v0 - 1.0
