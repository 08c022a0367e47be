"""Kinematics of one load step at one material point.

Contract (read by every material law): a step is described by the *relative*
deformation gradient ``f = F_{n+1} F_n^{-1}`` (3x3; the configuration at t_n is the
reference, so f = I means "no motion in this step").  From it this module computes

* ``R``  - the rotation of the polar decomposition ``f = R U`` (thesis eq. 4.29b);
* ``dE`` - the rotation-neutralized strain increment of the generalized mid-point
  rule (thesis eq. 4.34), ``dE = (U - I) [(1 - alpha) I + alpha U]^{-1}``; with the
  default alpha = 0.5 this is ``2 (U - I)(U + I)^{-1}`` (eq. 4.35, errata item 5).

Materials integrate in the rotation-neutralized frame and rotate the updated stress
back with R (eq. 4.20).  Plane strain and axisymmetry are the special cases where f is
block diagonal (in-plane 2x2 block, out-of-plane stretch f33); for them
``step_kinematics(f, alpha, planar=True)`` uses the closed-form 2-D polar decomposition
(R is the rotation by atan2(f21 - f12, f11 + f22)), which is exact and far cheaper than the
general iteration, and the strain increment of the block-diagonal U.

Everything here is a pure function, differentiable with jax.jvp/jacfwd everywhere,
including f = I (the polar decomposition is a Newton iteration, not an eigen-
decomposition, whose derivative is undefined at repeated stretches).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp

from jaxform.smallmat import det3, inv3

# Newton's polar iteration X <- (X + X^-T)/2 converges quadratically; from a relative
# step with principal stretches in [0.1, 10] it reaches machine precision in <= 9
# iterations, and its derivative converges with it (the map has zero derivative at the
# fixed point).  12 iterations leave a margin; `polar_converged` checks it.
POLAR_ITERATIONS = 12


def polar_decomposition(f: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Return (R, U) with f = R U, R proper orthogonal, U symmetric positive definite.

    f must have det f > 0 (an inverted element is caught by the caller first).
    """

    def body(_, x):
        return 0.5 * (x + jnp.swapaxes(inv3(x), -1, -2))

    r = jax.lax.fori_loop(0, POLAR_ITERATIONS, body, f)
    u = r.T @ f
    u = 0.5 * (u + u.T)
    return r, u


def polar_decomposition_planar(f: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Closed-form f = R U for f = [[a, b, 0], [c, d, 0], [0, 0, f33]] with det f > 0.

    R is the in-plane rotation with cos = (a + d)/rho, sin = (c - b)/rho,
    rho = sqrt((a + d)^2 + (c - b)^2) > 0 whenever the 2x2 block has a positive determinant;
    then U = R^T f is symmetric (its off-diagonal entries are equal by construction).
    """
    a, b, c, d = f[0, 0], f[0, 1], f[1, 0], f[1, 1]
    sp, df = a + d, c - b
    rho = jnp.sqrt(sp * sp + df * df)
    cs, sn = sp / rho, df / rho
    zero = jnp.zeros_like(a)
    one = jnp.ones_like(a)
    r = jnp.array([[cs, -sn, zero], [sn, cs, zero], [zero, zero, one]])
    u = r.T @ f
    u = 0.5 * (u + u.T)
    return r, u


def polar_converged(f: jax.Array, r: jax.Array, tol: float = 1e-12) -> jax.Array:
    """True where R is orthogonal to ``tol`` (a guard for extreme stretches)."""
    eye = jnp.eye(3, dtype=f.dtype)
    return jnp.max(jnp.abs(r.T @ r - eye)) <= tol


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class StepKinematics:
    """What a material update reads about the step: rotation and strain increment."""

    R: jax.Array  # (3, 3) rotation of the step, f = R U
    dE: jax.Array  # (3, 3) symmetric rotation-neutralized strain increment
    ok: jax.Array  # bool: det f > 0 and the polar iteration converged


def strain_increment(u: jax.Array, alpha: float | jax.Array = 0.5) -> jax.Array:
    """Generalized mid-point strain increment (U - I)((1 - alpha) I + alpha U)^-1."""
    eye = jnp.eye(3, dtype=u.dtype)
    de = (u - eye) @ inv3((1.0 - alpha) * eye + alpha * u)
    return 0.5 * (de + de.T)


def strain_increment_planar(u: jax.Array, alpha: float | jax.Array = 0.5) -> jax.Array:
    """:func:`strain_increment` of a block-diagonal U (the in-plane 2x2 block and u33, as
    :func:`polar_decomposition_planar` gives it): the 2x2 block's inverse and a division
    instead of a 3x3 inverse.  The same increment to rounding; the kinematics'
    forward-mode tangents (five at every Gauss point in every element Jacobian) cost less
    than half as much through it, the element Jacobians about a tenth less (the
    benchmarks page, "The targets not met")."""
    u2 = u[:2, :2]
    a = (1.0 - alpha) + alpha * u2[0, 0]
    b = alpha * u2[0, 1]
    d = (1.0 - alpha) + alpha * u2[1, 1]
    inv = jnp.array([[d, -b], [-b, a]]) / (a * d - b * b)  # U is symmetric
    m = (u2 - jnp.eye(2, dtype=u.dtype)) @ inv
    m = 0.5 * (m + m.T)
    e33 = (u[2, 2] - 1.0) / ((1.0 - alpha) + alpha * u[2, 2])
    z = jnp.zeros_like(e33)
    return jnp.array([[m[0, 0], m[0, 1], z], [m[1, 0], m[1, 1], z], [z, z, e33]])


def step_kinematics(
    f: jax.Array, alpha: float | jax.Array = 0.5, planar: bool = False
) -> StepKinematics:
    """Kinematics of a step from its relative deformation gradient f (3x3).

    ``planar=True`` promises the plane-strain/axisymmetric block structure (f13 = f23 =
    f31 = f32 = 0) and uses the closed-form polar decomposition.
    """
    if planar:
        ok_det = (det3(f) > 0.0) & (f[2, 2] > 0.0)
    else:
        ok_det = det3(f) > 0.0
    # Keep the decomposition finite on an inverted f; ok=False reports it to the caller.
    f_safe = jnp.where(ok_det, f, jnp.eye(3, dtype=f.dtype))
    if planar:
        r, u = polar_decomposition_planar(f_safe)
        return StepKinematics(R=r, dE=strain_increment_planar(u, alpha), ok=ok_det)
    r, u = polar_decomposition(f_safe)
    ok = ok_det & polar_converged(f_safe, r)
    return StepKinematics(R=r, dE=strain_increment(u, alpha), ok=ok)


def rotate(r: jax.Array, t: jax.Array) -> jax.Array:
    """R T R^T for a second-order tensor T."""
    return r @ t @ r.T


def deviator(t: jax.Array) -> jax.Array:
    return t - jnp.trace(t) / 3.0 * jnp.eye(3, dtype=t.dtype)


def safe_norm_eq(dev: jax.Array) -> tuple[jax.Array, jax.Array]:
    """von Mises equivalent sqrt(3/2 dev:dev) with a finite derivative at dev = 0.

    Returns (equivalent, positive) where ``positive`` is False for a zero deviator; the
    value is then 0 and its derivative is taken as 0 (double-where, no NaN).
    """
    q = 1.5 * jnp.sum(dev * dev)
    positive = q > 0.0
    eq = jnp.sqrt(jnp.where(positive, q, 1.0))
    return jnp.where(positive, eq, 0.0), positive
