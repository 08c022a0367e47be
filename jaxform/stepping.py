"""The time-stepping core: one adaptive load step and compiled chunks of them.

Pure functions of immutable state, all compiled: :func:`solve_step` solves one step by
Newton (differentiable by the implicit function theorem), :func:`attempt_step` makes one
converged step of adaptive size (a failed attempt halves the step, down to ``time.dt_s /
2**solver.max_cutbacks``; an easy step lets the next grow by ``time.dt_growth`` up to
``time.dt_s``), and :func:`run_chunk` scans a number of them, reporting each step's
outputs and status code.  The host loop around it (progress, rezoning, the history) is
:mod:`jaxform.simulation`; this module imports no output code.

Scenes are half-height models (symmetry plane z = 0) unless their workpiece says
otherwise (``Stepper.symmetric_z``): the top die travels d(t) towards the mid-plane,
``stroke_mm`` = 2 d(t) and ``force_N`` refer to the whole workpiece (the z-component of
the contact multipliers, which already include the 2 pi of axisymmetry).  Each converged
step also accumulates the friction work (N mm) and each candidate's slip.  Scenes without
a die (a membrane under a traction load, :mod:`jaxform.loads`) have ``Inputs.die = None``;
their ``force_N`` is the magnitude of the applied load's resultant at the step (N, per mm
of depth in plane strain) and ``stroke_mm`` is 0.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import partial
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp

from jaxform.assembly import Indices, Model, StepContext
from jaxform.contact import (
    TOUCH_GAP_MM,
    ContactStep,
    facet_normal,
    facets_in_contact,
    nodal_average,
    shear_bounds,
    tributary_areas,
)
from jaxform.formulations import GaussState, initial_gauss_state
from jaxform.kinematics import deviator, safe_norm_eq
from jaxform.linear import LinearSolver, matvec
from jaxform.loads import external_forces, total_force
from jaxform.rezone import min_quality
from jaxform.solver import ImplicitProblem, NewtonSettings, solve_implicit
from jaxform.status import OK
from jaxform.xla_options import jit

if TYPE_CHECKING:
    from jaxform.scenes import Inputs


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class SimState:
    x: jax.Array  # unknowns: nodal fields and multipliers
    gauss: GaussState
    t: jax.Array  # time (s)
    x_rate: jax.Array  # (x - x_previous) / dt of the last converged step: the predictor
    friction_work: jax.Array  # work dissipated by friction so far (N mm = mJ)
    slip_mm: jax.Array  # (n_c,) accumulated |slip| of each contact candidate (mm)
    contact_status: jax.Array  # (n_c,) 0 open, 1 stick, 2 slip at the last converged step


def initial_state(model: Model, inputs: Inputs) -> SimState:
    """The state at t = 0: no displacement, the material's initial Gauss state."""
    lay = model.layout
    z = jnp.zeros(lay.n_dofs)
    return SimState(
        x=z,
        gauss=initial_gauss_state(model.law, inputs.params, lay.n_elements),
        t=jnp.asarray(0.0),
        x_rate=z,
        friction_work=jnp.asarray(0.0),
        slip_mm=jnp.zeros(lay.n_contact),
        contact_status=jnp.zeros(lay.n_contact, jnp.int32),
    )


def _tree_where(c, a, b):
    return jax.tree_util.tree_map(lambda u, v: jnp.where(c, u, v), a, b)


def contact_step(model: Model, state: SimState, inp: Inputs, idx: Indices) -> ContactStep:
    """The contact conditions' constants for a step starting from ``state``."""
    pos = model.nodal_positions(state.x, inp.coords, idx)[idx.contact_nodes]
    if model.contact.friction == "shear":
        sig = state.gauss.mat.stress
        eq_gp, _ = jnp.vectorize(lambda t: safe_norm_eq(deviator(t)), signature="(3,3)->(),()")(sig)
        eq_el = eq_gp.mean(axis=1)
        eq_nodes = nodal_average(eq_el, idx.elements, model.layout.n_nodes)[idx.contact_nodes]
        # friction acts on the facets in contact only: counting a free facet below an edge
        # node (the bore or the bulge) let the edge carry up to twice m k
        gaps = jax.vmap(lambda p: inp.die.gap(p, state.t)[0])(pos)
        counted = facets_in_contact(gaps <= TOUCH_GAP_MM, idx.contact_facets)
        areas = tributary_areas(pos, idx.contact_facets, model.formulation.axisymmetric, counted)
        bound = shear_bounds(inp.die.m, eq_nodes, areas)
    else:
        bound = jnp.zeros(model.layout.n_contact, dtype=pos.dtype)
    return ContactStep(
        x_old=pos, t_old=state.t, shear_bound=bound, frictionless=idx.contact_fixed_r
    )


