"""A die profile as a clamped cubic B-spline of heights z(r), and its manufacturability
constraints as exact linear functions of the control heights.

The top die's profile between two radii r0 < r1 is the curve z(r) = sum_j c_j N_j(r)
(clamped cubic B-spline, uniform interior knots, n >= 4 control heights c_j): C2,
through c_0 at r0 and c_{n-1} at r1.  It is sampled onto the die's profile points in
[r0, r1] (their radii stay, their heights become z(r_i)): the die stays a polyline and
the contact code is unchanged.  Every map here is a constant matrix built once (NumPy):

* ``z = B c``          heights at the die's points (B: basis at their radii);
* ``d1 = D1 c``        the B-spline coefficients of z'(r) (a quadratic spline);
* ``d2 = D2 c``        those of z''(r) (a piecewise *linear* spline).

Constraints, with the reasons they are exact:

* no undercut, no overhanging wall: by construction.  z is a function of r and the die's
  points keep their increasing radii, so every vertical line meets the profile once.
* draft angle >= alpha on every wall (the wall's angle from the press direction):
  |z'(r)| <= cot(alpha) everywhere.  A B-spline lies within the range of its
  coefficients, so max |d1_j| <= cot(alpha) implies it; the bound is attained where the
  curve runs straight, so it is the exact condition of a polygon of walls and tight
  elsewhere.
* fillet radius >= R_min: the curvature |z''| / (1 + z'^2)^(3/2) <= 1/R_min.  z'' is
  piecewise linear with the values d2_j at the knots, so max |d2_j| is exactly max |z''|,
  and max |d2_j| <= 1/R_min implies the radius bound (exactly on flat parts, with margin
  (1 + z'^2)^(3/2) on walls).
* smoothness: C2 by construction (the corners the polyline samples are rounded by the
  die's corner radius as before).

The constraints are rows of ``A c <= b`` (:meth:`SplineBasis.constraint_rows`); the
design problem sees their violation as an exterior quadratic penalty, and
:meth:`SplineBasis.report` gives each one's value, limit and margin.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DEGREE = 3


def clamped_knots(r0: float, r1: float, n: int) -> np.ndarray:
    """The knot vector of a clamped cubic B-spline with n >= 4 coefficients on [r0, r1]:
    r0 and r1 four times each, n - 4 uniform interior knots."""
    inner = np.linspace(r0, r1, n - DEGREE + 1)
    return np.concatenate([[r0] * DEGREE, inner, [r1] * DEGREE])


def basis(knots: np.ndarray, degree: int, r: np.ndarray) -> np.ndarray:
    """(len(r), n) B-spline basis N_j(r) of ``degree`` on ``knots`` (Cox-de Boor,
    vectorized over r; the last interval is closed so that N(r1) is the end value)."""
    r = np.asarray(r, dtype=float)
    t = np.asarray(knots, dtype=float)
    n_int = len(t) - 1
    last = np.max(np.nonzero(t[1:] > t[:-1])[0])  # the last non-empty interval
    b = ((t[:-1][None, :] <= r[:, None]) & (r[:, None] < t[1:][None, :])).astype(float)
    b[:, last] = np.where((r >= t[last]) & (r <= t[last + 1]), 1.0, b[:, last])
    b[r >= t[last + 1], :last] = 0.0
    for p in range(1, degree + 1):
        m = n_int - p
        left_den = t[p : p + m] - t[:m]
        right_den = t[p + 1 : p + 1 + m] - t[1 : 1 + m]
        with np.errstate(divide="ignore", invalid="ignore"):
            left = np.where(left_den > 0, (r[:, None] - t[:m]) / left_den, 0.0)
            right = np.where(right_den > 0, (t[p + 1 : p + 1 + m] - r[:, None]) / right_den, 0.0)
        b = left * b[:, :m] + right * b[:, 1 : 1 + m]
    return b


def derivative_matrix(knots: np.ndarray, degree: int) -> np.ndarray:
    """(n - 1, n) map from the coefficients of a degree-p spline on ``knots`` to those of
    its derivative (degree p - 1 on knots[1:-1]): d_j = p (c_{j+1} - c_j) / (t_{j+p+1} -
    t_{j+1})."""
    n = len(knots) - degree - 1
    span = knots[degree + 1 : degree + n] - knots[1:n]
    d = np.zeros((n - 1, n))
    j = np.arange(n - 1)
    d[j, j + 1] = degree / span
    d[j, j] = -degree / span
    return d


@dataclass(frozen=True, eq=False)
class SplineBasis:
    """The constant maps of a clamped cubic B-spline of heights on [r0, r1] with n
    control heights, sampled at the radii ``r`` (the die's points in the range)."""

    r0: float
    r1: float
    n: int
    r: np.ndarray  # (k,) radii of the die's points in [r0, r1] (increasing)

    def __hash__(self):  # arrays inside: identity is enough
        return id(self)

    @property
    def knots(self) -> np.ndarray:
        return clamped_knots(self.r0, self.r1, self.n)

    def heights(self) -> np.ndarray:
        """(k, n) B: heights at the sampled radii are B @ c."""
        return basis(self.knots, DEGREE, self.r)

    def slope(self) -> np.ndarray:
        """(n - 1, n) D1: the coefficients of z'(r) are D1 @ c."""
        return derivative_matrix(self.knots, DEGREE)

    def second(self) -> np.ndarray:
        """(n - 2, n) D2: the coefficients of z''(r) (its values at the knots) are D2 @ c."""
        return derivative_matrix(self.knots[1:-1], DEGREE - 1) @ self.slope()

    def dense(self, per_span: int = 40):
        """(r, B, B', B'') on a fine grid of [r0, r1] (for the report's sampled values)."""
        r = np.linspace(self.r0, self.r1, per_span * (self.n - DEGREE) + 1)
        t = self.knots
        return (r, basis(t, DEGREE, r), basis(t[1:-1], DEGREE - 1, r) @ self.slope(),
                basis(t[2:-2], DEGREE - 2, r) @ self.second())  # fmt: skip

    def fit(self, z: np.ndarray, pinned: dict[int, float] | None = None) -> np.ndarray:
        """Control heights whose spline fits heights ``z`` at the sampled radii (least
        squares; the controls in ``pinned`` held at their values)."""
        b = self.heights()
        pinned = pinned or {}
        free = np.array([j for j in range(self.n) if j not in pinned], dtype=int)
        c = np.zeros(self.n)
        for j, v in pinned.items():
            c[j] = v
        rhs = np.asarray(z, dtype=float) - b @ c
        c[free] = np.linalg.lstsq(b[:, free], rhs, rcond=None)[0]
        return c


@dataclass(frozen=True, eq=False)
class Manufacturability:
    """The limits: the draft angle (deg from the press direction; 0: none) and the
    smallest fillet radius (mm; 0: none)."""

    draft_deg: float = 0.0
    fillet_radius_min_mm: float = 0.0

    @property
    def slope_max(self) -> float:
        """The largest |dz/dr| a wall with the draft angle may have (inf: no limit)."""
        if self.draft_deg <= 0.0:
            return np.inf
        return float(1.0 / np.tan(np.radians(self.draft_deg)))

    @property
    def curvature_max(self) -> float:
        """The largest |z''| (1/mm) the fillet radius allows (inf: no limit)."""
        if self.fillet_radius_min_mm <= 0.0:
            return np.inf
        return 1.0 / self.fillet_radius_min_mm
