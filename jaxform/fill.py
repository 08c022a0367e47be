"""The material's boundary conformed to a die between two nodes on it: what a die fill
measures.

A mesh's boundary is straight between its nodes.  Where two neighbouring boundary nodes
lie on a rounded die corner, the edge between them is a chord of the corner's arc: at a
concave corner of the cavity it leaves a sliver of the cavity outside the material, at a
convex corner it overlaps the die.  Contact holds both nodes on the die, so the material
follows the die between them to within the mesh's resolution; the sliver is the mesh's
chord, not air.  On the two-stage disk's finisher (corner radius 0.3 mm, nodes every
0.2 - 0.35 mm around the rib's corners) the chords alone read 0.15 % of the cavity as
unfilled with every boundary node on the die to within 0.3 um.

An edge is *conformed* to a die surface (a polyline, e.g. the rounded profile sampled by
:func:`jaxform.dies.rounded_polyline`) when both its ends lie within ``CONFORM_GAP_MM`` of
that surface and the surface's path between their projections is at most
``CONFORM_PATH_RATIO`` times the edge's length: a chord of a rounded corner (up to about
100 degrees of arc) conforms, a chord across a sharp corner (a path of sqrt 2 times the
chord at 90 degrees) or across a groove the material bridged does not.  The conformed
edge is the path p0 -> the surface's vertices between the projections -> p1.

* :func:`slivers` (traceable): per boundary edge whether it conforms and the closed
  polygon p0 -> path -> p1 between it and the die: its signed measure is what
  conforming adds to the material (a sliver at a concave corner, less an overlap at a
  convex one), for the design objectives' fill
  (:class:`jaxform.design.objectives.UnfilledPart`); the mask carries no gradient;
* :func:`conformed_edges` (host NumPy): the material's boundary with its conformed edges
  replaced by their paths, for the history's ``die_fill`` (an intersection with the
  cavity by Green's theorem, :func:`jaxform.postprocess.filled_volume`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxform.contact import TOUCH_GAP_MM
from jaxform.geometry import nearest_on_segments

CONFORM_GAP_MM = TOUCH_GAP_MM  # a node this close to the die lies on it (contact's touching gap)
CONFORM_PATH_RATIO = 1.2  # the die's path between the ends over the edge's length, at most


def _project(points, surface, arc, xp=jnp):
    """(arc length along the polyline ``surface`` (m, 2), its vertices at ``arc`` (m,), of
    each point's nearest point on it, the distance): the points (p, 2); traceable
    (``xp`` = jax.numpy) or host NumPy."""
    k, s, dist = nearest_on_segments(points, surface[:-1], surface[1:], xp=xp)
    return arc[k] + s * (arc[k + 1] - arc[k]), dist


def slivers(pos, edges, surface, xp=jnp):
    """(conformed (n_b,), the closed polygons p0 -> path -> p1 of every edge (n_b, m + 2,
    2)) of the directed boundary edges ``edges`` (n_b, 2) at positions ``pos`` against the
    die polyline ``surface`` (m, 2): the surface's vertices outside an edge's path collapse
    onto p0 (before it) or p1 (after it), so every polygon has m + 2 vertices.  For an
    edge with the material on its left (:func:`jaxform.mesh.boundary_edges`) the loop p0
    -> path -> p1 -> p0 runs counter-clockwise round a sliver on its right (outside the
    material: a concave die corner) and clockwise round an overlap on its left (a convex
    one): the polygon's signed measure is what conforming the edge adds to the material.
    Traceable; the mask is not differentiated.  ``xp``: jax.numpy (traced, the design
    objectives) or NumPy (the host's history, which an eager jax.numpy call would
    compile anew for every boundary length)."""
    pos, surface = xp.asarray(pos), xp.asarray(surface)
    edges = np.asarray(edges)
    p0, p1 = pos[edges[:, 0]], pos[edges[:, 1]]
    arc = xp.concatenate(
        [
            xp.zeros(1, surface.dtype),
            xp.cumsum(xp.linalg.norm(xp.diff(surface, axis=0), axis=1)),
        ]
    )
    s0, g0 = _project(p0, surface, arc, xp)
    s1, g1 = _project(p1, surface, arc, xp)
    chord = xp.linalg.norm(p1 - p0, axis=1)
    conformed = (
        (g0 <= CONFORM_GAP_MM)
        & (g1 <= CONFORM_GAP_MM)
        & (xp.abs(s1 - s0) <= CONFORM_PATH_RATIO * chord)
    )
    forward = (s0 <= s1)[:, None]
    # walk the vertices in the edge's direction: ascending where s0 <= s1, else descending
    sv = xp.where(forward, arc[None, :], arc[None, ::-1])  # (n_b, m)
    v = xp.where(forward[..., None], surface[None], surface[None, ::-1])  # (n_b, m, 2)
    lo, hi = xp.minimum(s0, s1)[:, None], xp.maximum(s0, s1)[:, None]
    inside = (sv > lo) & (sv < hi)
    before = xp.where(forward, sv <= lo, sv >= hi)
    q = xp.where(inside[..., None], v, xp.where(before[..., None], p0[:, None], p1[:, None]))
    polys = xp.concatenate([p0[:, None], q, p1[:, None]], axis=1)
    return (conformed if xp is np else jax.lax.stop_gradient(conformed)), polys


def conformed_edges(pos: np.ndarray, edges: np.ndarray, surfaces):
    """The material's boundary (the directed edges ``edges`` at ``pos``) with each edge
    that conforms to one of the die ``surfaces`` (the first it conforms to) replaced by
    its path along that die: (the start points (k, 2), the end points (k, 2) of the
    boundary's segments, the conformed edges' closed sliver polygons, whose signed
    measures are what conforming adds, :func:`slivers`).  Host NumPy."""
    starts, ends, used = [pos[edges[:, 0]]], [pos[edges[:, 1]]], []
    keep = np.ones(len(edges), dtype=bool)
    for surface in surfaces:
        conformed, polys = slivers(pos, edges, surface, xp=np)
        conformed = conformed & keep
        for poly in polys[conformed]:
            path = poly[np.r_[True, np.any(np.diff(poly, axis=0) != 0.0, axis=1)]]
            starts.append(path[:-1])
            ends.append(path[1:])
            used.append(poly)
        keep &= ~conformed
    return (np.concatenate([starts[0][keep], *starts[1:]]),
            np.concatenate([ends[0][keep], *ends[1:]]), used)  # fmt: skip
