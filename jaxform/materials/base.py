"""The contract between kinematics, a material law and the element residual.

A material law is a small immutable object (its *strategy*: tolerances, iteration
caps) with two pure functions of one material point:

``law.initial_state(params) -> MaterialState``
``law.update(kin, state_old, params, dt, solution=None) -> (stress, state_new, ok)``
``law.at_temperature(params, temperature_K) -> params``: the parameters at a point's
temperature (coupled thermal runs; Anand's Arrhenius factor, J2's yield slope; the
elastic law ignores it), so temperature enters the update as one more input.

* ``kin`` is a :class:`jaxform.kinematics.StepKinematics` (rotation R and
  rotation-neutralized strain increment dE of the step);
* ``state_old`` is the :class:`MaterialState` at t_n, its stress in the configuration
  at t_n;
* ``params`` is the law's parameter pytree (every leaf a float: all of them can be
  differentiated, e.g. for material identification);
* ``dt`` is the step's time increment in s;
* ``stress`` is the Cauchy stress at t_{n+1} (3x3, MPa, current configuration);
* ``solution`` (optional) is the ``state_new`` this same update returned before for the
  same input.  A law with a local solve takes it as the converged point instead of solving
  again, and differentiates there; a closed-form law ignores it.  The assembly's Jacobian
  pass uses it: the residual pass has solved every point already, vectorized over the
  whole mesh, and the Jacobian pass runs in chunks where the solve's loops cost most.
* ``ok`` is a bool: False when the local solve did not converge or the kinematics were
  invalid.  The caller (global Newton / step cutback) decides what to do; the update
  never raises and never returns NaN for finite input.

Derivatives: ``jax.jacfwd`` of ``update`` with respect to dE (or to the displacement
that produced it) is the consistent tangent.  Local solves inside are differentiated by
the implicit function theorem (:mod:`jaxform.implicit`).

Axisymmetry and plane strain need nothing special here: the caller passes a 3x3 f
whose out-of-plane stretch is r/R (axisymmetric) or 1 (plane strain).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp

from jaxform.kinematics import StepKinematics, deviator, rotate, safe_norm_eq


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class MaterialState:
    """State of one material point.

    stress: Cauchy stress, 3x3, MPa.
    s:      scalar internal variable in MPa: Anand's deformation resistance; for J2 the
            current yield stress; for elasticity unused (0).
    eqps:   equivalent plastic strain (accumulated, dimensionless).
    """

    stress: jax.Array
    s: jax.Array
    eqps: jax.Array


def elastic_trial(stress_old: jax.Array, de: jax.Array, shear_mpa, bulk_mpa) -> jax.Array:
    """T_n + l^e[dE] with isotropic moduli (thesis eq. 4.22)."""
    eye = jnp.eye(3, dtype=de.dtype)
    return stress_old + 2.0 * shear_mpa * deviator(de) + bulk_mpa * jnp.trace(de) * eye


def radial_return(trial: jax.Array, sigma_new, sigma_trial, positive) -> jax.Array:
    """Scale the trial deviator to equivalent stress sigma_new (radial return, beta=1)."""
    dev = deviator(trial)
    mean = jnp.trace(trial) / 3.0 * jnp.eye(3, dtype=trial.dtype)
    safe = jnp.where(positive, sigma_trial, 1.0)
    ratio = jnp.where(positive, sigma_new / safe, 1.0)
    return ratio * dev + mean


def finish(kin: StepKinematics, stress_bar: jax.Array) -> jax.Array:
    """Rotate the stress from the rotation-neutralized frame back (thesis eq. 4.20)."""
    return rotate(kin.R, stress_bar)


def trial_equivalent(trial: jax.Array):
    return safe_norm_eq(deviator(trial))
