"""Element residuals: stress divergence of the three quadrilateral formulations.

Contract: ``Formulation.residual(law, params, dt, x_ref, dofs, gstate)`` is a pure
function of ONE element (vmapped over elements by the assembly), returning

* ``r`` (4, n_fields): nodal residuals, the displacement columns in N (forces), the
  pressure column (q1q1) scaled by K/h0 so that it is in N as well;
* the new Gauss-point state (:class:`GaussState`), and a status code: ``OK``,
  ``LOCAL_SOLVE_FAILED`` (a material update did not converge) or ``INVERTED``
  (det F <= 0 at a Gauss point).

Formulations (``mesh.element``; :func:`formulation` maps the name to the two static
switches of :class:`Formulation`, ``mean_dilatation`` and ``mixed_pressure``):

* ``q4``   plain displacement quadrilateral: locks for nearly incompressible flow.
* ``q1p0`` F-bar / mean dilatation: the material sees F_bar = (J_bar/J)^(1/3) F with
  J_bar the element's volume ratio; virtual work with the actual F (de Souza Neto et al.
  1996), so the Jacobian is unsymmetric (jacfwd does not care).
* ``q1q1`` the seed's stabilized mixed u-p with equal-order (bilinear) pressure: the
  stress is dev(sigma_material) - p_hat I, and the weak constraint (thesis ch. 5)
      int q (p_material - p_hat)/K dv - int tau grad q . grad p_hat dv = 0,
      tau = theta h^2 / (2 G_flow),  h = sqrt(current element area)
  (Brezzi-Pitkaranta stabilization) removes the spurious pressure modes. G_flow
  (:func:`flow_shear_modulus`) is the elastic G where the material is elastic and the
  flow's incremental stiffness sigma_eq / (3 d_eqps) where it flows. The material
  stores the mixed stress, so p_material = p_hat_n - K tr(dE) in each step.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax.custom_derivatives import SymbolicZero

from jaxform import element as el
from jaxform.kinematics import deviator, safe_norm_eq, step_kinematics
from jaxform.materials.base import MaterialState
from jaxform.smallmat import det3, inv2, inv3
from jaxform.status import INVERTED, LOCAL_SOLVE_FAILED, OK


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class GaussState:
    """State at the Gauss points of the mesh (leading axes: element, Gauss point)."""

    F: jax.Array  # deformation gradient at t_n (F_bar for q1p0), (..., 3, 3)
    mat: MaterialState


class PointGiven(NamedTuple):
    """What an element's material updates take as given instead of computing."""

    solution: GaussState | None = None  # the converged new state (no local solves)
    temperature: jax.Array | None = None  # (4,) Gauss-point temperatures at t_{n+1} (K)


