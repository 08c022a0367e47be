"""Differentiable load history: exact gradients of any output of a run.

:func:`trajectory` runs a scene's load steps as one ``lax.scan`` over a *fixed* step
schedule (no cutback: a while loop cannot be reverse-differentiated), each step the
implicitly differentiated Newton solve of :func:`jaxform.stepping.solve_step`.  So
``jax.grad`` of any scalar function of the returned :class:`Trajectory` with respect to
anything in :class:`jaxform.scenes.Inputs` (initial coordinates = preform shape, die
profile points and path table = die shape and ram speed schedule, friction coefficients,
material parameters) and to the step times costs, per step, one transposed solve with
the converged step's Jacobian and one residual VJP: never a pass back through Newton
iterations.

Contract
--------
* ``trajectory(scene, inputs, times)`` -> :class:`Trajectory`.  Each step starts from
  the last step's rate (predictor) and, if that solve fails, once more from the last
  state (the second, differentiated solve starts from the first one's solution where
  that converged: no branch, so the run vmaps without computing both).  ``times`` (n,) are the
  step end times (s), increasing from > 0; the scene's own schedule is
  :meth:`Scene.step_targets`.  Steps that need a cutback in a forward run need a finer
  schedule here (``dt``): a failed step does not raise inside jit, it leaves its code in
  ``Trajectory.codes`` and the caller (:func:`value_and_grad`, the design loop) raises
  :class:`GradientRunError` at the public boundary.
* Contact and friction switch between smooth branches (open / stick / slip).  The
  gradient is that of the branch active at the converged solution of each step: exact
  wherever no node sits exactly on a switch (the common case), one-sided where one does.
  A finite-difference step that changes the active set sees a kink the gradient does not.
* ``trajectory(..., reuse_factorizations=True)`` (what :func:`value_and_grad` and the
  design problems' gradients use): the first solve of each of the last
  :func:`kept_steps` steps keeps its last factorization (the Jacobian one Newton step
  from the root) for the reverse pass, which refines with it instead of factoring
  J(x*) again; the others free it at once.  The memory held is bounded by the scene's
  ``solver.adjoint_memory_mb`` (klujax: ~69 MB a step at 100 x 100).  The klujax
  handles come back in ``Trajectory.factorizations`` and the caller frees them with
  :func:`release` after the reverse pass; a reverse pass after that is undefined, so
  differentiate such a run once (one jax.grad / value_and_grad / vjp call), not under vmap.
* A scene with ``[remesh]`` runs through the meshes of its forward run
  (:func:`remeshed_schedule` -> :class:`RemeshPlan`): the same remesh steps, the same
  new meshes, each remesh a fixed map (:class:`jaxform.remesh.StateMap`) differentiated
  like the steps.  :class:`RemeshPlan` states what that gradient is.  Each of its steps
  starts Newton from the forward run's converged unknowns (:attr:`MeshSegment.converged`)
  where those are closer than the rate predictor, so at the design point it converges at
  once, also where the forward run needed cutbacks or continued solves.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import cached_property, partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxform import program_store
from jaxform.capacity import Padded
from jaxform.formulations import GaussState
from jaxform.linear import Factorization
from jaxform.remesh import StateMap
from jaxform.scenes import Inputs, Scene
from jaxform.status import CAUSES, OK
from jaxform.stepping import (
    SimState,
    Stepper,
    converged_state,
    die_force,
    initial_state,
    solve_step,
    step_context,
    stepper_of,
)
from jaxform.xla_options import jit


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class Trajectory:
    """A differentiable run: per-step scalars (row 0 = the initial state) and final state."""

    time_s: jax.Array  # (n+1,)
    stroke_mm: jax.Array  # (n+1,) ram stroke (whole workpiece)
    force_N: jax.Array  # (n+1,) ram force, compression positive
    friction_work_Nmm: jax.Array  # (n+1,)
    x: jax.Array  # final unknowns
    gauss: GaussState  # final Gauss-point state (stress, s, eqps)
    positions: jax.Array  # (n_nodes, 2) final nodal positions (mm)
    coords: jax.Array  # (n_nodes, 2) initial nodal positions (mm)
    codes: jax.Array  # (n,) status code of each step (0 = converged)
    iterations: jax.Array  # (n,) Newton iterations of each step
    # (n, n_c) contact status of each candidate after each step (0 open, 1 stick, 2 slip):
    # the active set, whose changes bound where the run is differentiable (a remeshed
    # run: each step's candidates on its mesh, padded with -1 to the most of any mesh)
    contact_status: jax.Array
    # klujax factorizations kept for the reverse pass ((n,) leading axis; None when none
    # were kept): handles the caller frees with release() once the reverse pass is done
    factorizations: Factorization | None = None
    # (n+1, n_nodes) nodal temperatures (K) of each row (None: no temperature field, or
    # a remeshed run, whose rows lie on different meshes)
    temperature_K: jax.Array | None = None
    final_state: SimState | None = None  # the whole state after the last step


def _temperatures(model, x, inputs: Inputs):
    return model.element.temperatures(model.layout, x, inputs.thermal)


class GradientRunError(RuntimeError):
    """A step of a differentiable run did not converge."""


@partial(jit, static_argnums=(0, 5))
def _trajectory(stepper: Stepper, inputs: Inputs, times, state0, idx, n_kept=0, starts=None):
    model, linear, symmetric_z = stepper.model, stepper.linear, stepper.symmetric_z
    n_steps = times.shape[0]

    def step(st: SimState, xs):
        t_new, keep, start = xs
        sg = jax.lax.stop_gradient
        # the first Newton start: the last step's rate, or the forward run's converged
        # unknowns of the step (``starts``) where their residual is the smaller
        guess = st.x + (t_new - st.t) * st.x_rate
        if start is not None:
            guess = _closer(model, sg(st), sg(t_new), sg(inputs), idx, (start, sg(guess)))
        # first attempt from that start, not differentiated (stop_gradient: no
        # tangent reaches it, so it has no reverse pass); with n_kept, it factors and
        # solves with the factors and returns its last factorization
        fac0 = linear.empty_factorization(st.x.shape[0], st.x.dtype) if n_kept else None
        first = solve_step(stepper, sg(st), sg(t_new), sg(inputs), idx, x_guess=guess, fac=fac0)
        x1, its1, code1, fac1 = first.x, first.iterations, first.code, first.fac
        kept = None
        if n_kept:  # steps past the memory budget free it now
            fac1 = sg(fac1)  # integer handles: no tangent, and the FFI free has no JVP
            linear.release(replace(fac1, valid=fac1.valid & ~keep))
            kept = replace(fac1, valid=fac1.valid & keep)
        # the differentiated solve: from x1 where that converged (0 iterations, one
        # residual), else from the last state, like the forward run after a cutback.  No
        # lax.cond: under vmap a cond runs both branches, i.e. a whole second Newton solve
        # for every lane; here a lane that converged costs one residual evaluation.  Its
        # reverse pass refines with the kept factorization (of the iterate before x1).
        sol = solve_step(
            stepper,
            st,
            t_new,
            inputs,
            idx,
            x_guess=jnp.where(code1 == OK, x1, st.x),
            adjoint_fac=kept,
        )
        x, code, its = sol.x, sol.code, its1 + sol.iterations
        new = converged_state(model, st, x, sol.gauss, t_new, inputs, sol.cstep, idx)
        out = (
            t_new,
            die_force(model, x, inputs, t_new, idx),
            new.friction_work,
            code,
            its,
            new.contact_status,
            kept if linear.handles else None,  # handles for the owner to free
            _temperatures(model, x, inputs),
        )
        return new, out

    keep_steps = jnp.arange(n_steps) >= n_steps - n_kept  # the last n_kept steps
    scanned = jax.lax.scan(step, state0, (times, keep_steps, starts))
    final, (t, force, fw, codes, its, status, kept, temps) = scanned
    zero = jnp.zeros((1,), dtype=t.dtype)
    t_all = jnp.concatenate([zero, t])
    f0 = die_force(model, state0.x, inputs, jnp.asarray(0.0, t.dtype), idx)
    factor = 2.0 if symmetric_z else 1.0
    return Trajectory(
        time_s=t_all,
        stroke_mm=factor * jax.vmap(inputs.die.stroke)(t_all),
        force_N=jnp.concatenate([f0[None], force]),
        friction_work_Nmm=jnp.concatenate([zero, fw]),
        x=final.x,
        gauss=final.gauss,
        positions=model.nodal_positions(final.x, inputs.coords, idx),
        coords=inputs.coords,
        codes=codes,
        iterations=its,
        contact_status=status,
        factorizations=kept,
        temperature_K=(
            None
            if temps is None
            else jnp.concatenate([_temperatures(model, state0.x, inputs)[None], temps])
        ),
        final_state=final,
    )


def _closer(model, state: SimState, t_new, inputs: Inputs, idx, candidates: tuple):
    """Of the Newton starts ``candidates`` of the step from ``state`` to t_new, the one of
    the smallest scaled residual (an invalid state's: inf): at the design point the
    forward run's solution (residual at the tolerance), at a design far from it (a
    replay through a fixed plan at another design) the rate predictor where that is
    closer."""
    ctx = step_context(model, state, inputs, idx, t_new, t_new - state.t)

    def size(x):
        r, _, code, scale = model.residual(x, ctx)
        return jnp.where(code == OK, jnp.linalg.norm(r) / scale, jnp.inf)

    best = jnp.argmin(jnp.stack([size(x) for x in candidates]))
    return jnp.stack(candidates)[best]


def trajectory(
    scene: Scene,
    inputs: Inputs | None = None,
    times=None,
    reuse_factorizations: bool = False,
    idx=None,
    plan: RemeshPlan | None = None,
) -> Trajectory:
    """Run ``scene`` (with ``inputs`` in place of ``scene.inputs``) over the step end
    times ``times`` (default: the scene's schedule).  Traceable and differentiable.

    Arguments:
        scene: from :func:`jaxform.scenes.build_scene`.
        inputs: the run's differentiable inputs (default ``scene.inputs``).
        times: (n,) step end times in s (default :meth:`Scene.step_targets`).
        reuse_factorizations, idx: see below.

    Returns:
        the :class:`Trajectory` (per-step force, stroke, codes; final state).  A failed
        step leaves its code in ``codes``; :func:`check` raises for it.

    ``idx``: ``scene.idx`` as an argument of the caller's jit, for callers that compile a
    program around this (the design problems, the batches): the pattern then enters the
    program as an argument, not as a constant, which XLA would constant-fold (45 s of
    the compile sorting the 100 x 100 pattern inside klujax's solve).

    ``reuse_factorizations``: keep each step's last forward factorization, for the last
    :func:`kept_steps` steps (``scene.adjoint_memory_mb``), so that the reverse pass
    refines its adjoint solves with them instead of factoring each step's Jacobian
    again.  Only for one reverse-mode differentiation (jax.grad, value_and_grad, one
    vjp) outside vmap; the caller then frees them with :func:`release` (the entry points
    :func:`value_and_grad` and the design problems do both).

    ``plan``: the meshes of a scene that remeshes (``[remesh]``), from
    :func:`remeshed_schedule` (required for such a scene): the run takes the forward
    run's meshes and remeshes at its steps, through the fixed maps of
    :class:`RemeshPlan`.  It keeps no factorizations (``reuse_factorizations`` is
    ignored) and is not for an enclosing jit: each mesh's steps run the compiled program
    of its capacity bucket, shared by the meshes of one bucket."""
    inputs = scene.inputs if inputs is None else inputs
    if scene.press is not None and scene.press.energy_limited:
        raise ValueError(
            f"trajectory: a {scene.press.name} press moves the die with the work done; "
            "its differentiable run is jaxform.blows.blow_run"
        )
    if scene.remeshes and plan is None:
        raise ValueError(
            "trajectory: this scene remeshes ([remesh]); pass the forward run's plan "
            "(times, plan = jaxform.gradients.remeshed_schedule(scene, inputs))"
        )
    if plan is not None and len(plan.segments) > 1:
        times = jnp.asarray(plan.times if times is None else times)
        return _remeshed_trajectory(scene, inputs, times, plan)
    times = jnp.asarray(scene.step_targets() if times is None else times)
    n_kept = kept_steps(scene, times.shape[0]) if reuse_factorizations else 0
    if n_kept and _under_vmap((inputs, times)):
        raise ValueError(
            "trajectory(reuse_factorizations=True) under jax.vmap: a vmapped "
            "Newton loop runs finished lanes too, which would free factorizations "
            "still in use; run batches without it (as jaxform.batch does)"
        )
    state0 = initial_state(scene.model, inputs)
    stepper = stepper_of(scene, differentiable=True)
    return _trajectory(
        stepper,
        inputs,
        times,
        state0,
        scene.idx if idx is None else idx,
        n_kept,
    )


def _under_vmap(tree) -> bool:
    """Whether any leaf is being batched by jax.vmap (its tracer type, which JAX does not
    export; a check that can only miss, never refuse a run that is not batched)."""
    return any(type(a).__name__ == "BatchTracer" for a in jax.tree_util.tree_leaves(tree))


def kept_steps(scene: Scene, n_steps: int) -> int:
    """How many steps of an n_steps run may keep a factorization for the reverse pass:
    as many as ``scene.adjoint_memory_mb`` holds (:meth:`LinearSolver.factor_bytes`),
    none on a backend that cannot keep one (jax-sparse)."""
    if not scene.linear.keeps_factorization or scene.adjoint_memory_mb <= 0:
        return 0
    n = scene.model.layout.n_dofs
    size = scene.linear.factor_bytes(n, scene.idx.rows.shape[0], scene.idx.lu_symbolic)
    return int(min(n_steps, scene.adjoint_memory_mb * 2**20 // size))


def release(scene: Scene, traj: Trajectory) -> Trajectory:
    """Free the factorizations a run kept for its reverse pass (outside jit, after the
    reverse pass); ``traj`` without them."""
    if traj.factorizations is not None:
        scene.linear.release_now(jax.device_get(traj.factorizations))
    return replace(traj, factorizations=None)


def schedule(scene: Scene, inputs: Inputs | None = None) -> np.ndarray:
    """The step schedule the forward run takes: run the scene (adaptive steps, with
    cutbacks, :func:`jaxform.simulation.simulate`) and return the end times of its
    converged steps, so that a differentiable run takes the same steps and each of them
    converged in the forward run.  (A scene that remeshes needs its meshes too:
    :func:`remeshed_schedule`.)"""
    return remeshed_schedule(scene, inputs)[0]


def remeshed_schedule(
    scene: Scene, inputs: Inputs | None = None, progress=None
) -> tuple[np.ndarray, RemeshPlan | None]:
    """(step end times, :class:`RemeshPlan`) of the forward run of ``scene`` with
    ``inputs`` by full Newton (:meth:`Scene.full_newton`, the replay's method): the
    schedule of :func:`schedule` and, for a scene with ``[remesh]``, the meshes the run
    went through and the maps between them (None without ``[remesh]``).
    ``progress``: the forward run's progress callback (:func:`jaxform.simulation.simulate`)."""
    from jaxform.simulation import simulate

    if scene.rezone_quality > 0.0:
        raise ValueError(
            "mesh.rezone_quality > 0: a rezoned history has no gradient here "
            "(the mesh changes between steps); set mesh.rezone_quality = 0 for "
            "gradient runs"
        )
    run = (scene if inputs is None else replace(scene, inputs=inputs)).full_newton()
    res = simulate(run, progress)
    times = np.asarray(res.history["time_s"][1:])
    if not scene.remeshes:
        return times, None
    return times, RemeshPlan.of(res)


@dataclass(frozen=True, eq=False)
class MeshSegment:
    """The steps of a remeshed run on one mesh, as a gradient run takes them: ``scene`` on
    that mesh (the first: the run's own), ``padded`` to its capacity bucket (what the steps
    run: the meshes of one bucket share a compiled program), ``n_steps`` steps, reached
    from the previous mesh's last state through ``transfer`` (None for the first).

    ``converged``: (n_steps, n_dofs) the forward run's converged unknowns of these steps
    on ``scene`` (None: not recorded).  The replay starts each step's Newton solve there
    (:attr:`starts`) or from the last step's rate, whichever has the smaller residual: at
    the design point the replay's solution is the forward run's, so each step converges
    at once where the forward run may have needed cutbacks and continued solves that the
    fixed-step replay does not have; a replay through the plan at another design (a
    finite-difference neighbour: near; an optimizer's next design: maybe far) takes the
    closer start.  The gradient does not depend on the start (implicit
    differentiation)."""

    scene: Scene
    padded: Padded
    n_steps: int
    transfer: StateMap | None
    converged: np.ndarray | None = None

    @cached_property
    def starts(self):
        """The Newton starts of the replay's steps in the layout the steps run (padded to
        the bucket, ghosts at rest), or None (padded once, on the host)."""
        if self.converged is None:
            return None
        if self.padded is None:
            return jnp.asarray(self.converged)
        return jnp.asarray(np.stack([self.padded._pad_x(x) for x in self.converged]))

    @classmethod
    def of_rows(cls, result, seg, start: int, end: int, padded=None) -> MeshSegment:
        """The segment of a forward run's rows ``start:end`` (a
        :class:`jaxform.simulation.Result` and its :class:`jaxform.simulation.Segment`
        ``seg``), stepped in ``padded`` (default: the forward run's padding)."""
        converged = np.stack([np.asarray(result.fields["x"][r]) for r in range(start, end)])
        padded = seg.padded if padded is None else padded
        return cls(seg.scene, padded, end - start, seg.transfer, converged)


@dataclass(frozen=True, eq=False)
class RemeshPlan:
    """The meshes of a forward run with remeshing, fixed for gradient runs.

    A gradient run through it (:func:`trajectory` with ``plan``) remeshes after the same
    steps onto the same meshes: each remesh is the fixed map of the forward run
    (:class:`jaxform.remesh.StateMap`, set up once at the design point: new reference
    coordinates interpolated from the old deformed positions, Gauss-point fields by patch
    recovery and interpolation, nodal fields and contact by interpolation), applied to the
    run's traced state.  So ``jax.grad`` goes through every mesh and every map.

    What the gradient is: that of the run whose remesh schedule, new-mesh topology and
    transfer weights are those of the forward run at the design point.  It is exact for
    perturbations small enough to leave the remesher's output topology unchanged; the new
    mesh's nodes move with the old deformed configuration (through the interpolation
    weights) instead of being placed anew by gmsh, and the recovery's limiter is piecewise
    linear (its derivative one-sided exactly where it switches, as contact's)."""

    segments: tuple[MeshSegment, ...]

    @classmethod
    def of(cls, result) -> RemeshPlan:
        """The plan of a :class:`jaxform.simulation.Result` of a scene with ``[remesh]``
        (one segment where it did not remesh): its meshes as it padded them."""
        n_rows = len(result.history["time_s"])
        ends = [s.first_row for s in result.segments[1:]] + [n_rows]
        starts = [1] + ends[:-1]
        return cls(
            tuple(
                MeshSegment.of_rows(result, s, start, end)
                for s, start, end in zip(result.segments, starts, ends)
            )
        )

    @property
    def n_steps(self) -> int:
        return sum(s.n_steps for s in self.segments)


def _remeshed_trajectory(
    scene: Scene, inputs: Inputs, times, plan: RemeshPlan, chunked: bool = False
) -> Trajectory:
    """:func:`trajectory` through the meshes of ``plan`` (traced, not under jit).  Between
    two meshes' step programs, the remesh map and the padding to the bucket run as one
    compiled program (and its reverse as one more), not as hundreds of eager operations
    that would each compile."""
    if times.shape[0] != plan.n_steps:
        raise ValueError(f"trajectory: {times.shape[0]} step times for a plan of {plan.n_steps}")
    state, coords = initial_state(scene.model, inputs), inputs.coords
    parts, state, coords = through_meshes(plan.segments, inputs, times, state, coords, chunked)
    return joined(plan.segments, parts, state, coords)


def through_meshes(segments, inputs: Inputs, times, state, coords, chunked: bool = False):
    """(the parts of each mesh, the last state, its reference coordinates): the steps of
    ``segments`` (:class:`MeshSegment`) from (state, coords) before the first one's map,
    each mesh entered through its map and padding, stepped by :func:`mesh_steps` from its
    Newton starts (``chunked``: a padded mesh's steps in runs), and left without the
    padding.  The one loop of a remeshed scene's and a process operation's replay."""
    parts, first = [], 0
    for seg in segments:
        sc = seg.scene if seg.padded is None else seg.padded.scene
        stepper = stepper_of(sc, differentiable=True)
        state, coords, run_coords, run_state = _enter_mesh(seg, state, coords)
        part = mesh_steps(stepper, sc.idx, replace(inputs, coords=run_coords),
                          times[first : first + seg.n_steps], run_state, seg.starts,
                          chunked and seg.padded is not None)  # fmt: skip
        state = _leave_mesh(seg, part.final_state)
        parts.append(part)
        first += seg.n_steps
    return tuple(parts), state, coords


def joined(segments, parts: tuple, state, coords, temperature_K=None) -> Trajectory:
    """One trajectory from the parts run on each mesh of ``segments`` (row 0 of the first
    mesh, then every mesh's steps; the contact status padded with -1 to the widest mesh),
    ending in ``state`` on the last mesh at reference ``coords``."""

    def rows(name):
        return jnp.concatenate(
            [getattr(parts[0], name)[:1]] + [getattr(p, name)[1:] for p in parts]
        )

    n_c = max(s.scene.model.layout.n_contact for s in segments)
    status = [
        jnp.pad(p.contact_status[:, : s.scene.model.layout.n_contact],
                ((0, 0), (0, n_c - s.scene.model.layout.n_contact)), constant_values=-1)
        for p, s in zip(parts, segments)
    ]  # fmt: skip
    last = segments[-1].scene.model.layout
    return Trajectory(
        time_s=rows("time_s"),
        stroke_mm=rows("stroke_mm"),
        force_N=rows("force_N"),
        friction_work_Nmm=rows("friction_work_Nmm"),
        x=state.x,
        gauss=state.gauss,
        positions=coords + last.nodal(state.x)[:, :2],
        coords=coords,
        codes=jnp.concatenate([p.codes for p in parts]),
        iterations=jnp.concatenate([p.iterations for p in parts]),
        contact_status=jnp.concatenate(status),
        temperature_K=temperature_K,
        final_state=state,
    )


@partial(jax.custom_vjp, nondiff_argnums=(0, 1))
def _segment(stepper: Stepper, idx, inputs: Inputs, times, state0, starts) -> Trajectory:
    """One mesh's steps of a remeshed gradient run, :func:`_trajectory` without kept
    factorizations, differentiated as two compiled programs shared by every mesh of a
    capacity bucket: the steps with their reverse pass's residuals, and the reverse pass.
    Left to JAX's own differentiation of the jitted steps, the first mesh (part of whose
    state has no tangent) and the last (whose final state gets no cotangent) would each
    compile programs of their own.  ``starts``: the steps' Newton starts
    (:attr:`MeshSegment.starts`) or None (zero cotangent: the solution does not depend
    on them)."""
    return _trajectory(stepper, inputs, times, state0, idx, 0, starts)


CHUNK_STEPS = 8  # the longest run of steps one compiled segment program takes


def step_chunks(n_steps: int, longest: int = CHUNK_STEPS) -> tuple[int, ...]:
    """``n_steps`` as runs of ``longest`` (a power of two) steps, then the powers of two
    of the rest, largest first: whatever their step counts, the meshes of one capacity
    bucket run at most log2(longest) + 1 step programs (and as many reverse passes)."""
    chunks = [longest] * (n_steps // longest)
    size = longest
    while size > 1:
        size //= 2
        if n_steps % (2 * size) >= size:
            chunks.append(size)
    return tuple(chunks)


def mesh_steps(
    stepper: Stepper, idx, inputs: Inputs, times, state0, starts=None, chunked=False
) -> Trajectory:
    """One mesh's steps of a remeshed gradient run (:func:`_segment`, from the Newton
    ``starts`` of :meth:`MeshSegment.starts`) as one trajectory: in one run, or
    ``chunked`` in the runs of :func:`step_chunks`, each from the last one's final state
    (where a plan's meshes share buckets, fewer programs)."""
    n_steps = times.shape[0]
    parts, first = [], 0
    for n in step_chunks(n_steps) if chunked else (n_steps,):
        run = slice(first, first + n)
        part_starts = None if starts is None else starts[run]
        parts.append(_segment(stepper, idx, inputs, times[run], state0, part_starts))
        state0, first = parts[-1].final_state, first + n
    return parts[0] if len(parts) == 1 else _chained(tuple(parts))


@jit
def _chained(parts: tuple) -> Trajectory:
    """The trajectory of consecutive runs of steps on one mesh (rows 1.. of each after
    the first repeat the row before them): one program, not eager concatenations."""

    def rows(name):
        later = [getattr(p, name)[1:] for p in parts[1:]]
        return jnp.concatenate([getattr(parts[0], name), *later])

    def steps(name):
        return jnp.concatenate([getattr(p, name) for p in parts])

    temps = None if parts[-1].temperature_K is None else rows("temperature_K")
    return replace(
        parts[-1],
        time_s=rows("time_s"),
        stroke_mm=rows("stroke_mm"),
        force_N=rows("force_N"),
        friction_work_Nmm=rows("friction_work_Nmm"),
        coords=parts[0].coords,
        codes=steps("codes"),
        iterations=steps("iterations"),
        contact_status=steps("contact_status"),
        temperature_K=temps,
    )


@partial(jit, static_argnums=0)
def _segment_forward(stepper: Stepper, idx, inputs: Inputs, times, state0, starts):
    """(trajectory, its pullback): every differentiable input gets a cotangent."""
    return jax.vjp(lambda i, t, s, g: _trajectory(stepper, i, t, s, idx, 0, g),
                   inputs, times, state0, starts)  # fmt: skip


@jit
def _segment_backward(pullback, cotangent):
    return pullback(cotangent)


def _segment_bwd(stepper, idx, pullback, cotangent):
    program_store.make_room()  # the reverse pass compiles a program per mesh too
    return _segment_backward(pullback, cotangent)


_segment.defvjp(_segment_forward, _segment_bwd)


def _enter_mesh(seg: MeshSegment, state, coords):
    """:func:`_entered_mesh`, after making room where the process is crowded with memory
    maps (:func:`jaxform.program_store.make_room`): each mesh of a replay
    compiles programs of its own (its map, its bucket's steps, their reverse passes)."""
    program_store.make_room()
    return _entered_mesh(seg, state, coords)


@partial(jax.jit, static_argnums=0)  # a segment is hashed by identity: one program each
def _entered_mesh(seg: MeshSegment, state, coords):
    """(state, coords) on the segment's mesh (through its remesh map, if any), and the
    coordinates and state padded to its capacity bucket."""
    if seg.transfer is not None:
        state, coords = seg.transfer.apply(state, coords, jnp)
    # strongly typed: the first mesh's initial state has weakly typed scalars (t = 0.0),
    # which would make its step program another one than the later meshes'
    state, coords = jax.tree_util.tree_map(lambda a: jax.lax.convert_element_type(a, a.dtype),
                                           (state, coords))  # fmt: skip
    if seg.padded is None:  # a mesh stepped as it is (a process operation's own)
        return state, coords, coords, state
    return state, coords, seg.padded.coords(coords, jnp), seg.padded.state(state, jnp)


@partial(jax.jit, static_argnums=0)
def _leave_mesh(seg: MeshSegment, state):
    """The segment's last state without the padding."""
    return state if seg.padded is None else seg.padded.trim(state, jnp)


def check(traj: Trajectory) -> None:
    """Raise :class:`GradientRunError` if a step of ``traj`` failed (outside jit only)."""
    codes = np.asarray(traj.codes)
    bad = np.flatnonzero(codes != OK)
    if bad.size:
        k = int(bad[0])
        t = float(np.asarray(traj.time_s)[k + 1])
        raise GradientRunError(
            f"differentiable run: step {k + 1} (to t = {t:g} s) failed: "
            f"{CAUSES.get(int(codes[k]), 'unknown')}; the differentiable run has no cutback, "
            f"use a smaller time.dt_s (or pass a finer step schedule)"
        )


def value_and_grad(
    objective: Callable[[Any, Trajectory], jax.Array],
    scene: Scene,
    design: Any,
    to_inputs: Callable[[Any], tuple[Inputs, jax.Array]],
):
    """(J, dJ/d design, trajectory) for
    ``J = objective(design, trajectory(scene, *to_inputs(design)))``.

    ``to_inputs(design) -> (inputs, times)`` maps the design variables (any pytree) to the
    run's inputs.  Raises :class:`GradientRunError` when a step fails."""

    def j(d):
        inputs, times = to_inputs(d)
        traj = trajectory(scene, inputs, times, reuse_factorizations=True)
        return objective(d, traj), traj

    (val, traj), grad = jax.value_and_grad(j, has_aux=True)(design)
    traj = release(scene, jax.block_until_ready(traj))
    check(traj)
    return val, grad, traj
