"""Load stepping: steps with cutback, chunks of lax.scan, the run's history.

The caller owns the loop (jax-md style): :func:`jaxform.scenes.build_scene` does the
set-up once (mesh, dofs, pattern, material, dies), :func:`simulate` advances it chunk by chunk through a
compiled ``lax.scan`` over load steps and hands each chunk to an optional progress
callback.  Inside a step, a failed Newton solve (no convergence, a failed local
material solve, an inverted element) halves the step, up to ``solver.max_cutbacks``
times; when the cutbacks run out the simulation stops, keeping the last converged state,
and :class:`SimulationError` names the step, the time and the cause.

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
from dataclasses import dataclass, field
from functools import partial
from typing import Callable

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
from jaxform.rezone import RezoneError, min_quality, rezone
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
        return SimState(x=z, gauss=g, t=jnp.asarray(0.0), x_rate=z,
                        friction_work=jnp.asarray(0.0), slip_mm=zc,
                        contact_status=jnp.zeros(lay.n_contact, jnp.int32))


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
        eq_gp, _ = jnp.vectorize(lambda t: safe_norm_eq(deviator(t)),
                                 signature="(3,3)->(),()")(sig)
        eq_el = eq_gp.mean(axis=1)
        eq_nodes = nodal_average(eq_el, idx.elements, model.layout.n_nodes)[idx.contact_nodes]
        areas = tributary_areas(pos, idx.contact_facets, model.formulation.axisymmetric)
        bound = shear_bounds(inp.die.m, eq_nodes, areas)
    else:
        bound = jnp.zeros(model.layout.n_contact, dtype=pos.dtype)
    return ContactStep(x_old=pos, t_old=state.t, shear_bound=bound,
                       frictionless=idx.contact_fixed_r)


def _step_residual(model: Model, x, ctx: StepContext):
    return model.residual(x, ctx)


def _step_residual_and_jacobian(model: Model, x, ctx: StepContext):
    return model.residual_and_jacobian(x, ctx)


def _step_adjoint(model: Model, x, ctx: StepContext, gauss_bar):
    return model.jacobian_and_state_vjp(x, ctx, gauss_bar)


def step_context(model: Model, state: SimState, inp: Inputs, idx: Indices, t_new,
                 dt) -> StepContext:
    """The step data of a step from ``state`` to t_new = state.t + dt: the one place that
    builds a :class:`jaxform.assembly.StepContext`."""
    return StepContext(gauss=state.gauss, coords=inp.coords, t=t_new, dt=dt, params=inp.params,
                       die=inp.die, c_contact=inp.c_contact,
                       cstep=contact_step(model, state, inp, idx), idx=idx,
                       f_ext=applied_forces(model, inp, t_new, idx))


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


def solve_step(model: Model, linear: LinearSolver, settings: NewtonSettings,
               state: SimState, t_new, dt, inp: Inputs, idx: Indices, x_guess=None, fac=None,
               adjoint_fac=None):
    """One Newton solve from state (at t) to t_new = t + dt, starting from x_guess (or
    state.x; state.x also when the guess is not a valid state); ``fac``: the kept
    factorization for ``settings.method = 'modified'``, or for 'newton' one that each
    iteration replaces, the last returned; ``adjoint_fac``: a factorization near the root
    for the reverse pass to reuse (see :func:`jaxform.solver.solve_implicit`).

    Differentiable (reverse mode) in ``state`` and ``inp`` by the implicit function theorem
    (:func:`jaxform.solver.solve_implicit`).  Returns (x, gauss, its, code, hist, cstep, fac)."""
    ctx = step_context(model, state, inp, idx, t_new, dt)
    x_fallback = jax.lax.stop_gradient(state.x)
    x0 = x_fallback if x_guess is None else jax.lax.stop_gradient(x_guess)
    x, g, its, code, hist, fac = solve_implicit(
        partial(_step_residual, model), partial(_step_residual_and_jacobian, model),
        partial(_step_adjoint, model), StepLinear(model.layout.n_dofs, linear), settings, x0,
        x_fallback, ctx, fac, adjoint_fac)
    return x, g, its, code, hist, ctx.cstep, fac


def converged_state(model: Model, state: SimState, x, gauss, t_new, inp: Inputs,
                    cstep: ContactStep, idx: Indices) -> SimState:
    """The state after a converged step from ``state`` to (x, gauss) at t_new: the rate for
    the next predictor, the friction work and slip of the step, the contact status."""
    ctx = StepContext(gauss=state.gauss, coords=inp.coords, t=t_new, dt=t_new - state.t,
                      params=inp.params, die=inp.die, c_contact=inp.c_contact, cstep=cstep,
                      idx=idx)
    status, _, _, slip = model.contact_report(x, ctx)
    lam_t = x[idx.mult_dofs[:, 1]]
    return SimState(x=x, gauss=gauss, t=t_new,
                    x_rate=jax.lax.stop_gradient((x - state.x) / (t_new - state.t)),
                    friction_work=state.friction_work - jnp.sum(lam_t * slip),
                    slip_mm=state.slip_mm + jnp.abs(slip),
                    contact_status=status.astype(state.contact_status.dtype))


def macro_step(model, linear, settings, max_cutbacks, state: SimState, t_target, inp, idx,
               fac=None):
    """Advance to t_target, halving the sub-step on failure. Returns (state, info dict,
    fac): ``fac`` the factorization kept by modified Newton (None for 'newton')."""
    n_hist = settings.max_total_iterations + 1

    def cond(c):
        return ~c["done"]

    def body(c):
        st, h = c["state"], c["h"]
        # predictor: the last step's rate, extrapolated (exact for steady motion); not
        # after a failure in this step (the rate may be what failed), and never an invalid one
        use_rate = (c["level"] == 0).astype(st.x.dtype)
        x, g, its, code, hist, cstep, fac_new = solve_step(
            model, linear, settings, st, st.t + h, h, inp, idx,
            x_guess=st.x + use_rate * h * st.x_rate, fac=c["fac"])
        ok = code == OK
        t_new = jnp.where(ok, st.t + h, st.t)
        conv = converged_state(model, st, x, g, st.t + h, inp, cstep, idx)
        new = _tree_where(ok, conv, st)
        level = jnp.where(ok, c["level"], c["level"] + 1)
        failed = level > max_cutbacks
        reached = ok & (t_new >= t_target - 1e-12 * jnp.maximum(1.0, t_target))
        h_next = jnp.where(ok, jnp.minimum(h, t_target - t_new), 0.5 * h)
        return dict(
            state=new, h=h_next, level=level, done=reached | failed,
            iterations=c["iterations"] + its, cutbacks=c["cutbacks"] + (~ok).astype(jnp.int32),
            code=jnp.where(failed, code, jnp.where(ok, OK, c["code"])),
            last_cause=jnp.where(ok, c["last_cause"], code),
            hist=jnp.where(ok, hist, c["hist"]), fac=fac_new,
        )

    init = dict(state=state, h=t_target - state.t, level=jnp.asarray(0), done=jnp.asarray(False),
                iterations=jnp.asarray(0), cutbacks=jnp.asarray(0, jnp.int32),
                code=jnp.asarray(OK), last_cause=jnp.asarray(OK),
                hist=jnp.full(n_hist, jnp.inf), fac=fac)
    out = jax.lax.while_loop(cond, body, init)
    info = {k: out[k] for k in ("iterations", "cutbacks", "code", "hist")}
    return out["state"], info, out["fac"]


def applied_forces(model: Model, inp: Inputs, t, idx: Indices):
    """External nodal forces of the scene's traction load at time t (None without a load)."""
    if inp.load is None:
        return None
    lay = model.layout
    return external_forces(inp.load, t, inp.coords, idx.load_facets,
                           model.formulation.axisymmetric, lay.n_fields, lay.n_dofs)


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
        stroke_mm=(jnp.zeros_like(state.t) if inp.die is None
                   else (2.0 if symmetric_z else 1.0) * inp.die.travel(state.t)),
        force_N=die_force(model, state.x, inp, state.t, idx),
        friction_work_Nmm=state.friction_work,
        x=state.x,
        stress=state.gauss.mat.stress,
        s=state.gauss.mat.s,
        eqps=state.gauss.mat.eqps,
        slip_mm=state.slip_mm,
        contact_status=state.contact_status,
    )


