"""Isotropic hypoelasticity: the Anand law's elastic part alone.

Rate form (objective via the rotation-neutralized frame): T_{n+1} = R (T_n + l^e[dE]) R^T.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import jax
import jax.numpy as jnp

from jaxform.kinematics import StepKinematics
from jaxform.materials.base import MaterialState, elastic_trial, finish


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class ElasticParams:
    G_MPa: jax.Array  # shear modulus
    K_MPa: jax.Array  # bulk modulus


@dataclass(frozen=True)
class Hypoelastic:
    """Isotropic hypoelastic law (no internal variables)."""

    name: str = "elastic"
    # the parameters a design or identification run varies by default
    design_params: ClassVar[tuple[str, ...]] = ("G_MPa", "K_MPa")

    def for_points(self, n_points: int):
        """The strategy for a mesh of n_points Gauss points: the same (closed form)."""
        del n_points
        return self

    def initial_state(self, params: ElasticParams) -> MaterialState:
        z = jnp.zeros((), dtype=jnp.asarray(params.G_MPa).dtype)
        return MaterialState(stress=jnp.zeros((3, 3), z.dtype), s=z, eqps=z)

    def shear_modulus(self, params: ElasticParams):
        return params.G_MPa

    def at_temperature(self, params: ElasticParams, temperature_K):
        """Elastic moduli do not depend on the temperature here."""
        del temperature_K
        return params

    def update(
        self,
        kin: StepKinematics,
        state_old: MaterialState,
        params: ElasticParams,
        dt,
        solution: MaterialState | None = None,
    ):
        del solution  # closed form: nothing to solve
        trial = elastic_trial(state_old.stress, kin.dE, params.G_MPa, params.K_MPa)
        stress = finish(kin, trial)
        new = MaterialState(stress=stress, s=state_old.s, eqps=state_old.eqps)
        return stress, new, kin.ok
