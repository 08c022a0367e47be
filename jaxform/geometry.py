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
