"""Heat balance of one element: transient conduction, plastic heating, die and air exchange.

The thermal sibling of the stress divergence (:mod:`jaxform.formulations`): a pure function
of ONE element, vmapped by the assembly, whose Jacobian (with the thermo-mechanical
coupling) comes from the same ``jax.jacfwd`` as the mechanics.

Contract.  :func:`element_heat` takes the element's reference coordinates, its nodal
displacements u (4, 2) and temperature changes theta (4,) at t_{n+1}, the step's
:class:`ElementHeat` (theta at t_n, which edges exchange heat and which of those touch a
die), the
Gauss state before and after the step (for the plastic work), and returns the nodal heat
terms of the step (:class:`HeatTerms`, each (4,), in mW = N mm/s).  The residual of node a
is their signed sum (backward Euler, balance of the heat of the step):

    R_a = C_a (T_a - T_a,n)/dt + int k grad N_a . grad T dv - beta int N_a w_p/dt dv
          + int_exposed N_a q dA

* C_a = rho c int N_a dV0: the row-sum lumped heat capacity on the reference volume
  (mass is conserved, so rho0 c dV0 is the heat capacity of the material the node
  carries); lumping keeps a chilled step free of undershoot below the die temperature;
* conduction with the current gradients and volume (updated geometry), isotropic k;
* w_p = sigma_eq d_eqps: the plastic work of the step per current volume (Cauchy stress,
  equivalent plastic strain increment), beta the Taylor-Quinney factor;
* q: the heat flux leaving through an exposed edge, h_die (T - T_die(t)) where the edge
  touches a die at the start of the step (both nodes within ``TOUCH_GAP_MM``, as for
  friction), else h_air (T - T_air) + eps sigma_SB (T^4 - T_air^4); 2-point Gauss on the
  edge in its current position (2 pi r for axisymmetry).  Axis and mid-plane edges are not
  exposed: adiabatic by symmetry.

Since the N_a sum to one, the conduction terms sum to zero and the assembled residual
sums to stored - plastic + die + air heat: the discrete energy balance is exact at a
converged step (:func:`jaxform.assembly.Model.heat_flows` reports its terms).

The unknown is theta = T - T_0, the change from the billet temperature T_0 (an input: its
derivative reaches every term through T = T_0 + theta): the stored heat C (theta - theta_n)
then keeps its digits when C is large or the change small, where C (T - T_n) of two
absolute temperatures near 700 K would lose them.

Units: mm, s, N, K; energy in mJ (= N mm), power in mW.  The inputs keep the units the
config names (kg/m^3, J/kg K, W/m K, W/m^2 K); :class:`ThermalInputs` converts:
rho c in J/(m^3 K) x 1e-6 = mJ/(mm^3 K); k in W/(m K) = mW/(mm K); h in W/(m^2 K) x 1e-3
= mW/(mm^2 K).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxform import element as el
from jaxform.kinematics import deviator, safe_norm_eq
from jaxform.materials.base import MaterialState
from jaxform.mesh import boundary_edges
from jaxform.smallmat import det3, inv2
from jaxform.tables import interp_table

STEFAN_BOLTZMANN_W_M2K4 = 5.670374419e-8
_PER_MM2 = 1e-3  # W/m^2 -> mW/mm^2
_PER_MM3 = 1e-6  # J/m^3 -> mJ/mm^3
_EDGE_GAUSS = np.array([0.5 - 0.5 / np.sqrt(3.0), 0.5 + 0.5 / np.sqrt(3.0)])
# sets whose edges are adiabatic (symmetry): the axis and the mid-plane
ADIABATIC_SETS = ("axis", "symmetry")


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class ThermalInputs:
    """Everything thermal a design may differentiate (units in the names)."""

    billet_temperature_K: jax.Array  # initial temperature of the workpiece
    die_temperature_K: jax.Array
    air_temperature_K: jax.Array
    htc_die_W_m2K: jax.Array  # contact conductance to the dies
    htc_air_W_m2K: jax.Array  # convection to the air
    emissivity: jax.Array  # radiation to the air (0: none)
    taylor_quinney: jax.Array  # fraction of the plastic work turned into heat
    density_kg_m3: jax.Array
    specific_heat_J_kgK: jax.Array
    conductivity_W_mK: jax.Array
    dwell_s: jax.Array = 0.0  # before this time no heat flows to the dies (s)
    # the die temperature's change (K) from die_temperature_K along a time table (s)
    die_path_time_s: jax.Array = (0.0,)
    die_path_change_K: jax.Array = (0.0,)

    @property
    def capacity(self):
        """rho c in mJ/(mm^3 K) (= MPa/K)."""
        return self.density_kg_m3 * self.specific_heat_J_kgK * _PER_MM3

    def die_temperature(self, t):
        """The die temperature (K) at time t (s)."""
        change = interp_table(t, self.die_path_time_s, self.die_path_change_K)
        return self.die_temperature_K + change

    def flux_out(self, temp, touching, die_k):
        """Heat flux leaving the workpiece (mW/mm^2) at temperature temp (K): to a die at
        die_k (K) where ``touching`` (1.0), else to the air by convection and radiation."""
        t_air = self.air_temperature_K
        to_die = self.htc_die_W_m2K * _PER_MM2 * (temp - die_k)
        to_air = _PER_MM2 * (
            self.htc_air_W_m2K * (temp - t_air)
            + self.emissivity * STEFAN_BOLTZMANN_W_M2K4 * (temp**4 - t_air**4)
        )
        return touching * to_die + (1.0 - touching) * to_air


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class ElementHeat:
    """One step's thermal data of each element (leading axis: element)."""

    theta_old: jax.Array  # (4,) nodal temperature changes from the billet's at t_n (K)
    exposed: jax.Array  # (4,) 1.0 where edge k (nodes k, k+1) exchanges heat
    touch: jax.Array  # (4,) 1.0 where that edge touches a die at t_n
    die_K: jax.Array  # () the die temperature at t_{n+1} (K)


