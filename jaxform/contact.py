"""Rigid dies and the contact conditions at the workpiece's candidate nodes.

Frictionless normal contact with Lagrange multipliers, solved exactly in the global
Newton (semismooth Newton on the Fischer-free "min" complementarity function):

    gap g_i >= 0,   lambda_i >= 0,   lambda_i g_i = 0
    <=>  C_i = lambda_i - max(0, lambda_i - c g_i) = 0     for any c > 0.

c only changes the path of the iterations, not the converged answer; it is set from the
stiffness scale of the mesh (G times a length, N/mm), never tuned by the user.
lambda_i is the total normal force (N) the die puts on node i; the die force is their sum.
The die pushes node i along the die normal n (pointing into the workpiece), so the
residual of node i's forces gains - lambda_i n.

A die moves rigidly along a prescribed path; the flat die here is the plane
z = z0 - v t with normal (0, -1) (the top die of an upsetting scene).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class FlatDie:
    """Flat rigid top die: the plane z = z0_mm - speed_mm_s * t, pressing down."""

    z0_mm: jax.Array
    speed_mm_s: jax.Array

    def position(self, t):
        return self.z0_mm - self.speed_mm_s * t

    def gap_and_normal(self, x_node: jax.Array, t):
        """Signed gap (mm, > 0 open) of a node at current position x_node (2,), and n."""
        g = self.position(t) - x_node[1]
        n = jnp.array([0.0, -1.0], dtype=x_node.dtype)
        return g, n


def contact_node_terms(die, x_node, lam, t, c):
    """(force residual on the node (2,), complementarity residual C) for one candidate."""
    g, n = die.gap_and_normal(x_node, t)
    r_u = -lam * n
    comp = lam - jnp.maximum(0.0, lam - c * g)
    return r_u, comp