def _step_residual(model: Model, x, ctx: StepContext):
    return model.residual(x, ctx)


def _step_residual_and_jacobian(model: Model, x, ctx: StepContext):
    return model.residual_and_jacobian(x, ctx)


def _step_adjoint(model: Model, x, ctx: StepContext, gauss_bar):
    return model.jacobian_and_state_vjp(x, ctx, gauss_bar)


def step_context(
    model: Model, state: SimState, inp: Inputs, idx: Indices, t_new, dt
) -> StepContext:
    """The step data of a step from ``state`` to t_new = state.t + dt: the one place that
    builds a :class:`jaxform.assembly.StepContext`."""
    return StepContext(
        gauss=state.gauss,
        coords=inp.coords,
        t=t_new,
        dt=dt,
        params=inp.params,
        die=inp.die,
        c_contact=inp.c_contact,
        cstep=contact_step(model, state, inp, idx),
        idx=idx,
        f_ext=applied_forces(model, inp, t_new, idx),
    )


@dataclass(frozen=True)
class StepLinear:
    """The linear algebra of a step's Newton solve on the pattern in the StepContext's Indices
    (hashable: a static part of the compiled step).  Called: a solve (or a transposed
    one, for the reverse pass); ``factor`` / ``solve_factored``: a factorization kept
    across iterations and steps (modified Newton) or for the reverse pass; ``matvec``:
    J y (J^T y), to refine a solve with a kept factorization."""

    n: int
    solver: LinearSolver

    def __call__(self, vals, b, ctx: StepContext, transpose: bool):
        idx = ctx.idx
        solve = self.solver.solve_transpose if transpose else self.solver.solve
        return solve(idx.rows, idx.cols, vals, b, self.n, idx.lu_symbolic)

    def factor(self, vals, ctx: StepContext, old):
        idx = ctx.idx
        return self.solver.refactor(idx.rows, idx.cols, vals, self.n, idx.lu_symbolic, old)

    def solve_factored(self, fac, b, ctx: StepContext, transpose: bool = False):
        return self.solver.solve_factored(fac, b, ctx.idx.lu_symbolic, transpose)

    def matvec(self, vals, y, ctx: StepContext, transpose: bool):
        idx = ctx.idx
        rows, cols = (idx.cols, idx.rows) if transpose else (idx.rows, idx.cols)
        return matvec(rows, cols, vals, y, self.n)


@dataclass(frozen=True)
class StepSolution:
    """What a step's Newton solve returns: the unknowns and Gauss state at the end of the
    step, the iterations, the status code, the Newton history (||R_k|| / F), the contact
    constants of the step, and the factorization kept (or None)."""

    x: jax.Array
    gauss: GaussState
    iterations: jax.Array
    code: jax.Array
    hist: jax.Array
    cstep: ContactStep | None
    fac: object = None


def solve_step(
    stepper: Stepper,
    state: SimState,
    t_new,
    inp: Inputs,
    idx: Indices,
    x_guess=None,
    fac=None,
    adjoint_fac=None,
) -> StepSolution:
    """One Newton solve from state (at t) to t_new, starting from x_guess (or state.x;
    state.x also when the guess is not a valid state); ``fac``: the kept factorization for
    ``stepper.newton.method = 'modified'``, or for 'newton' one that each iteration
    replaces, the last returned; ``adjoint_fac``: a factorization near the root for the
    reverse pass to reuse (see :func:`jaxform.solver.solve_implicit`).

    Differentiable (reverse mode) in ``state``, ``t_new`` and ``inp`` by the implicit
    function theorem (:func:`jaxform.solver.solve_implicit`)."""
    model = stepper.model
    ctx = step_context(model, state, inp, idx, t_new, t_new - state.t)
    x_fallback = jax.lax.stop_gradient(state.x)
    x0 = x_fallback if x_guess is None else jax.lax.stop_gradient(x_guess)
    problem = ImplicitProblem(
        partial(_step_residual, model),
        partial(_step_residual_and_jacobian, model),
        partial(_step_adjoint, model),
        StepLinear(model.layout.n_dofs, stepper.linear),
        stepper.newton,
    )
    x, g, its, code, hist, fac = solve_implicit(
        problem,
        x0,
        x_fallback,
        ctx,
        fac,
        adjoint_fac,
    )
    return StepSolution(x, g, its, code, hist, ctx.cstep, fac)


