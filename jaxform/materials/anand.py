"""Anand's rate-dependent elasto-viscoplasticity in the seed thesis's scheme.

Constitutive functions (thesis eqs. 6.1-6.3 with errata items 2-4):

    epdot = f(sigma, s) = A_eff * sinh(xi * sigma / s) ** (1/m),
    A_eff = A * exp(-Q/(R theta))                     (Table 6.3 gives A_eff directly)
    s_dot = g(sigma, s) = h0 * |1 - s/s*|^a * sign(1 - s/s*) * epdot,
    s*    = s_hat * (epdot / A_eff) ** n.

Integration (ch. 4, App. B): hypoelastic trial stress in the rotation-neutralized frame
(generalized mid-point, alpha from the kinematics), then radial return with beta = 1,
i.e. backward Euler on the two scalar equations (eq. 4.6b with the 3G of errata item 4)

    sigma - sigma_trial + 3 G dt f(sigma, s) = 0,     s - s_n - dt g(sigma, s) = 0.

Local solve.  The seed's own predictor (App. B) overflows for this material because
f is astronomically steep in sigma (sinh(.)^4.3).  We solve instead in the unknown
y = log(d_eqps) with the *inverse* flow law, sigma = (s/xi) asinh((rate/A_eff)^m), which
is gentle:

    F(y) = 3G e^y + (s(y)/xi) asinh(exp(m (y - log(dt A_eff)))) - sigma_trial = 0,

where s(y) is the root of the hardening equation for the plastic strain increment e^y,
    phi(s) = s - s_n - e^y h0 sgnpow(1 - s/s*(y), a) = 0,
which is bracketed by [min(s_n, s*), max(s_n, s*)] (backward Euler cannot overshoot s*).
F is bracketed by y in [log(sigma_trial/3G) - 200, log(sigma_trial/3G)] (all the trial
stress relaxed at the upper end).  Both are solved by Newton safeguarded with bisection
(:mod:`jaxform.implicit`), so the solve converges for any finite step and rate.  That
nested solve evaluates the hardening root afresh at every outer iterate (~5 x ~5 scalar
evaluations a point); the same pair is found first by Newton on both equations at once
from the same start (y from the viscous estimate, s = s_n; ~5 iterations of the 2x2
system), and the nested solve runs only where that did not converge (under vmap its loops
run as long as one point of the batch needs them, none when all converged).  The
solution is differentiated by the implicit function theorem once, at the converged pair
(y, s), from the 2x2 Jacobian of both equations (``_local_solution`` below), not root by
root through the nesting.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import partial
from typing import ClassVar

import jax
import jax.numpy as jnp

from jaxform.implicit import bracketed_newton, root_scalar
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
class AnandParams:
    """Anand parameters; units are in the names (MPa, 1/s, K)."""

    A_1_s: jax.Array  # pre-exponential factor A (1/s)
    Q_over_R_K: jax.Array  # activation energy over gas constant (K); 0 if A is lumped
    temperature_K: jax.Array  # absolute temperature (K)
    xi: jax.Array  # stress multiplier
    m: jax.Array  # strain-rate sensitivity of stress
    s0_MPa: jax.Array  # initial deformation resistance
    h0_MPa: jax.Array  # hardening/softening constant
    s_hat_MPa: jax.Array  # saturation coefficient
    n: jax.Array  # strain-rate sensitivity of the saturation value (b in Table 6.1)
    a: jax.Array  # strain-rate sensitivity of hardening
    G_MPa: jax.Array  # shear modulus
    K_MPa: jax.Array  # bulk modulus

    def log_a_eff(self):
        return jnp.log(self.A_1_s) - self.Q_over_R_K / self.temperature_K


def _asinh_exp(t):
    """asinh(exp(t)), overflow-free for any t."""
    big = t > 0.0
    tb = jnp.where(big, t, 0.0)
    ts = jnp.where(big, 0.0, t)
    return jnp.where(
        big, tb + jnp.log1p(jnp.sqrt(1.0 + jnp.exp(-2.0 * tb))), jnp.arcsinh(jnp.exp(ts))
    )


def _signed_pow(u, a):
    """sign(u) |u|^a with a finite derivative at u = 0 (zero there for a > 1).  |u|^a as
    exp(a log |u|): XLA's CPU programs evaluate exp and log vectorized, but a power with
    a traced exponent one element at a time through libm (the benchmarks page, "Powers
    through exp and log")."""
    nz = u != 0.0
    au = jnp.where(nz, jnp.abs(u), 1.0)
    return jnp.where(nz, jnp.sign(u) * jnp.exp(a * jnp.log(au)), 0.0)


def _log_sinh(x):
    """log(sinh(x)) for x > 0, stable for large and small x."""
    return x + jnp.log(-jnp.expm1(-2.0 * x)) - jnp.log(2.0)


def flow_stress(rate, s, p: AnandParams):
    """Inverse of f in sigma: the equivalent stress (MPa) that flows at `rate` (1/s)."""
    return s / p.xi * _asinh_exp(p.m * (jnp.log(rate) - p.log_a_eff()))


def saturation(rate, p: AnandParams):
    """s*(rate) in MPa."""
    return p.s_hat_MPa * jnp.exp(p.n * (jnp.log(rate) - p.log_a_eff()))


def hardening_rate(s, rate, p: AnandParams):
    """ds/d(eqps) = h0 sgnpow(1 - s/s*, a) (MPa)."""
    return p.h0_MPa * _signed_pow(1.0 - s / saturation(rate, p), p.a)


def _s_residual(s, args):
    y, s_n, log_dt, p = args
    rate = jnp.exp(y - log_dt)
    return s - s_n - jnp.exp(y) * hardening_rate(s, rate, p)


def _flow_residual(y, s, sig_tr, log_dt, p: AnandParams):
    """Eq. 4.6b in the unknown y = log(d_eqps), with the inverse flow law (MPa)."""
    log_dt_a = log_dt + p.log_a_eff()
    return 3.0 * p.G_MPa * jnp.exp(y) + s / p.xi * _asinh_exp(p.m * (y - log_dt_a)) - sig_tr


def _local_residual(z, args):
    """Both backward-Euler equations at z = (y, s): flow (MPa) and hardening (MPa)."""
    sig_tr, s_n, log_dt, p = args
    y, s = z[0], z[1]
    return jnp.stack([_flow_residual(y, s, sig_tr, log_dt, p), _s_residual(s, (y, s_n, log_dt, p))])


def _newton_2x2(j, b):
    """(d0, d1, regular): d = -j^-1 b for a 2x2 j by Cramer's rule, and whether j is
    regular (d = 0 where it is not: no division by zero, no NaN derivative)."""
    det = j[0, 0] * j[1, 1] - j[0, 1] * j[1, 0]
    regular = det != 0.0
    inv_det = jnp.where(regular, 1.0 / jnp.where(regular, det, 1.0), 0.0)
    d0 = -(j[1, 1] * b[0] - j[0, 1] * b[1]) * inv_det
    d1 = -(j[0, 0] * b[1] - j[1, 0] * b[0]) * inv_det
    return d0, d1, regular


JOINT_MIN_POINTS = 4_000  # Gauss points (1 000 four-point elements) from which the
# joint local solve pays for its compile time within one run (:meth:`Anand.for_points`)


@dataclass(frozen=True)
class Anand:
    """Anand elasto-viscoplastic law (strategy: local-solve tolerances and caps)."""

    name: str = "anand"
    # the parameters a design or identification run varies by default
    design_params: ClassVar[tuple[str, ...]] = ("s0_MPa", "h0_MPa", "s_hat_MPa")
    max_outer: int = 100
    max_inner: int = 80
    max_joint: int = 12
    rtol: float = 1e-13
    joint: bool = True  # Newton on both equations first (False: the nested solve alone)

    def for_points(self, n_points: int) -> Anand:
        """The strategy for a mesh of ``n_points`` Gauss points: the joint Newton first
        from JOINT_MIN_POINTS on, the nested solve alone below.  The joint solve halves
        the local solves' run time but adds ~1k equations to every program holding the
        update (~0.5 s of compile, docs/benchmarks.md); on a 10 x 10 mesh the local solves
        of a whole run cost ~0.05 s, so a small scene compiles the smaller program."""
        return replace(self, joint=n_points >= JOINT_MIN_POINTS)

    def initial_state(self, params: AnandParams) -> MaterialState:
        s0 = jnp.asarray(params.s0_MPa)
        z = jnp.zeros((), s0.dtype)
        return MaterialState(stress=jnp.zeros((3, 3), s0.dtype), s=s0 + z, eqps=z)

    def shear_modulus(self, params: AnandParams):
        return params.G_MPa

    def at_temperature(self, params: AnandParams, temperature_K):
        """The parameters at temperature_K (K): the Arrhenius factor exp(-Q/(R theta))
        follows it (a lumped preset, Q/R = 0, does not depend on it)."""
        return replace(params, temperature_K=temperature_K)

    # -- the local solve ------------------------------------------------------------
    def _s_of_y(self, y, s_n, log_dt, p: AnandParams, known=None):
        """The hardening root s(y) (differentiable: the outer solve's slope needs ds/dy);
        ``known = (s, flag)``: s is already the root where flag holds (not differentiated)."""
        rate = jnp.exp(y - log_dt)
        s_star = saturation(rate, p)
        lo = jnp.minimum(s_n, s_star)
        hi = jnp.maximum(s_n, s_star)
        scale = jnp.abs(s_n) + jnp.abs(s_star)
        args = (y, s_n, log_dt, p)
        tol = self.rtol * scale
        if known is None:
            return root_scalar(_s_residual, args, lo, hi, s_n, tol, tol, self.max_inner)
        s0, flag = known
        s, conv = bracketed_newton(
            _s_residual, args, (lo, hi), jnp.where(flag, s0, s_n), tol, tol, self.max_inner, flag
        )
        return s, conv.astype(s.dtype)

    def _y_residual(self, y, args):
        sig_tr, s_n, log_dt, p = args
        s, _ = self._s_of_y(y, s_n, log_dt, p)
        return _flow_residual(y, s, sig_tr, log_dt, p)

    def _start(self, sig_tr, s_n, log_dt, p: AnandParams):
        """The bracket of y and the start inside it (the viscous estimate at s_n)."""
        y_hi = jnp.log(sig_tr / (3.0 * p.G_MPa))
        y_lo = y_hi - 200.0
        log_dt_a = log_dt + p.log_a_eff()
        x = p.xi * sig_tr / s_n
        y_visc = log_dt_a + _log_sinh(jnp.minimum(x, 700.0)) / p.m
        return y_lo, y_hi, jnp.clip(y_visc, y_lo, y_hi)

    def joint_newton(self, sig_tr, s_n, log_dt, p: AnandParams):
        """Newton on both backward-Euler equations at once, z = (y, s), from the nested
        solve's start, y kept in its bracket: (y, s, converged as bool).  Converged: the
        last step or both residuals within the nested solve's tolerances (rtol in y,
        rtol sig_tr in the flow equation, rtol (|s_n| + |s|) in s).  A non-finite or
        non-positive iterate, or ``max_joint`` iterations, leave it unconverged."""
        y_lo, y_hi, y0 = self._start(sig_tr, s_n, log_dt, p)
        args = (sig_tr, s_n, log_dt, p)

        def with_value(z):
            r = _local_residual(z, args)
            return r, r

        def cond(c):
            return ~c[2] & ~c[3] & (c[1] < self.max_joint)

        def body(c):
            z, it = c[0], c[1]
            jz, r = jax.jacfwd(with_value, has_aux=True)(z)
            dy, ds, regular = _newton_2x2(jz, r)
            tol_s = self.rtol * (jnp.abs(s_n) + jnp.abs(z[1]))
            small_r = (jnp.abs(r[0]) <= self.rtol * sig_tr) & (jnp.abs(r[1]) <= tol_s)
            small_step = (jnp.abs(dy) <= self.rtol) & (jnp.abs(ds) <= tol_s)
            zn = jnp.where(small_r, z, jnp.stack([jnp.clip(z[0] + dy, y_lo, y_hi), z[1] + ds]))
            bad = ~regular | ~jnp.all(jnp.isfinite(zn)) | (zn[1] <= 0.0)
            return zn, it + 1, (small_r | small_step) & ~bad, bad

        init = (jnp.stack([y0, s_n]), jnp.asarray(0), jnp.asarray(False), jnp.asarray(False))
        z, _, done, _ = jax.lax.while_loop(cond, body, init)
        return z[0], z[1], done

    def nested_solve(self, sig_tr, s_n, log_dt, p: AnandParams):
        """The nested safeguarded solve alone: (y = log d_eqps, s_new, converged as
        1.0/0.0), differentiable root by root (the reference of the tests)."""
        y_lo, y_hi, y0 = self._start(sig_tr, s_n, log_dt, p)
        args = (sig_tr, s_n, log_dt, p)
        y, conv_y = root_scalar(
            self._y_residual, args, y_lo, y_hi, y0, self.rtol, self.rtol * sig_tr, self.max_outer
        )
        s_new, conv_s = self._s_of_y(y, s_n, log_dt, p)
        return y, s_new, conv_y * conv_s

    def local_solve(self, sig_tr, s_n, log_dt, p: AnandParams):
        """(y = log d_eqps, s_new, converged as 1.0/0.0): :meth:`joint_newton`, and the
        nested solve where it did not converge (not differentiable itself: see
        ``_local_solution``).  ``joint = False``: the nested solve alone."""
        if not self.joint:
            return self.nested_solve(sig_tr, s_n, log_dt, p)
        y_j, s_j, joint = self.joint_newton(sig_tr, s_n, log_dt, p)
        y_lo, y_hi, y0 = self._start(sig_tr, s_n, log_dt, p)
        y, conv_y = bracketed_newton(
            self._y_residual,
            (sig_tr, s_n, log_dt, p),
            (y_lo, y_hi),
            jnp.where(joint, y_j, y0),
            self.rtol,
            self.rtol * sig_tr,
            self.max_outer,
            joint,
        )
        s_new, conv_s = self._s_of_y(y, s_n, log_dt, p, known=(s_j, joint))
        return y, s_new, conv_y.astype(y.dtype) * conv_s

    def return_map(self, sig_tr, s_n, dt, p: AnandParams, solution=None):
        """Solve eq. 4.6b given the trial equivalent stress (> 0).

        ``solution``: ``(d_eqps, s_new)`` of this same return map when it was already
        solved (at the same input): taken as the converged point without solving again,
        the derivatives taken there (the Jacobian pass of the assembly).
        Returns (d_eqps, s_new, sigma_new, converged).
        """
        log_dt = jnp.log(dt)
        if solution is None:
            y, s_new, conv = _local_solution(self, sig_tr, s_n, log_dt, p)
        else:
            d_known, s_known = solution
            # log of the known increment, kept inside the solve's bracket: an increment
            # lost to rounding in eqps_new - eqps_old (below 1e-16 of eqps) flows at the
            # bracket's lower end, where the flow is negligible as it is at the root
            y_hi = jnp.log(sig_tr / (3.0 * p.G_MPa))
            y_known = jnp.clip(jnp.log(jnp.maximum(d_known, 1e-300)), y_hi - 200.0, y_hi)
            y, s_new, conv = _solution_at(y_known, s_known, sig_tr, s_n, log_dt, p)
        deqps = jnp.exp(y)
        sigma_new = sig_tr - 3.0 * p.G_MPa * deqps
        ok = (conv > 0.5) & jnp.isfinite(sigma_new) & jnp.isfinite(s_new)
        return deqps, s_new, sigma_new, ok

    # -- the material update ----------------------------------------------------------
    def update(
        self,
        kin: StepKinematics,
        state_old: MaterialState,
        params: AnandParams,
        dt,
        solution: MaterialState | None = None,
    ):
        p = params
        trial = elastic_trial(state_old.stress, kin.dE, p.G_MPa, p.K_MPa)
        sig_tr, positive = trial_equivalent(trial)
        # A trial stress this small flows by less than 1e-80 of itself: elastic exactly.
        flows = positive & (sig_tr > 1e-12 * state_old.s)
        sig_safe = jnp.where(flows, sig_tr, state_old.s)
        known = None if solution is None else (solution.eqps - state_old.eqps, solution.s)
        deqps, s_new, sig_new, ok_local = self.return_map(sig_safe, state_old.s, dt, p, known)
        deqps = jnp.where(flows, deqps, 0.0)
        s_new = jnp.where(flows, s_new, state_old.s)
        sig_new = jnp.where(flows, sig_new, sig_tr)
        stress_bar = radial_return(trial, sig_new, sig_tr, positive)
        stress = finish(kin, stress_bar)
        new = MaterialState(stress=stress, s=s_new, eqps=state_old.eqps + deqps)
        ok = kin.ok & (ok_local | ~flows) & jnp.all(jnp.isfinite(stress))
        return stress, new, ok


# -- the local solution, differentiated once at the converged point -----------------------
# The solve above is nested (a root in s inside every evaluation of the root in y), so
# differentiating it root by root repeats the inner solve in every derivative evaluation
# of the outer one.  At the converged (y, s) both equations hold, and the implicit
# function theorem gives the tangent from the 2x2 Jacobian of the pair (jax.jacfwd of
# _local_residual, computed from the primal values alone):
#     d(y, s) = -[dR/d(y, s)]^{-1} (dR/d(args) . d(args)).
# Same derivative, no solve in the tangent: the consistent tangent of a Gauss point
# costs its update plus two residual evaluations.
@partial(jax.custom_jvp, nondiff_argnums=(0,))
def _local_solution(law: Anand, sig_tr, s_n, log_dt, p: AnandParams):
    return law.local_solve(sig_tr, s_n, log_dt, p)


def _implicit_tangent(y, s, primals, tangents):
    """d(y, s) at a root (y, s) of _local_residual(., primals), for d(primals) = tangents."""
    z = jnp.stack([y, s])
    jz = jax.jacfwd(_local_residual)(z, primals)
    _, dr = jax.jvp(lambda a: _local_residual(z, a), (primals,), (tangents,))
    dy, ds, _ = _newton_2x2(jz, dr)
    return dy, ds


@_local_solution.defjvp
def _local_solution_jvp(law, primals, tangents):
    y, s, conv = _local_solution(law, *primals)
    dy, ds = _implicit_tangent(y, s, primals, tangents)
    return (y, s, conv), (dy, ds, jnp.zeros_like(conv))


# The same solution when its point is already known (see Anand.return_map's `solution`):
# the value is the given (y, s), the derivative that of the root through it.  The
# tangents of y and s themselves are ignored: they name where the root is, not an input.
@jax.custom_jvp
def _solution_at(y, s, sig_tr, s_n, log_dt, p: AnandParams):
    return y, s, jnp.ones_like(y)


@_solution_at.defjvp
def _solution_at_jvp(primals, tangents):
    y, s, *args = primals
    dy, ds = _implicit_tangent(y, s, tuple(args), tuple(tangents[2:]))
    return (y, s, jnp.ones_like(y)), (dy, ds, jnp.zeros_like(y))
