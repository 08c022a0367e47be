"""Load stepping: steps with cutback, chunks of lax.scan, the run's history.

The caller owns the loop (jax-md style): :func:`jaxform.scenes.build_scene` does the
set-up once (mesh, dofs, pattern, material, dies), :func:`simulate` advances it chunk by
chunk through a
compiled ``lax.scan`` over load steps and hands each chunk to an optional progress
callback.  The step adapts (:class:`Stepper`): a failed Newton solve (no convergence, a
failed local material solve, an inverted element) halves it, down to ``time.dt_s /
2**solver.max_cutbacks``; easy steps let it grow back by ``time.dt_growth`` up to
``time.dt_s``.  When a step fails at the smallest size the simulation stops, keeping the
last converged state, and :class:`SimulationError` names the step, the time, the cause
and the worst element.

Scenes are half-height models (symmetry plane z = 0): the top die travels d(t) towards
the mid-plane, ``stroke_mm`` = 2 d(t) and ``force_N`` refer to the whole workpiece (the
z-component of the contact multipliers, which already include the 2 pi of axisymmetry).
Each converged step also accumulates the friction work (N mm) and each candidate's slip.

Scenes without a die (a membrane under a traction load, :mod:`jaxform.loads`) have
``Inputs.die = None`` and no contact candidates; their ``force_N`` is the magnitude of the
applied load's resultant at the step (N, per mm of depth in plane strain) and
``stroke_mm`` is 0.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from jaxform import mesh as meshing
from jaxform.assembly import Indices, Model, StepContext
from jaxform.contact import ContactStep, nodal_average, shear_bounds, tributary_areas
from jaxform.dies import RigidDie
from jaxform.formulations import GaussState, initial_gauss_state
from jaxform.kinematics import deviator, safe_norm_eq
from jaxform.linear import LinearSolver, matvec
from jaxform.loads import FacetLoad, external_forces, total_force
from jaxform.postprocess import extra_history
from jaxform.precision import require_x64
from jaxform.rezone import RezoneError, corner_qualities, min_quality, rezone
from jaxform.solver import NewtonSettings, solve_implicit
from jaxform.status import CAUSES, OK
from jaxform.xla_options import jit


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


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class Inputs:
    """Everything a design may differentiate, passed to the compiled step as arguments."""

    coords: jax.Array  # initial nodal coordinates (mm)
    params: object  # material parameters
    die: RigidDie | None  # profile, path and friction coefficients (None: no die)
    c_contact: jax.Array  # complementarity scale (N/mm), set-up constant
    load: FacetLoad | None = None  # traction load on idx.load_facets (None: no load)


@dataclass(frozen=True)
class Scene:
    """A set-up scene (built by jaxform.scenes.build_scene): the caller runs it."""

    config: dict
    mesh: meshing.Mesh
    model: Model
    idx: Indices
    linear: LinearSolver
    newton: NewtonSettings
    inputs: Inputs
    dt: float
    t_end: float
    max_cutbacks: int
    chunk: int
    kind: str = "billet"  # workpiece: 'billet', 'ring', 'block' or 'membrane'
    symmetric_z: bool = True  # half-height model: stroke = 2 x die travel
    rezone_quality: float = 0.0  # rezone when the worst corner quality drops below (0: never)
    grid: tuple[int, int] | None = None  # (nr, nz) of a structured mesh (rezoning needs it)
    adjoint_memory_mb: float = 0.0  # forward factorizations a gradient run may keep (MB)
    dt_growth: float = 1.5  # an easy step lets the next one grow by this factor (to dt)

    @property
    def n_steps(self) -> int:
        return int(math.ceil(self.t_end / self.dt - 1e-9))

    def step_targets(self) -> np.ndarray:
        k = np.arange(1, self.n_steps + 1)
        return np.minimum(k * self.dt, self.t_end)

    def initial_state(self) -> SimState:
        lay = self.model.layout
        g = initial_gauss_state(self.model.law, self.inputs.params, lay.n_elements)
        z = jnp.zeros(lay.n_dofs)
        zc = jnp.zeros(lay.n_contact)
        return SimState(
            x=z,
            gauss=g,
            t=jnp.asarray(0.0),
            x_rate=z,
            friction_work=jnp.asarray(0.0),
            slip_mm=zc,
            contact_status=jnp.zeros(lay.n_contact, jnp.int32),
        )


class SimulationError(RuntimeError):
    """A step failed after all cutbacks; ``result`` holds the history up to the last good step."""

    def __init__(self, message: str, result):
        super().__init__(message)
        self.result = result


# ----------------------------------------------------------------------------------
# compiled pieces (static: model, linear solver, Newton settings, cutbacks)


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
        areas = tributary_areas(pos, idx.contact_facets, model.formulation.axisymmetric)
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
    x, g, its, code, hist, fac = solve_implicit(
        partial(_step_residual, model),
        partial(_step_residual_and_jacobian, model),
        partial(_step_adjoint, model),
        StepLinear(model.layout.n_dofs, stepper.linear),
        stepper.newton,
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
    return -jnp.sum(lam[:, 0] * n[:, 1] + lam[:, 1] * tan[:, 1])


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


@dataclass
class Result:
    """History (one row per converged load step, row 0 = initial state) and fields."""

    history: dict[str, np.ndarray]
    fields: dict[str, np.ndarray]  # per row: x, stress, s, eqps
    scene: Scene
    final_state: SimState
    newton_histories: np.ndarray  # per step: ||R_k|| / F of the last (sub)step's Newton
    failure: str | None = None
    inputs: Inputs | None = None  # the inputs final_state refers to (coords change on rezoning)
    rezones: list = field(default_factory=list)  # jaxform.rezone.RezoneReport per rezoning


def _absolute(scene: Scene, inp: Inputs, x: np.ndarray) -> np.ndarray:
    """Unknowns with the displacement measured from the scene's reference coordinates
    ``scene.inputs.coords`` (after rezoning the compiled step measures it from the rezoned
    reference ``inp.coords``)."""
    shift = np.asarray(inp.coords) - np.asarray(scene.inputs.coords)
    if not np.any(shift):
        return x
    lay = scene.model.layout
    x = np.array(x)
    lay.nodal(x)[:, :2] += shift  # a view: shifts x in place
    return x


def _failure_message(scene: Scene, inp: Inputs, state: SimState, step: int, row) -> str:
    """Why step ``step`` failed, where: the cause, the time reached, the smallest step
    tried, and the worst element of the last converged mesh (its centre and corner
    quality), which names the place when the cause is geometric (an element folding)."""
    pos = scene.model.nodal_positions(np.asarray(state.x), np.asarray(inp.coords), scene.idx)
    elements = np.asarray(scene.mesh.elements)
    q = corner_qualities(np.asarray(pos), elements).min(axis=1)
    e = int(np.argmin(q))
    centre = np.asarray(pos)[elements[e]].mean(axis=0)
    h_min = scene.dt * 0.5**scene.max_cutbacks
    t = float(state.t)
    return (
        f"step {step} (last converged time {t:g} s, target time "
        f"{min(t + h_min, scene.t_end):g} s) failed after {int(row['cutbacks'])} attempts, "
        f"the last at the smallest step dt = {h_min:g} s (time.dt_s / 2**solver.max_cutbacks): "
        f"{CAUSES.get(int(row['code']), 'unknown')}; worst element {e} at "
        f"({centre[0]:.4g}, {centre[1]:.4g}) mm, corner quality {q[e]:.3g}"
    )


HISTORY_KEYS = (
    "time_s",
    "dt_s",
    "stroke_mm",
    "force_N",
    "iterations",
    "factorizations",
    "cutbacks",
    "friction_work_Nmm",
    "mesh_quality",
    "rezoned",
)
FIELD_KEYS = ("x", "stress", "s", "eqps", "slip_mm", "contact_status")
PROGRESS_KEYS = ("time_s", "stroke_mm", "force_N", "iterations", "cutbacks", "dt_s")


def _initial_row(scene: Scene, state: SimState) -> dict:
    """History row 0: the initial state."""
    out = jax.device_get(
        step_outputs(scene.model, state, scene.inputs, scene.idx, scene.symmetric_z)
    )
    q = min_quality(np.asarray(scene.inputs.coords), np.asarray(scene.mesh.elements))
    return dict(out, iterations=0, factorizations=0, cutbacks=0, code=OK, rezoned=0,
                dt_s=0.0, mesh_quality=float(q))  # fmt: skip


def _progress(scene: Scene, step: int, row: dict) -> dict:
    """What the progress callback gets after a step: its number, an estimate of the
    number of steps (the rest at the largest step) and the row's scalars."""
    left = max(scene.t_end - float(row["time_s"]), 0.0)
    n_steps = step + int(math.ceil(left / scene.dt - 1e-9))
    return dict(step=step, n_steps=n_steps, **{k: row[k] for k in PROGRESS_KEYS})


