"""Rate-independent J2 plasticity with linear isotropic hardening.

Yield function: sigma_eq - (sigma_y0 + H * eqps) <= 0.  Return mapping in the
rotation-neutralized frame with the same kinematics as the Anand law; with linear
hardening the consistency condition is linear, so the plastic increment is closed form:
d_eqps = (sigma_trial - sigma_y(eqps_n)) / (3G + H).  H = 0 is perfect plasticity.
State: ``s`` holds the current yield stress in MPa.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar

import jax
import jax.numpy as jnp

from jaxform.kinematics import StepKinematics
from jaxform.materials.base import (
    MaterialState,
    elastic_trial,
    finish,
    radial_return,
    trial_equivalent,
)


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class J2Params:
    G_MPa: jax.Array
    K_MPa: jax.Array
    sigma_y0_MPa: jax.Array  # initial yield stress
    H_MPa: jax.Array  # linear hardening modulus d(sigma_y)/d(eqps); 0 = perfect plasticity
    # the initial yield stress at temperature theta: sigma_y0 + yield_slope (theta - T_ref)
    yield_slope_MPa_K: jax.Array = 0.0  # d(sigma_y0)/d(theta), negative: softer when hot
    reference_temperature_K: jax.Array = 293.15  # where sigma_y0 is given


@dataclass(frozen=True)
class J2Plasticity:
    name: str = "j2"
    # the parameters a design or identification run varies by default
    design_params: ClassVar[tuple[str, ...]] = ("sigma_y0_MPa", "H_MPa")

    def for_points(self, n_points: int):
        """The strategy for a mesh of n_points Gauss points: the same (closed form)."""
        del n_points
        return self

    def initial_state(self, params: J2Params) -> MaterialState:
        y0 = jnp.asarray(params.sigma_y0_MPa)
        z = jnp.zeros((), y0.dtype)
        return MaterialState(stress=jnp.zeros((3, 3), y0.dtype), s=y0 + z, eqps=z)

    def shear_modulus(self, params: J2Params):
        return params.G_MPa

    def at_temperature(self, params: J2Params, temperature_K):
        """The parameters at temperature_K (K): sigma_y0 moved along yield_slope_MPa_K
        (the hardening modulus is kept)."""
        shift = params.yield_slope_MPa_K * (temperature_K - params.reference_temperature_K)
        return replace(params, sigma_y0_MPa=params.sigma_y0_MPa + shift,
                       reference_temperature_K=temperature_K)  # fmt: skip

    def update(
        self,
        kin: StepKinematics,
        state_old: MaterialState,
        params: J2Params,
        dt,
        solution: MaterialState | None = None,
    ):
        del solution  # closed form: nothing to solve
        g, h = params.G_MPa, params.H_MPa
        trial = elastic_trial(state_old.stress, kin.dE, g, params.K_MPa)
        sig_tr, positive = trial_equivalent(trial)
        sigma_y = params.sigma_y0_MPa + h * state_old.eqps
        f_tr = sig_tr - sigma_y
        plastic = f_tr > 0.0
        deqps = jnp.where(plastic, f_tr, 0.0) / (3.0 * g + h)
        sig_new = sig_tr - 3.0 * g * deqps
        stress_bar = radial_return(trial, sig_new, sig_tr, positive)
        stress = finish(kin, stress_bar)
        eqps = state_old.eqps + deqps
        new = MaterialState(stress=stress, s=params.sigma_y0_MPa + h * eqps, eqps=eqps)
        return stress, new, kin.ok
