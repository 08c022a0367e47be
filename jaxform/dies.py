"""Rigid dies: profile geometry, motion, and the closest-point gap of a workpiece node.

A die is a rigid curve in the model's 2-D section (r-z or x-y, mm) that translates along
z.  Its profile is a polyline ``points`` (k >= 2 points at t = 0) walked so that the
workpiece lies on the *right-hand side* of the direction of travel; for a top die walked
from the axis outward that is below it.  The first and last segments are extended to
infinity, so a two-point profile is an infinite straight die (the flat die).  Splines are
sampled into fine polylines at set-up (:func:`catmull_rom`).

Motion: the die's downward travel d(t) (mm) is linear interpolation in a table
``path_time_s -> path_travel_mm`` (constant speed is a two-row table); its position at
time t is the profile shifted by (0, -d(t)).

Gap: for a node at x the closest point q on the shifted polyline is found over all
segments at once (projection clamped to each segment; no search state, so a node slides
from one segment to the next without any switching logic).  If q lies inside a segment
the signed gap is g = (x - q) . n_seg with n_seg the segment's normal pointing to the
workpiece; if q is a vertex, g = +-|x - q| with the sign of (x - q) . (pseudo-normal of the
vertex) and the normal (x - q)/|x - q|.  So g is continuous everywhere and continuously
differentiable around convex corners.  The unit tangent is the normal turned by +90 deg
(for a top die walked outward: +r).

Friction coefficients live with the die (``mu``: Coulomb coefficient, ``m``: shear
friction factor) so they are arguments of the compiled step and can be differentiated.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class RigidDie:
    points: jax.Array  # (k, 2) profile at t = 0 (mm); workpiece on the right of the walk
    path_time_s: jax.Array  # (m,) increasing times (s), first 0
    path_travel_mm: jax.Array  # (m,) downward travel at those times (mm), first 0
    mu: jax.Array  # Coulomb friction coefficient (-)
    m: jax.Array  # shear friction factor (-), tau = m sigma_eq / sqrt(3)

    def travel(self, t):
        """Downward travel d(t) in mm (linear in the table; constant past its ends)."""
        return jnp.interp(t, self.path_time_s, self.path_travel_mm)

    def offset(self, t):
        return jnp.stack([jnp.zeros_like(self.travel(t)), -self.travel(t)])

    def gap(self, x, t):
        """(g, n, tangent) of a node at current position x (2,) at time t."""
        return closest_point_gap(self.points + self.offset(t)[None, :], x)


def segment_normals(points):
    d = points[1:] - points[:-1]
    length = jnp.sqrt(jnp.sum(d * d, axis=1))
    return jnp.stack([d[:, 1], -d[:, 0]], axis=1) / length[:, None]


def closest_point_gap(points, x):
    """Signed distance from x to the polyline ``points`` (see the module docstring)."""
    a, b = points[:-1], points[1:]
    d = b - a
    n_seg = d.shape[0]
    s = jnp.sum((x - a) * d, axis=1) / jnp.sum(d * d, axis=1)
    first = jnp.arange(n_seg) == 0
    last = jnp.arange(n_seg) == n_seg - 1
    s_c = jnp.clip(s, jnp.where(first, -jnp.inf, 0.0), jnp.where(last, jnp.inf, 1.0))
    q = a + s_c[:, None] * d
    dist2 = jnp.sum((x - q) ** 2, axis=1)
    i = jnp.argmin(dist2)
    normals = segment_normals(points)
    n_i = normals[i]
    v = x - q[i]
    # pseudo-normal of the vertex that q sits on (if any): start vertex for s_c <= 0
    at_start = (s_c[i] <= 0.0) & ~first[i]
    at_end = (s_c[i] >= 1.0) & ~last[i]
    at_vertex = at_start | at_end
    j_other = jnp.where(at_start, i - 1, jnp.minimum(i + 1, n_seg - 1))
    pseudo = n_i + normals[j_other]
    r2 = jnp.sum(v * v)
    nonzero = r2 > 0.0
    r = jnp.sqrt(jnp.where(nonzero, r2, 1.0))
    sign = jnp.where(jnp.sum(v * pseudo) >= 0.0, 1.0, -1.0)
    n_vertex = jnp.where(nonzero, sign * v / r, pseudo / jnp.sqrt(jnp.sum(pseudo**2)))
    g_vertex = jnp.where(nonzero, sign * r, 0.0)
    g = jnp.where(at_vertex, g_vertex, jnp.sum(v * n_i))
    n = jnp.where(at_vertex, n_vertex, n_i)
    tangent = jnp.stack([-n[1], n[0]])
    return g, n, tangent


# ----------------------------------------------------------------------------------
# set-up helpers (NumPy)


class DieError(ValueError):
    pass


def catmull_rom(points: np.ndarray, per_span: int = 16) -> np.ndarray:
    """Sample the uniform Catmull-Rom spline through ``points`` (C1, passes through every
    point; end tangents by reflection) into a polyline with ``per_span`` pieces per span."""
    p = np.asarray(points, dtype=float)
    ext = np.vstack([2 * p[0] - p[1], p, 2 * p[-1] - p[-2]])
    u = np.linspace(0.0, 1.0, per_span, endpoint=False)[:, None]
    out = []
    for i in range(1, len(ext) - 2):
        p0, p1, p2, p3 = ext[i - 1], ext[i], ext[i + 1], ext[i + 2]
        out.append(0.5 * (2 * p1 + (-p0 + p2) * u + (2 * p0 - 5 * p1 + 4 * p2 - p3) * u**2
                          + (-p0 + 3 * p1 - 3 * p2 + p3) * u**3))
    out.append(p[-1:])
    return np.vstack(out)


def check_profile(points: np.ndarray, key: str) -> np.ndarray:
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] < 2:
        raise DieError(f"{key}: must be a list of at least 2 [r_mm, z_mm] points, got shape "
                       f"{p.shape}")
    if not np.all(np.isfinite(p)):
        raise DieError(f"{key}: points must be finite")
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
    if np.any(seg <= 1e-9):
        k = int(np.argmin(seg))
        raise DieError(f"{key}: points {k} and {k + 1} coincide (segments must have length > 0)")
    return p


def time_at_travel(times: np.ndarray, travel: np.ndarray, target: float, key: str) -> float:
    """Inverse of the path table (the end time of a run that stops at ``target`` mm)."""
    if target > travel[-1] + 1e-12:
        raise DieError(f"{key}: the path ends at travel {travel[-1]:g} mm, before the "
                       f"required {target:g} mm")
    k = int(np.searchsorted(travel, target - 1e-12))
    k = max(k, 1)
    t0, t1, d0, d1 = times[k - 1], times[k], travel[k - 1], travel[k]
    return float(t0 + (target - d0) * (t1 - t0) / (d1 - d0)) if d1 > d0 else float(t1)


def make_die(points, times, travel, mu: float = 0.0, m: float = 0.0) -> RigidDie:
    return RigidDie(points=jnp.asarray(points, dtype=float),
                    path_time_s=jnp.asarray(times, dtype=float),
                    path_travel_mm=jnp.asarray(travel, dtype=float),
                    mu=jnp.asarray(float(mu)), m=jnp.asarray(float(m)))
