"""Ductile damage criteria: integrals of a stress-state function over the plastic strain.

Each criterion is D = integral of f(sigma) d(eqps) over the history of a material point,
with sigma the Cauchy stress and eqps the equivalent plastic strain (both of the material
law).  The three criteria, in the order of the last axis of :func:`integrands`:

* ``cl``: normalized Cockcroft-Latham (Oh, Chen and Kobayashi's form),
  f = max(sigma_1, 0) / sigma_eq: 1 in uniaxial tension, 0 in uniaxial compression;
* ``brozzo``: Brozzo, Deluca and Rendina, f = 2 max(sigma_1, 0) / (3 (sigma_1 - sigma_m)):
  1 in uniaxial tension, 0 in uniaxial compression;
* ``ayada``: Ayada, Higashino and Mori, f = sigma_m / sigma_eq (signed): 1/3 in uniaxial
  tension, -1/3 in uniaxial compression.

sigma_1 is the largest principal stress, sigma_m the mean stress, sigma_eq von Mises'
equivalent stress.  A step adds f(sigma_n+1) (eqps_n+1 - eqps_n)
(:func:`increment`): the backward-Euler rule of the implicit material update, whose plastic
strain increment flows at the end of step stress; exact wherever f is constant over the
step (proportional loading, the homogeneous tests), also on the step that starts from the
stress-free state (where f is undefined and the trapezoid rule would lose half a step).

Stress tensors are 3 x 3 with their shear in the (0, 1) block only: the in-plane block of
an axisymmetric or plane-strain section (index 2 the hoop or out-of-plane direction), or a
diagonal tensor.  The largest principal stress is then the closed form
max(c + sqrt(d^2 + tau^2), sigma_22), c and d the in-plane block's mean and half difference,
differentiable everywhere but on the switch (no eigen-decomposition, whose derivative is
infinite at repeated principal values, which uniaxial states have).  Pure JAX, vmappable
and differentiable: part of the compiled step (:mod:`jaxform.stepping`).
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxform.kinematics import deviator, safe_norm_eq

CRITERIA = ("cl", "brozzo", "ayada")
N_CRITERIA = len(CRITERIA)


def _safe_sqrt(q):
    pos = q > 0.0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, q, 1.0)), 0.0)


def largest_principal(stress):
    """The largest principal value of stress tensors (..., 3, 3) with shear only in the
    (0, 1) block (see the module docstring)."""
    a, b, tau = stress[..., 0, 0], stress[..., 1, 1], stress[..., 0, 1]
    in_plane = 0.5 * (a + b) + _safe_sqrt((0.5 * (a - b)) ** 2 + tau**2)
    return jnp.maximum(in_plane, stress[..., 2, 2])


def integrands(stress):
    """f of each criterion (..., 3) for stress tensors (..., 3, 3), in :data:`CRITERIA`
    order; 0 where the stress has no deviator (no plastic flow can happen there)."""
    eq, pos = jnp.vectorize(lambda s: safe_norm_eq(deviator(s)), signature="(3,3)->(),()")(stress)
    s1 = largest_principal(stress)
    sm = jnp.trace(stress, axis1=-2, axis2=-1) / 3.0
    tension = jnp.maximum(s1, 0.0)
    safe_eq = jnp.where(pos, eq, 1.0)
    gap = s1 - sm  # >= 0, and > 0 wherever the deviator is not zero
    safe_gap = jnp.where(pos & (gap > 0.0), gap, 1.0)
    cl = jnp.where(pos, tension / safe_eq, 0.0)
    brozzo = jnp.where(pos & (gap > 0.0), 2.0 * tension / (3.0 * safe_gap), 0.0)
    ayada = jnp.where(pos, sm / safe_eq, 0.0)
    return jnp.stack([cl, brozzo, ayada], axis=-1)


def increment(stress, d_eqps):
    """The damage each criterion gains over a step (..., 3): f at the end of step stress
    ``stress`` (..., 3, 3) times the step's plastic strain ``d_eqps`` (...)."""
    return integrands(stress) * d_eqps[..., None]


def initial_damage(n_elements: int, n_points: int = 4, dtype=jnp.float64):
    """Zero damage at every Gauss point: (n_elements, n_points, 3)."""
    return jnp.zeros((n_elements, n_points, N_CRITERIA), dtype)