@partial(jit, static_argnums=(0, 1, 2, 4))
def run_chunk(model, linear, settings, max_cutbacks, symmetric_z, state: SimState,
              targets, active, inp: Inputs, idx: Indices, rezone_quality=0.0, fac=None):
    """lax.scan over a chunk of load steps; inactive steps (past the end, after a
    failure, or after a step that left an element corner quality below ``rezone_quality``:
    the caller rezones and goes on) leave the state unchanged.  ``fac``: the factorization
    modified Newton keeps (None for 'newton'), carried through and returned with
    (state, outputs): the caller owns it and frees the last one."""

    def step(carry, tk):
        st, failed, paused, fac = carry
        t_target, act = tk
        run = act & ~failed & ~paused

        def do(st, fac):
            return macro_step(model, linear, settings, max_cutbacks, st, t_target, inp, idx,
                              fac)

        def skip(st, fac):
            n_hist = settings.max_total_iterations + 1
            return st, dict(iterations=jnp.asarray(0), cutbacks=jnp.asarray(0, jnp.int32),
                            code=jnp.asarray(OK), hist=jnp.full(n_hist, jnp.inf)), fac

        new, info, fac_new = jax.lax.cond(run, do, skip, st, fac)
        failed = failed | (info["code"] != OK)
        pos = model.nodal_positions(new.x, inp.coords, idx)
        quality = min_quality(pos, idx.elements)
        paused = paused | (run & ~failed & (rezone_quality > 0.0) & (quality < rezone_quality))
        out = step_outputs(model, new, inp, idx, symmetric_z)
        out.update(info)
        out["factorizations"] = (info["iterations"] if fac is None
                                 else fac_new.count - fac.count)
        out["active"] = run
        out["mesh_quality"] = quality
        out["paused"] = paused
        return (new, failed, paused, fac_new), out

    init = (state, jnp.asarray(False), jnp.asarray(False), fac)
    (state, _, _, fac), outs = jax.lax.scan(step, init, (targets, active))
    return state, outs, fac


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


