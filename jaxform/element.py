"""Reference element, quadrature and per-point geometry of 4-node quadrilaterals.

Layer 1 of the finite-element stack (then formulations -> assembly -> solver):
bilinear shape functions on [-1, 1]^2, the 2x2 Gauss rule, and at each Gauss point the
deformation gradient of a 2-D section embedded in 3-D:

* axisymmetric, coordinates (r, z): F = [[F_rr, F_rz, 0], [F_zr, F_zz, 0], [0, 0, r/R]],
  volume element dV0 = 2 pi R dA (so nodal forces are totals over the full ring);
* plane strain, coordinates (x, y): F_33 = 1, dV0 = dA (forces per mm of depth).

Total Lagrangian bookkeeping: the unknowns are displacements from the initial
configuration; material updates receive the relative deformation gradient of the step,
f = F_{n+1} F_n^{-1} (see jaxform.kinematics), so the stress update is the seed's
updated-Lagrangian one while the residual is written on the fixed initial mesh.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxform.smallmat import det2, det3, inv2, inv3

_G = 1.0 / np.sqrt(3.0)
GAUSS_POINTS = np.array([[-_G, -_G], [_G, -_G], [_G, _G], [-_G, _G]])
GAUSS_WEIGHTS = np.ones(4)
_CORNERS = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])


def shape_functions(xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """N (4,) and dN/dxi (4, 2) at a reference point xi (2,)."""
    a, b = _CORNERS[:, 0], _CORNERS[:, 1]
    n = 0.25 * (1 + a * xi[0]) * (1 + b * xi[1])
    dn = 0.25 * np.column_stack([a * (1 + b * xi[1]), b * (1 + a * xi[0])])
    return n, dn


# Values at the four Gauss points: N (4 gp, 4 nodes), dN/dxi (4 gp, 4 nodes, 2)
N_GP = np.stack([shape_functions(x)[0] for x in GAUSS_POINTS])
DN_GP = np.stack([shape_functions(x)[1] for x in GAUSS_POINTS])


class GaussGeometry(NamedTuple):
    """Reference geometry at the Gauss points of one element."""

    dndx: jax.Array  # dN/dX (4 gp, 4, 2)
    radius: jax.Array  # R (4,) (1 for plane strain)
    weight: jax.Array  # reference volume weights dV0 (4,)
    det: jax.Array  # det dX/dxi (4,)


def gauss_geometry(x_ref: jax.Array, axisymmetric: bool) -> GaussGeometry:
    """Reference geometry at the Gauss points of one element; x_ref: (4, 2) nodal
    coordinates."""
    jac = jnp.einsum("gai,aj->gji", DN_GP, x_ref)  # (g, j, i) = dX_j / dxi_i
    det = det2(jac)
    dndx = jnp.einsum("gai,gij->gaj", DN_GP, inv2(jac))
    radius = N_GP @ x_ref[:, 0] if axisymmetric else jnp.ones(4)
    weight = det * GAUSS_WEIGHTS * (2.0 * jnp.pi * radius if axisymmetric else 1.0)
    return GaussGeometry(dndx, radius, weight, det)


def deformation_gradient(u: jax.Array, dndx: jax.Array, radius: jax.Array, axisymmetric: bool):
    """F (4 gp, 3, 3) from nodal displacements u (4, 2)."""
    grad = jnp.einsum("ai,gaj->gij", u, dndx)  # du_i/dX_j
    f2 = jnp.eye(2) + grad
    if axisymmetric:
        f33 = 1.0 + (N_GP @ u[:, 0]) / radius
    else:
        f33 = jnp.ones(4)
    f = jnp.zeros((4, 3, 3), dtype=u.dtype)
    f = f.at[:, :2, :2].set(f2)
    return f.at[:, 2, 2].set(f33)


def virtual_work_residual(p1: jax.Array, dndx, radius, weight, axisymmetric: bool):
    """Nodal forces (4, 2) of first Piola stresses P (4 gp, 3, 3): sum_g P : Grad(N_a e_i) dV0."""
    r = jnp.einsum("gij,gaj,g->ai", p1[:, :2, :2], dndx, weight)
    if axisymmetric:
        hoop = jnp.einsum("g,ga,g->a", p1[:, 2, 2], N_GP / radius[:, None], weight)
        r = r.at[:, 0].add(hoop)
    return r


def first_piola(cauchy: jax.Array, f: jax.Array) -> jax.Array:
    """P = J sigma F^-T at each Gauss point."""
    return det3(f)[:, None, None] * jnp.einsum("gij,gkj->gik", cauchy, inv3(f))


def facet_forces(x_a: jax.Array, x_b: jax.Array, traction: jax.Array, axisymmetric: bool):
    """Consistent nodal forces (2 nodes, 2) of a uniform traction (2,) on the straight
    2-node facet from x_a to x_b (reference coordinates, mm): the integral of the linear
    shape functions times the traction over the facet, L/2 each in plane strain (per mm of
    depth), 2 pi L (2 r_a + r_b)/6 and 2 pi L (r_a + 2 r_b)/6 over the full ring."""
    length = jnp.sqrt(jnp.sum((x_b - x_a) ** 2))
    if axisymmetric:
        w = 2.0 * jnp.pi * length * jnp.stack([2.0 * x_a[0] + x_b[0], x_a[0] + 2.0 * x_b[0]]) / 6.0
    else:
        w = 0.5 * length * jnp.ones(2, dtype=x_a.dtype)
    return w[:, None] * traction[None, :]