def _rezone_after(scene: Scene, state: SimState, inp: Inputs, control: StepControl):
    """Rezone after a step that paused the chunk: (state, inputs, control, report).  A
    rezoning that could not raise the quality keeps the mesh and waits until the quality
    has fallen by another 10 %.  Raises RezoneError."""
    state, inp, report = rezone(scene, state, inp)
    trigger = scene.rezone_quality if report.improved else 0.9 * report.quality_before
    return state, inp, replace(control, rezone_quality=jnp.asarray(trigger)), report


def simulate(scene: Scene, progress: Callable[[dict], None] | None = None) -> Result:
    """Run the scene to its end; raises SimulationError (with .result) on failure.

    Steps adapt (:class:`Stepper`): ``scene.dt`` is the largest step, a failed attempt
    halves it, easy steps let it grow back; every converged step is a history row
    (column ``dt_s``), and the run ends exactly at ``scene.t_end``.  With
    ``scene.rezone_quality`` > 0, a step after which an element's worst corner quality
    is below it ends the compiled chunk; the mesh is rezoned (:mod:`jaxform.rezone`) and
    the run goes on from there (history column ``rezoned`` = 1 on that step).

    Arguments:
        scene: a scene built by :func:`jaxform.scenes.build_scene`.
        progress: called after each converged step with a dict (step, n_steps estimate,
            time_s, stroke_mm, force_N, iterations, cutbacks, dt_s), or None.

    Returns:
        A :class:`Result`: the history (one row per converged step, row 0 the initial
        state), the fields, the final state and the rezoning reports."""
    require_x64()
    state, inp = scene.initial_state(), scene.inputs
    stepper = Stepper(scene.model, scene.linear, scene.newton, scene.max_cutbacks,
                      scene.dt_growth, scene.symmetric_z)  # fmt: skip
    control = StepControl(h=jnp.asarray(scene.dt), dt_max=jnp.asarray(scene.dt),
                          t_end=jnp.asarray(scene.t_end),
                          rezone_quality=jnp.asarray(scene.rezone_quality))  # fmt: skip
    rows, rezones, failure = [_initial_row(scene, state)], [], None
    t_stop = scene.t_end - 1e-9 * scene.dt
    modified = scene.newton.method == "modified"
    n = scene.model.layout.n_dofs
    owned = [scene.linear.empty_factorization(n, state.x.dtype) if modified else None]
    try:
        while float(state.t) < t_stop and failure is None:
            fac, owned[0] = owned[0], None  # the chunk frees it when it refactors
            state_new, control, outs, owned[0] = run_chunk(
                stepper, state, control, inp, scene.idx, scene.chunk, fac
            )
            outs = jax.device_get(outs)
            for j in range(scene.chunk):
                row = {k: v[j] for k, v in outs.items()}
                if not row["active"]:
                    break
                if int(row["code"]) != OK:
                    failure = _failure_message(scene, inp, state_new, len(rows), row)
                    break
                row.update(x=_absolute(scene, inp, row["x"]), dt_s=float(row["h_used"]),
                           rezoned=int(bool(row["paused"])))  # fmt: skip
                rows.append(row)
                if progress is not None:
                    progress(_progress(scene, len(rows) - 1, row))
            state = state_new
            if rows[-1]["rezoned"] and float(state.t) >= t_stop:
                rows[-1]["rezoned"] = 0  # the run ends here: nothing to rezone for
            if rows[-1]["rezoned"] and failure is None:
                try:
                    state, inp, control, report = _rezone_after(scene, state, inp, control)
                except RezoneError as err:
                    failure = f"step {len(rows) - 1}: {err}"
                else:
                    rezones.append(report)
                    rows[-1]["rezoned"] = int(report.improved)
    finally:
        # the last factorization modified Newton kept is freed here; one a raising chunk
        # held is lost, never freed twice
        if owned[0] is not None:
            jax.block_until_ready(scene.linear.release(owned[0]))
    history = {k: np.array([float(r[k]) for r in rows]) for k in HISTORY_KEYS}
    history["newton_iterations"] = history.pop("iterations")
    fields = {k: np.stack([np.asarray(r[k]) for r in rows]) for k in FIELD_KEYS}
    history.update(extra_history(scene, fields["x"], history["time_s"]))
    hists = np.array([r["hist"] for r in rows[1:]])
    result = Result(history=history, fields=fields, scene=scene, final_state=state,
                    newton_histories=hists, failure=failure, inputs=inp,
                    rezones=rezones)  # fmt: skip
    if failure:
        raise SimulationError(failure, result)
    return result