def converged_state(
    model: Model, state: SimState, x, gauss, t_new, inp: Inputs, cstep: ContactStep, idx: Indices
) -> SimState:
    """The state after a converged step from ``state`` to (x, gauss) at t_new: the rate for
    the next predictor, the friction work and slip of the step, the contact status."""
    ctx = StepContext(
        gauss=state.gauss,
        coords=inp.coords,
        t=t_new,
        dt=t_new - state.t,
        params=inp.params,
        die=inp.die,
        c_contact=inp.c_contact,
        cstep=cstep,
        idx=idx,
    )
    status, _, _, slip = model.contact_report(x, ctx)
    lam_t = x[idx.mult_dofs[:, 1]]
    return SimState(
        x=x,
        gauss=gauss,
        t=t_new,
        x_rate=jax.lax.stop_gradient((x - state.x) / (t_new - state.t)),
        friction_work=state.friction_work - jnp.sum(lam_t * slip),
        slip_mm=state.slip_mm + jnp.abs(slip),
        contact_status=status.astype(state.contact_status.dtype),
    )


@dataclass(frozen=True)
class Stepper:
    """The static part of the compiled time stepping (hashable): what a chunk of steps
    solves and how the step size adapts.  A failed attempt halves the step, down to
    ``dt_max / 2**max_cutbacks``; after an easy step (no cutback, at most a fifth of the
    iterations a solve may take) the next one grows by ``dt_growth`` up to ``dt_max``."""

    model: Model
    linear: LinearSolver
    newton: NewtonSettings
    max_cutbacks: int
    dt_growth: float = 1.5
    symmetric_z: bool = True

    def next_step(self, h_used, iterations, cutbacks, dt_max):
        """The size of the next step after one of size h_used."""
        # no shrinking ahead on many iterations: halving after a hard but converged step
        # made the 20 x 20 q1p0 friction scene fail at 54.8 % (72-82 steps, 12-37
        # cutbacks) where the full step completes it (57 steps, no cutback)
        n = self.newton.max_total_iterations
        easy = (cutbacks == 0) & (iterations <= max(n // 5, 1))
        grown = jnp.minimum(dt_max, h_used * self.dt_growth)
        return jnp.where(easy, grown, h_used)


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class StepControl:
    """The traced part of the time stepping: the step size to try next, the largest
    step (``time.dt_s``), the end time, and the rezoning trigger (0: never)."""

    h: jax.Array  # s
    dt_max: jax.Array  # s
    t_end: jax.Array  # s
    rezone_quality: jax.Array


def attempt_step(
    stepper: Stepper, state: SimState, control: StepControl, inp: Inputs, idx: Indices, fac=None
):
    """One converged step from ``state``: tried with ``control.h`` (the last step snapped to
    end exactly at t_end), halved on failure until it converges or reaches the smallest
    step.  Returns (state, info dict, fac): info has the step size taken (h_used),
    iterations and cutbacks of all attempts, the status code, and the Newton history of
    the last attempt; ``fac`` the factorization modified Newton keeps (None for 'newton')."""
    settings = stepper.newton
    n_hist = settings.max_total_iterations + 1
    h_min = control.dt_max * 0.5**stepper.max_cutbacks
    snap = 1e-9 * control.dt_max

    def cond(c):
        return ~c["done"]

    def body(c):
        st, h = c["state"], c["h"]
        t_new = jnp.where(st.t + h >= control.t_end - snap, control.t_end, st.t + h)
        hh = t_new - st.t
        # predictor: the last step's rate, extrapolated (exact for steady motion); not
        # after a failure in this step (the rate may be what failed), and never an invalid one
        use_rate = (c["cutbacks"] == 0).astype(st.x.dtype)
        sol = solve_step(
            stepper, st, t_new, inp, idx, x_guess=st.x + use_rate * hh * st.x_rate, fac=c["fac"]
        )
        ok = sol.code == OK
        conv = converged_state(stepper.model, st, sol.x, sol.gauss, t_new, inp, sol.cstep, idx)
        failed = ~ok & (h <= h_min * (1.0 + 1e-9))  # nothing smaller to try
        return dict(
            state=_tree_where(ok, conv, st),
            h=jnp.where(ok, h, 0.5 * h),
            h_used=hh,
            done=ok | failed,
            iterations=c["iterations"] + sol.iterations,
            last_iterations=sol.iterations,
            cutbacks=c["cutbacks"] + (~ok).astype(jnp.int32),
            code=jnp.where(ok, OK, sol.code),
            hist=sol.hist,
            fac=sol.fac,
        )

    zero = jnp.zeros_like(control.h)
    init = dict(
        state=state,
        h=jnp.maximum(control.h, h_min),
        h_used=zero,
        done=jnp.asarray(False),
        iterations=jnp.asarray(0),
        last_iterations=jnp.asarray(0),
        cutbacks=jnp.asarray(0, jnp.int32),
        code=jnp.asarray(OK),
        hist=jnp.full(n_hist, jnp.inf),
        fac=fac,
    )
    out = jax.lax.while_loop(cond, body, init)
    info = {k: out[k] for k in ("iterations", "cutbacks", "code", "hist", "h_used")}
    info["h_next"] = stepper.next_step(
        out["h_used"], out["last_iterations"], out["cutbacks"], control.dt_max
    )
    return out["state"], info, out["fac"]


def applied_forces(model: Model, inp: Inputs, t, idx: Indices):
    """External nodal forces of the scene's traction load at time t (None without a load)."""
    if inp.load is None:
        return None
    lay = model.layout
    return external_forces(
        inp.load,
        t,
        inp.coords,
        idx.load_facets,
        model.formulation.axisymmetric,
        lay.n_fields,
        lay.n_dofs,
    )


def die_force(model: Model, x, inp: Inputs, t, idx: Indices):
    """Ram force (N, positive in compression): minus the z-component of the force the die
    puts on the workpiece, lambda_n n + lambda_t t summed over the candidates.  Without a
    die: the magnitude of the applied load's resultant at t (0 without a load)."""
    if inp.die is None:
        if inp.load is None:
            return jnp.zeros((), dtype=x.dtype)
        res = total_force(inp.load, inp.coords, idx.load_facets, model.formulation.axisymmetric)
        return inp.load.factor(t) * jnp.sqrt(jnp.sum(res**2))
    pos = model.nodal_positions(x, inp.coords, idx)[idx.contact_nodes]
    _, n, tan = jax.vmap(lambda p: inp.die.gap(p, t))(pos)
    lam = x[idx.mult_dofs]
    force = -jnp.sum(lam[:, 0] * n[:, 1] + lam[:, 1] * tan[:, 1])
    if model.layout.n_facets:  # corner contact: the die pushes a facet along -(its normal)
        ends = model.facet_ends(x, inp.coords, idx)
        n_f = facet_normal(ends[:, 0], ends[:, 1])
        force = force + jnp.sum(x[idx.facet_mult] * n_f[:, 1])
    return force


def step_outputs(model: Model, state: SimState, inp: Inputs, idx: Indices, symmetric_z: bool):
    """Scalars and fields recorded after each step."""
    return dict(
        time_s=state.t,
        stroke_mm=(
            jnp.zeros_like(state.t)
            if inp.die is None
            else (2.0 if symmetric_z else 1.0) * inp.die.travel(state.t)
        ),
        force_N=die_force(model, state.x, inp, state.t, idx),
        friction_work_Nmm=state.friction_work,
        x=state.x,
        stress=state.gauss.mat.stress,
        s=state.gauss.mat.s,
        eqps=state.gauss.mat.eqps,
        slip_mm=state.slip_mm,
        contact_status=state.contact_status,
    )


@partial(jit, static_argnums=(0, 5))
def run_chunk(
    stepper: Stepper,
    state: SimState,
    control: StepControl,
    inp: Inputs,
    idx: Indices,
    n: int,
    fac=None,
):
    """lax.scan over n steps, each one converged step of adaptive size
    (:func:`attempt_step`); steps after the end, after a failure, or after a step that
    left an element corner quality below ``control.rezone_quality`` (the caller rezones
    and goes on) leave the state unchanged and are marked inactive.  ``fac``: the
    factorization modified Newton keeps (None for 'newton'), carried through and returned
    with (state, control for the next chunk, outputs): the caller owns it and frees the
    last one."""
    model = stepper.model

    def step(carry, _):
        st, ctl, failed, paused, fac = carry
        run = (st.t < ctl.t_end) & ~failed & ~paused

        def do(st, fac):
            return attempt_step(stepper, st, ctl, inp, idx, fac)

        def skip(st, fac):
            n_hist = stepper.newton.max_total_iterations + 1
            z = jnp.zeros_like(ctl.h)
            return (
                st,
                dict(
                    iterations=jnp.asarray(0),
                    cutbacks=jnp.asarray(0, jnp.int32),
                    code=jnp.asarray(OK),
                    hist=jnp.full(n_hist, jnp.inf),
                    h_used=z,
                    h_next=ctl.h,
                ),
                fac,
            )

        new, info, fac_new = jax.lax.cond(run, do, skip, st, fac)
        failed = failed | (info["code"] != OK)
        pos = model.nodal_positions(new.x, inp.coords, idx)
        quality = min_quality(pos, idx.elements)
        trigger = ctl.rezone_quality
        paused = paused | (run & ~failed & (trigger > 0.0) & (quality < trigger))
        out = step_outputs(model, new, inp, idx, stepper.symmetric_z)
        out.update(info)
        out["factorizations"] = info["iterations"] if fac is None else fac_new.count - fac.count
        out["active"] = run
        out["mesh_quality"] = quality
        out["paused"] = paused
        return (new, replace(ctl, h=info["h_next"]), failed, paused, fac_new), out

    init = (state, control, jnp.asarray(False), jnp.asarray(False), fac)
    (state, control, _, _, fac), outs = jax.lax.scan(step, init, None, length=n)
    return state, control, outs, fac