@dataclass(frozen=True)
class Formulation:
    """An element formulation (static, hashable): the seed's q1q1 by default."""

    mixed_pressure: bool = True  # a nodal pressure unknown, stabilized (q1q1)
    mean_dilatation: bool = False  # the material sees F-bar (q1p0)
    axisymmetric: bool = True
    theta: float = 0.1  # q1q1 stabilization factor
    alpha: float = 0.5  # mid-point parameter of the strain increment

    @property
    def n_fields(self) -> int:
        return 3 if self.mixed_pressure else 2

    def residual(self, law, params, dt, x_ref, dofs, gstate: GaussState, given=None):
        """``given`` (:class:`PointGiven`, optional): this element's new Gauss state from
        an earlier evaluation at the same dofs (the material updates then skip their local
        solves: see :mod:`jaxform.materials.base`), and the Gauss points' temperatures at
        the end of the step (K), which the material sees (``law.at_temperature``); None:
        solve, at the parameters' own temperature (isothermal)."""
        given = PointGiven() if given is None else given
        solution, temperature = given.solution, given.temperature
        axi = self.axisymmetric
        u = dofs[:, :2]
        geom = el.gauss_geometry(x_ref, axi)
        dndx, radius, weight, det_ref = geom
        f = el.deformation_gradient(u, dndx, radius, axi)
        det_f = det3(f)
        geom_ok = jnp.all(det_f > 0.0) & jnp.all(det_ref > 0.0)
        if self.mean_dilatation:
            jbar = jnp.sum(det_f * weight) / jnp.sum(weight)
            safe = jnp.where(det_f > 0.0, det_f, 1.0)
            f_mat = f * cube_root(jnp.abs(jbar) / safe)[:, None, None]
        else:
            f_mat = f
        f_rel = jnp.einsum("gij,gjk->gik", f_mat, inv3(gstate.F))

        def point(fr, st, converged, temp):
            p = params if temp is None else law.at_temperature(params, temp)
            return planar_point_update(law, self.alpha, fr, st, p, dt, converged)

        converged = None if solution is None else solution.mat
        sigma, mat_new, ok = jax.vmap(point)(f_rel, gstate.mat, converged, temperature)
        ok = ok > 0.5
        if self.mixed_pressure:
            d_eqps = mat_new.eqps - gstate.mat.eqps
            g_flow = flow_shear_modulus(law.shear_modulus(params), sigma, d_eqps)
            p_hat = el.N_GP @ dofs[:, 2]
            p_mat = -jnp.trace(sigma, axis1=1, axis2=2) / 3.0
            eye = jnp.eye(3, dtype=sigma.dtype)
            sigma = sigma + (p_mat - p_hat)[:, None, None] * eye
            mat_new = MaterialState(stress=sigma, s=mat_new.s, eqps=mat_new.eqps)
        r_u = el.virtual_work_residual(el.first_piola(sigma, f), dndx, radius, weight, axi)
        if self.mixed_pressure:
            r_p = self._pressure_residual(params, f, geom, g_flow, p_mat, dofs[:, 2])
            r = jnp.concatenate([r_u, r_p[:, None]], axis=1)
        else:
            r = r_u
        code = jnp.where(geom_ok, jnp.where(jnp.all(ok), OK, LOCAL_SOLVE_FAILED), INVERTED)
        return r, GaussState(F=f_mat, mat=mat_new), code

    def _pressure_residual(self, params, f, geom: el.GaussGeometry, g_flow, p_mat, p_nodes):
        dndx, weight, det_ref = geom.dndx, geom.weight, geom.det
        k = params.K_MPa
        det_f = det3(f)
        dv = det_f * weight  # current volume weights
        area_cur = jnp.sum(jnp.abs(det_f * det_ref))  # in-plane current area (2x2 rule, w=1)
        h2 = area_cur
        h0 = jnp.sqrt(jnp.sum(det_ref))
        tau = self.theta * h2 / (2.0 * g_flow)  # (4,): one per Gauss point
        f2inv = inv2(f[:, :2, :2])
        grad_n = jnp.einsum("gaj,gji->gai", dndx, f2inv)  # current gradients of N
        p_hat = el.N_GP @ p_nodes
        grad_p = jnp.einsum("gai,a->gi", grad_n, p_nodes)
        r = jnp.einsum("ga,g,g->a", el.N_GP, (p_mat - p_hat) / k, dv)
        r = r - jnp.einsum("g,gai,gi,g->a", tau, grad_n, grad_p, dv)
        return r * (k / h0)


def cube_root(x):
    """x^(1/3) for x > 0 as exp(log(x) / 3): XLA's CPU programs evaluate exp and log
    vectorized, a fractional power one element at a time through libm (the benchmarks
    page, "Powers through exp and log")."""
    return jnp.exp(jnp.log(x) / 3.0)


def flow_shear_modulus(g, sigma, d_eqps):
    """The shear stiffness the step's deformation meets at each Gauss point (MPa):
    1/G_flow = 1/G + 3 d_eqps / sigma_eq.

    Elastic points (d_eqps = 0) give the elastic G; flowing points give ~ sigma_eq /
    (3 d_eqps), the incremental form of the flow viscosity sigma_eq / (3 eqps_rate) of
    rigid-viscoplastic forging codes, which is 10-100x below G in a forging step. The q1q1
    stabilization must scale with the stiffness of the problem it stabilizes: with the
    elastic G alone, tau was 10-100x too small wherever the material flows, and the
    checkerboard pressure mode came back under friction (zig-zag contact pressure and
    shear traction in stick zones)."""
    s_eq, positive = jax.vmap(lambda t: safe_norm_eq(deviator(t)))(sigma)
    # a stress-free point has not flowed: its ratio is 0 (double where: no NaN derivative)
    ratio = jnp.where(positive, jnp.maximum(d_eqps, 0.0) / jnp.where(positive, s_eq, 1.0), 0.0)
    return g / (1.0 + 3.0 * g * ratio)


