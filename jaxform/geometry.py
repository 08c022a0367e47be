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