class HeatTerms(NamedTuple):
    """Nodal heat terms of one element's step (each (4,), mW); the residual is
    ``stored + conduction - plastic + die + air``."""

    stored: jax.Array  # C_a (T_a - T_a,n) / dt
    conduction: jax.Array
    plastic: jax.Array  # heat generated by plastic work
    die: jax.Array  # heat given to the dies
    air: jax.Array  # heat given to the air

    def residual(self):
        return self.stored + self.conduction - self.plastic + self.die + self.air

    def magnitude(self):
        """Sum of the terms' magnitudes: the heat scale of the step (mW)."""
        return sum(jnp.abs(t) for t in self)


def plastic_work(old: MaterialState, new: MaterialState):
    """sigma_eq d_eqps at each Gauss point: the plastic work of the step per current
    volume (mJ/mm^3), with the stress at the end of the step (backward Euler)."""
    s_eq, _ = jax.vmap(lambda s: safe_norm_eq(deviator(s)))(new.stress)
    return s_eq * jnp.maximum(new.eqps - old.eqps, 0.0)


def element_heat(
    th: ThermalInputs,
    dt,
    x_ref,
    u,
    theta,
    heat: ElementHeat,
    work,
    axisymmetric: bool,
) -> HeatTerms:
    """The :class:`HeatTerms` of one element (see the module docstring); ``theta``: the
    nodal temperature changes from the billet temperature at t_{n+1} (K); ``work``: the
    plastic work of the step at the Gauss points (:func:`plastic_work`)."""
    temp = th.billet_temperature_K + theta
    dndx, radius, weight, _ = el.gauss_geometry(x_ref, axisymmetric)
    f = el.deformation_gradient(u, dndx, radius, axisymmetric)
    dv = det3(f) * weight  # current volume weights
    grad_n = jnp.einsum("gaj,gji->gai", dndx, inv2(f[:, :2, :2]))  # current gradients
    grad_t = jnp.einsum("gai,a->gi", grad_n, temp)
    k = th.conductivity_W_mK
    conduction = k * jnp.einsum("gai,gi,g->a", grad_n, grad_t, dv)
    lumped = el.N_GP.T @ weight  # int N_a dV0
    stored = th.capacity * lumped * (theta - heat.theta_old) / dt
    plastic = th.taylor_quinney * (el.N_GP.T @ (work * dv)) / dt
    # exposed edges, in their current position
    pos = x_ref + u
    a, b = jnp.arange(4), (jnp.arange(4) + 1) % 4
    s = jnp.asarray(_EDGE_GAUSS)
    n_a = 1.0 - s  # (2,) shape values of the edge's first node at its Gauss points
    length = jnp.linalg.norm(pos[b] - pos[a], axis=1)  # (4,)
    t_gp = n_a[None, :] * temp[a][:, None] + s[None, :] * temp[b][:, None]  # (edge, 2)
    if axisymmetric:
        r_gp = n_a[None, :] * pos[a, 0][:, None] + s[None, :] * pos[b, 0][:, None]
        w = 2.0 * jnp.pi * r_gp * 0.5 * length[:, None]
    else:
        w = 0.5 * length[:, None] * jnp.ones((1, 2))
    w = w * heat.exposed[:, None]
    touch = heat.touch[:, None]

    def edge_nodal(q):  # (edge, 2) flux at the edge points -> (4,) nodal heat
        on_a = jnp.sum(q * w * n_a[None, :], axis=1)
        on_b = jnp.sum(q * w * s[None, :], axis=1)
        return jnp.zeros(4, dtype=temp.dtype).at[a].add(on_a).at[b].add(on_b)

    die = edge_nodal(touch * th.flux_out(t_gp, 1.0, heat.die_K))
    air = edge_nodal((1.0 - touch) * th.flux_out(t_gp, 0.0, heat.die_K))
    return HeatTerms(stored, conduction, plastic, die, air)


def exposed_edges(elements: np.ndarray, facet_sets: dict) -> np.ndarray:
    """(n_el, 4) 1.0 where element edge k (nodes k, k+1) lies on the boundary and not on
    an adiabatic set (:data:`ADIABATIC_SETS`)."""
    elements = np.asarray(elements, dtype=np.int64)
    n = int(elements.max()) + 1
    edges = np.stack([elements, np.roll(elements, -1, axis=1)], axis=2)  # (n_el, 4, 2)
    key = edges[..., 0] * n + edges[..., 1]
    walked = boundary_edges(elements)
    adiabatic = [np.asarray(facet_sets[s], dtype=np.int64).reshape(-1, 2)
                 for s in ADIABATIC_SETS if s in facet_sets]  # fmt: skip
    adiabatic = np.concatenate(adiabatic) if adiabatic else np.zeros((0, 2), np.int64)
    both = np.concatenate([adiabatic, adiabatic[:, ::-1]])
    on_boundary = np.isin(key, walked[:, 0] * n + walked[:, 1])
    return (on_boundary & ~np.isin(key, both[:, 0] * n + both[:, 1])).astype(float)