def simulate(scene: Scene, progress: Callable[[dict], None] | None = None) -> Result:
    """Run the scene to its end, in compiled chunks of load steps.

    Arguments:
        scene: from :func:`jaxform.scenes.build_scene`.
        progress: called after each chunk with a dict (step, n_steps, time_s, stroke_mm,
            force_N, iterations, cutbacks).

    Returns:
        the :class:`Result`: ``history`` (one row per converged step) and ``fields``.

    Raises:
        SimulationError (with ``.result`` up to the last converged step): a step failed
        after all cutbacks.

    With ``scene.rezone_quality`` > 0, a step after which an element's worst corner quality
    is below it ends the compiled chunk; the mesh is rezoned (:mod:`jaxform.rezone`) and
    the run goes on from there (history column ``rezoned`` = 1 on that step).  If no node
    move can raise the quality, the mesh stays as it is and the next attempt waits until
    the quality has fallen by another 10 %."""
    require_x64()
    targets = scene.step_targets()
    n = len(targets)
    c = scene.chunk
    state = scene.initial_state()
    inp = scene.inputs
    st_args = (scene.model, scene.linear, scene.newton, jnp.asarray(scene.max_cutbacks),
               scene.symmetric_z)
    init = jax.device_get(step_outputs(scene.model, state, inp, scene.idx, scene.symmetric_z))
    rows = [dict(init, iterations=0, factorizations=0, cutbacks=0, code=OK, rezoned=0,
                 mesh_quality=float(min_quality(np.asarray(scene.inputs.coords),
                                                np.asarray(scene.mesh.elements))))]
    hists = []
    rezones = []
    failure = None
    trigger = scene.rezone_quality
    k0 = 0
    owned = [scene.linear.empty_factorization(scene.model.layout.n_dofs, state.x.dtype)
             if scene.newton.method == "modified" else None]
    try:
        while k0 < n and failure is None:
            tk = np.full(c, targets[-1])
            act = np.zeros(c, dtype=bool)
            m = min(c, n - k0)
            tk[:m], act[:m] = targets[k0:k0 + m], True
            fac, owned[0] = owned[0], None  # the chunk frees it when it refactors
            state_new, outs, owned[0] = run_chunk(*st_args, state, jnp.asarray(tk),
                                                  jnp.asarray(act), inp, scene.idx,
                                                  jnp.asarray(trigger), fac)
            outs = jax.device_get(outs)
            done = m
            for j in range(m):
                row = {k: v[j] for k, v in outs.items()}
                if int(row["code"]) != OK:
                    t_fail = float(targets[k0 + j])
                    failure = (f"step {k0 + j + 1} (target time {t_fail:g} s, last converged "
                               f"time {float(row['time_s']):g} s) failed after "
                               f"{scene.max_cutbacks} cutbacks: "
                               f"{CAUSES.get(int(row['code']), 'unknown')}")
                    break
                row["x"] = _absolute(scene, inp, row["x"])
                row["rezoned"] = int(bool(row["paused"]))
                rows.append(row)
                hists.append(row["hist"])
                if progress is not None:
                    progress(dict(step=k0 + j + 1, n_steps=n, **{k: row[k] for k in (
                        "time_s", "stroke_mm", "force_N", "iterations", "cutbacks")}))
                if row["paused"]:
                    done = j + 1
                    break
            state = state_new
            k0 += done
            if rows[-1]["rezoned"] and (failure is not None or k0 >= n):
                rows[-1]["rezoned"] = 0  # the run ends here: nothing to rezone for
            if rows[-1]["rezoned"]:
                try:
                    state, inp, report = rezone(scene, state, inp)
                except RezoneError as err:
                    failure = f"step {k0}: {err}"
                else:
                    rezones.append(report)
                    # a rezoning that could not raise the quality keeps the mesh; try again
                    # when the quality has fallen by another 10 %
                    trigger = (scene.rezone_quality if report.improved
                               else 0.9 * report.quality_before)
                    rows[-1]["rezoned"] = int(report.improved)
    finally:
        # the last factorization modified Newton kept is freed here; one a raising chunk
        # held is lost, never freed twice
        if owned[0] is not None:
            jax.block_until_ready(scene.linear.release(owned[0]))
    hist_keys = ("time_s", "stroke_mm", "force_N", "iterations", "factorizations", "cutbacks",
                 "friction_work_Nmm", "mesh_quality", "rezoned")
    history = {k: np.array([float(r[k]) for r in rows]) for k in hist_keys}
    history["newton_iterations"] = history.pop("iterations")
    fields = {k: np.stack([np.asarray(r[k]) for r in rows])
              for k in ("x", "stress", "s", "eqps", "slip_mm", "contact_status")}
    history.update(extra_history(scene, fields["x"], history["time_s"]))
    result = Result(history=history, fields=fields, scene=scene, final_state=state,
                    newton_histories=np.array(hists), failure=failure, inputs=inp,
                    rezones=rezones)
    if failure:
        raise SimulationError(failure, result)
    return result