# -- the material point, with its tangent taken in the 5 components of f ------------------
# A 2-D section's relative deformation gradient has five independent components
# (f11, f12, f21, f22, f33: the block structure of jaxform.kinematics).  The element
# Jacobian is jacfwd over the element dofs (8 for q4/q1p0, 12 for q1q1), and each of those
# tangents would otherwise be pushed through the whole material update (the polar
# decomposition and the nested local Anand solves) at every Gauss point.  The custom JVP
# below computes the point's Jacobian in the five components of f once (jacfwd, the
# consistent tangent, computed from the primal values only, so an outer jacfwd/vmap over
# element tangents does not repeat it) and maps every incoming tangent df through it with
# one small product.  Tangents of the old state, the parameters and dt (gradients for
# design) are pushed through the update itself, and skipped when they are symbolic zeros
# (the Newton assembly).  The values are those of the plain update; the derivatives are
# the same derivatives, computed in another order (tested against the plain jacfwd).
_PLANAR = ((0, 0), (0, 1), (1, 0), (1, 1), (2, 2))


def _planar_components(f):
    return jnp.stack([f[i, j] for i, j in _PLANAR])


def _planar_matrix(v):
    z = jnp.zeros_like(v[0])
    return jnp.array([[v[0], v[1], z], [v[2], v[3], z], [z, z, v[4]]])


def _point(law, alpha, f, state, params, dt, solution=None):
    stress, new, ok = law.update(
        step_kinematics(f, alpha, planar=True), state, params, dt, solution
    )
    return stress, new, jnp.where(ok, 1.0, 0.0).astype(stress.dtype)


@partial(jax.custom_jvp, nondiff_argnums=(0, 1))
def planar_point_update(law, alpha, f, state, params, dt, solution=None):
    """``law.update(step_kinematics(f, alpha, planar=True), state, params, dt, solution)``
    with the ``ok`` flag as a float (1.0 / 0.0), differentiated as described above.
    ``solution`` says where the local solve converges; it is not differentiated."""
    return _point(law, alpha, f, state, params, dt, solution)


def _planar_point_update_jvp(law, alpha, primals, tangents):
    f, state, params, dt, solution = primals
    df, d_state, d_params, d_dt, _ = tangents

    def in_f(v):
        out = _point(law, alpha, _planar_matrix(v), state, params, dt, solution)
        return out, out

    if type(df) is SymbolicZero:  # e.g. a derivative in the parameters alone
        out = _point(law, alpha, f, state, params, dt, solution)
        t_out = jax.tree_util.tree_map(jnp.zeros_like, out)
    else:
        jac, out = jax.jacfwd(in_f, has_aux=True)(_planar_components(f))
        dv = _planar_components(df)
        t_out = jax.tree_util.tree_map(lambda j: j @ dv, jac)
    others = (d_state, d_params, d_dt)
    if not all(type(t) is SymbolicZero for t in jax.tree_util.tree_leaves(others)):
        inst = jax.tree_util.tree_map(
            lambda t, p: jnp.zeros_like(p) if type(t) is SymbolicZero else t,
            others,
            (state, params, dt),
        )
        _, t_rest = jax.jvp(
            lambda s, p, d: _point(law, alpha, f, s, p, d, solution), (state, params, dt), inst
        )
        t_out = jax.tree_util.tree_map(jnp.add, t_out, t_rest)
    return out, t_out


planar_point_update.defjvp(_planar_point_update_jvp, symbolic_zeros=True)


def initial_gauss_state(law, params, n_elements: int) -> GaussState:
    st = law.initial_state(params)
    mat = jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (n_elements, 4) + a.shape), st)
    eye = jnp.broadcast_to(jnp.eye(3), (n_elements, 4, 3, 3))
    return GaussState(F=eye, mat=mat)


# mesh.element -> the formulation's switches
ELEMENTS = {
    "q1q1": dict(mixed_pressure=True, mean_dilatation=False),
    "q1p0": dict(mixed_pressure=False, mean_dilatation=True),
    "q4": dict(mixed_pressure=False, mean_dilatation=False),
}


def formulation(element: str, **settings) -> Formulation:
    """The :class:`Formulation` of ``mesh.element`` = element ('q1q1', 'q1p0' or 'q4'),
    with the other settings (axisymmetric, theta, alpha) passed on."""
    if element not in ELEMENTS:
        raise ValueError(f"mesh.element = {element!r}: must be one of {tuple(ELEMENTS)}")
    return Formulation(**ELEMENTS[element], **settings)
