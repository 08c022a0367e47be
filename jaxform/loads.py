"""Distributed (traction) loads on boundary facets: dead loads ramped in time.

A :class:`FacetLoad` is a uniform traction on a set of boundary facets of the reference
mesh, fixed in direction and in magnitude per unit *reference* area (a dead load: it
neither follows the rotation of the facet nor its stretch; for small strains this is the
usual traction boundary condition, at finite strain it is a nominal/first Piola traction).
It grows linearly from 0 at t = 0 to its full value at ``ramp_end_s`` and stays there.

The consistent nodal forces are assembled by one vmapped call of
:func:`jaxform.element.facet_forces` over the facets and a scatter-add; the result enters
the global residual as R = f_int - f_ext (jaxform.assembly). Everything here is a pure
function of its arguments, so the traction and the ramp can be differentiated.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp

from jaxform.element import facet_forces


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class FacetLoad:
    traction: jax.Array  # (2,) full traction per unit reference area (MPa = N/mm^2)
    ramp_end_s: jax.Array  # time (s) at which the full traction is reached

    def factor(self, t):
        """Load factor in [0, 1]: t / ramp_end_s, constant after the ramp."""
        return jnp.clip(t / self.ramp_end_s, 0.0, 1.0)


def external_forces(
    load: FacetLoad, t, coords, facets, axisymmetric: bool, n_fields: int, n_dofs: int
):
    """Global external force vector (n_dofs,) of the load at time t.

    coords: (n_nodes, 2) reference coordinates; facets: (n_f, 2) node ids of the loaded
    boundary facets."""
    a, b = coords[facets[:, 0]], coords[facets[:, 1]]
    f = jax.vmap(lambda xa, xb: facet_forces(xa, xb, load.traction, axisymmetric))(a, b)
    dofs = facets[:, :, None] * n_fields + jnp.arange(2)[None, None, :]  # (n_f, 2 nodes, 2)
    out = jnp.zeros(n_dofs, dtype=coords.dtype).at[dofs].add(f)
    return load.factor(t) * out


def total_force(load: FacetLoad, coords, facets, axisymmetric: bool):
    """The full load's resultant (2,) in N (per mm of depth in plane strain)."""
    a, b = coords[facets[:, 0]], coords[facets[:, 1]]
    f = jax.vmap(lambda xa, xb: facet_forces(xa, xb, load.traction, axisymmetric))(a, b)
    return jnp.sum(f, axis=(0, 1))
