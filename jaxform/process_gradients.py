"""Exact gradients through a multi-stage process: every operation replayed with traced state.

    run_process(...) --ProcessPlan.of--> ProcessPlan --process_trajectory(plan, inputs, times)
        --> ProcessTrajectory (one jaxform.gradients.Trajectory per operation)

The forward process run (:func:`jaxform.process.run_process`) fixes, per operation, the
step schedule and the meshes it went through (:class:`jaxform.gradients.MeshSegment`:
each mesh, padded to its capacity bucket where the operation remeshes, and the remesh map
that brought the state onto it), and the map that brought the part into the operation: a
:class:`jaxform.process.Carry` (the deformed positions become the next reference; stress,
resistance, eqps, temperature carry over; contact starts afresh), a trim's
:class:`jaxform.remesh.StateMap`, or a reheat to a set temperature (:class:`SetTemperature`).
:func:`process_trajectory` replays the whole sequence with traced values: each operation's
inputs (its dies, friction, speed, thermal inputs; the first one's coordinates: the
billet) and step times are arguments, so ``jax.grad`` of any output of any operation goes
back to any input of any operation, through every step, remesh, carry and trim and the
heat of a dwell.

What the gradient is: that of the process whose step schedules, meshes, remesh and trim
maps (topology and interpolation weights) and die placements are those of the forward run
at the design point (as :class:`jaxform.gradients.RemeshPlan` states for one scene): exact
for perturbations that leave them unchanged.  A forming operation's die travel is fixed
(a ``travel_mm`` or ``final_gap_mm`` stroke of an explicit profile does not depend on the
incoming part); a *flat* die placed on the incoming part's top stands where the forward
run's part had its top.  A trim cuts at the forward run's cut (its new mesh's nodes move
with the old deformed positions through the fixed weights).

Each mesh's steps run the compiled program of its capacity bucket, a coarser one than the
forward run's (:func:`jaxform.capacity.coarse_bucket`: a process's meshes share fewer
programs), shared between the operations whose meshes share a bucket, and, where that
compiles fewer programs, in runs of 8, 4, 2, 1 steps (:func:`jaxform.gradients.mesh_steps`);
the maps between them run as one compiled program each.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from jaxform.capacity import Bucket, Padded, coarse_bucket, padded
from jaxform.gradients import (
    MeshSegment,
    Trajectory,
    check,
    joined,
    step_chunks,
    through_meshes,
)
from jaxform.remesh import StateMap
from jaxform.scenes import Inputs, Scene
from jaxform.stepping import initial_state, stepper_of


@dataclass(frozen=True, eq=False)
class SetTemperature:
    """A reheat to a set temperature as a map: every node's temperature unknown set to
    ``temperature_K`` minus the run's billet temperature (the unknown's origin), the clock
    at 0; the mesh and the rest of the state as they are."""

    layout: object  # jaxform.assembly.Layout
    temperature_K: float

    def apply(self, state, coords, thermal):
        lay = self.layout
        nodal = lay.nodal(state.x)
        col = lay.temperature_column
        value = self.temperature_K - thermal.billet_temperature_K
        nodal = nodal.at[:, col].set(jnp.broadcast_to(value, nodal[:, col].shape))
        n_nodal = nodal.size
        x = jnp.concatenate([nodal.ravel(), state.x[n_nodal:]])
        return replace(state, x=x, t=jnp.zeros_like(state.t)), coords


@dataclass(frozen=True, eq=False)
class Stage:
    """One operation as a gradient run replays it: the map that brought the part in
    (``entry``: None for the first operation, a :class:`jaxform.process.Carry`, a
    :class:`jaxform.remesh.StateMap` of a trim, a :class:`SetTemperature`), the meshes
    its steps ran on (``segments``; none for a trim, a set temperature, a dwell without
    heat) and its step end times (s, its own clock).  ``scene``: the operation's scene
    (its inputs are what the design varies), ``final_scene``: the one the part leaves on."""

    operation: object  # jaxform.process_config.Operation
    scene: Scene
    final_scene: Scene
    entry: object
    segments: tuple[MeshSegment, ...]
    times: np.ndarray
    chunked: bool = False  # a padded mesh's steps in runs of 8, 4, 2, 1 (ProcessPlan.of)

    @property
    def name(self) -> str:
        return self.operation.name

    @property
    def stepped(self) -> bool:
        """Whether the operation takes steps (forming; a dwell or furnace with heat)."""
        return len(self.segments) > 0


@dataclass(frozen=True, eq=False)
class ProcessPlan:
    """The operations of a forward process run, fixed for gradient runs
    (:func:`process_trajectory`)."""

    stages: tuple[Stage, ...]

    @classmethod
    def of(cls, result) -> ProcessPlan:
        """The plan of a :class:`jaxform.process.ProcessResult` that ran to its end."""
        if result.failure:
            raise ValueError(f"ProcessPlan.of: the process run failed: {result.failure}")
        plan = cls(tuple(_stage(run) for run in result.runs))
        if plan.step_programs(chunked=True) >= plan.step_programs(chunked=False):
            return plan  # few meshes to a bucket: each mesh's steps in one run
        return cls(tuple(replace(s, chunked=True) for s in plan.stages))

    def inputs(self) -> tuple[Inputs, ...]:
        """Each operation's inputs as the forward run had them."""
        return tuple(s.scene.inputs for s in self.stages)

    def times(self) -> tuple[np.ndarray, ...]:
        return tuple(np.asarray(s.times) for s in self.stages)

    def step_programs(self, chunked: bool | None = None) -> int:
        """The distinct step programs a replay compiles (each twice: the steps with their
        residuals, and the reverse pass), keyed as jit keys them: the differentiable
        stepper, the index arrays' shapes, the run's length (``chunked``: the runs of
        :func:`jaxform.gradients.step_chunks` on a padded mesh, else a mesh's steps in
        one; None: as the plan runs them)."""
        keys = set()
        for stage in self.stages:
            runs_in_chunks = stage.chunked if chunked is None else chunked
            for seg in stage.segments:
                sc = seg.scene if seg.padded is None else seg.padded.scene
                shapes = tuple(np.shape(a) for a in jax.tree_util.tree_leaves(sc.idx))
                key = (stepper_of(sc, differentiable=True), shapes)
                runs = (step_chunks(seg.n_steps) if runs_in_chunks and seg.padded is not None
                        else (seg.n_steps,))  # fmt: skip
                keys |= {(key, n) for n in runs}
        return len(keys)

    def index(self, name: str) -> int:
        """The stage of the operation named ``name``; ValueError if none is."""
        for k, s in enumerate(self.stages):
            if s.name == name:
                return k
        names = ", ".join(s.name for s in self.stages)
        raise ValueError(f"no operation named {name!r}; the process has: {names}")


def _coarser(scene: Scene, forward: Padded | None) -> Padded | None:
    """The padding a replay steps a remeshed operation's mesh in: its
    :func:`jaxform.capacity.coarse_bucket` (the forward run's where that holds more)."""
    if forward is None:
        return None
    bucket = coarse_bucket(scene)
    if bucket.nodes <= forward.bucket.nodes and bucket.contacts <= forward.bucket.contacts:
        return forward
    bucket = Bucket(max(bucket.nodes, forward.bucket.nodes),
                    max(bucket.contacts, forward.bucket.contacts))  # fmt: skip
    return padded(scene, bucket)


def _stage(run) -> Stage:
    """A :class:`Stage` from one :class:`jaxform.process.OperationRun`."""
    res, op = run.result, run.operation
    n_rows = len(res.history["time_s"])
    entry = run.transfer
    set_to = getattr(op.keys, "set_temperature_K", None)
    if entry is None and set_to is not None:  # a set temperature: the same mesh, T set
        entry = SetTemperature(res.scene.model.layout, float(set_to))
    if n_rows == 1 and not op.forming:  # a trim, a set temperature, a dwell without heat
        return Stage(op, res.scene, res.final_scene, entry, (), np.zeros(0))
    ends = [s.first_row for s in res.segments[1:]] + [n_rows]
    starts = [1] + ends[:-1]
    segments = tuple(
        MeshSegment.of_rows(res, s, start, end, _coarser(s.scene, s.padded))
        for s, start, end in zip(res.segments, starts, ends)
        if end > start
    )
    times = np.asarray(res.history["time_s"][1:])
    return Stage(op, res.scene, res.final_scene, entry, segments, times)


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class ProcessTrajectory:
    """A differentiable process run: one :class:`jaxform.gradients.Trajectory` per
    operation (a trim, a set temperature, a dwell without heat: one row, the part as the
    operation leaves it, no steps)."""

    operations: tuple

    @property
    def final(self) -> Trajectory:
        return self.operations[-1]

    @property
    def codes(self):
        return jnp.concatenate([t.codes for t in self.operations])

    @property
    def stroke_mm(self):
        """Every operation's strokes (each its own, from 0)."""
        return jnp.concatenate([t.stroke_mm for t in self.operations])

    @property
    def contact_status(self):
        """Every step's contact status of every operation (padded with -1 to the widest)."""
        n_c = max(t.contact_status.shape[1] for t in self.operations)
        return jnp.concatenate([
            jnp.pad(t.contact_status, ((0, 0), (0, n_c - t.contact_status.shape[1])),
                    constant_values=-1)
            for t in self.operations
        ])  # fmt: skip


@partial(jax.jit, static_argnums=0)
def _entered(stage: Stage, state, coords, inputs: Inputs):
    """(state, coords) on the operation's first mesh: the first operation's initial state,
    or the part carried, trimmed or set to a temperature; the die wear the operation's own
    (from 0 at its dies' stations)."""
    scene = stage.scene
    if stage.entry is None:
        return initial_state(scene.model, inputs), inputs.coords
    if isinstance(stage.entry, SetTemperature):
        return stage.entry.apply(state, coords, inputs.thermal)
    state, coords = stage.entry.apply(state, coords, jnp)
    if isinstance(stage.entry, StateMap):  # a trim: the clock at 0, the wear kept
        return replace(state, t=jnp.zeros_like(state.t)), coords
    wear = scene.inputs.wear
    shape = (0, 0) if wear is None else wear.stations.shape[:2]
    return replace(state, wear_mm=jnp.zeros(shape)), coords


@partial(jax.jit, static_argnums=0)
def _still(stage: Stage, state, coords, inputs: Inputs):
    """The one-row trajectory of an operation that takes no step (its part as it leaves,
    at its time 0)."""
    model, z = stage.final_scene.model, jnp.zeros(1)
    t = jnp.zeros_like(state.t)
    temps = model.element.temperatures(model.layout, state.x, inputs.thermal)
    return Trajectory(
        time_s=jnp.reshape(t, (1,)),
        stroke_mm=z,
        force_N=z,
        friction_work_Nmm=jnp.reshape(state.friction_work, (1,)),
        x=state.x,
        gauss=state.gauss,
        positions=coords + model.layout.nodal(state.x)[:, :2],
        coords=coords,
        codes=jnp.zeros(0, jnp.int32),
        iterations=jnp.zeros(0, jnp.int32),
        contact_status=jnp.zeros((0, model.layout.n_contact), jnp.int32),
        temperature_K=None if temps is None else temps[None],
        final_state=state,
    )


def _stepped(stage: Stage, inputs: Inputs, times, state, coords) -> Trajectory:
    """The operation's steps through its meshes from (state, coords) on its first mesh."""
    parts, state, coords = through_meshes(stage.segments, inputs, times, state, coords,
                                          stage.chunked)  # fmt: skip
    return _joined(stage, parts, state, coords)


@partial(jax.jit, static_argnums=0)
def _joined(stage: Stage, parts: tuple, state, coords) -> Trajectory:
    """The operation's trajectory from its meshes' parts (row 0 of the first, then every
    mesh's steps; contact status padded with -1 to the widest mesh): one program (and one
    for its reverse), not dozens of eager concatenations that would each compile."""

    one_mesh = len(parts) == 1 and stage.segments[0].padded is None
    temps = parts[0].temperature_K if one_mesh else None
    return joined(stage.segments, parts, state, coords, temps)


def process_trajectory(plan: ProcessPlan, inputs=None, times=None) -> ProcessTrajectory:
    """Replay the process of ``plan`` with each operation's ``inputs`` and step ``times``
    (tuples, one per operation; default the forward run's).  Traced and differentiable
    (not for an enclosing jit: each mesh runs its bucket's compiled program).  A failed
    step leaves its code in the operation's ``codes`` (:func:`check_process`)."""
    inputs = plan.inputs() if inputs is None else tuple(inputs)
    times = plan.times() if times is None else tuple(times)
    state = coords = None
    out = []
    for stage, inp, ts in zip(plan.stages, inputs, times):
        state, coords = _entered(stage, state, coords, inp)
        if stage.stepped:
            traj = _stepped(stage, inp, jnp.asarray(ts), state, coords)
            state, coords = traj.final_state, traj.coords
        else:
            traj = _still(stage, state, coords, inp)
        out.append(traj)
    return ProcessTrajectory(tuple(out))


def forward_trajectory(result) -> ProcessTrajectory:
    """What :func:`process_trajectory` of ``result``'s own plan gives at the design it ran
    at (each replayed step converges where the forward run's did), read from the forward
    :class:`jaxform.process.ProcessResult` itself: each operation's history on its own
    clock (time, stroke, force, friction work, Newton iterations) and its final state on
    the mesh it ends on.  No replay and nothing to compile: the values of the outputs,
    not their gradients.  ``contact_status`` has no rows and ``temperature_K`` is None
    (the per-row fields are not read; no process objective reads them)."""
    out = []
    for run in result.runs:
        res = run.result
        h, scene, state = res.history, res.final_scene, res.final_state
        lay = scene.model.layout
        coords = jnp.asarray(scene.inputs.coords)
        n = len(h["time_s"]) - 1
        out.append(Trajectory(
            time_s=jnp.asarray(h["time_s"], float),
            stroke_mm=jnp.asarray(h["stroke_mm"], float),
            force_N=jnp.asarray(h["force_N"], float),
            friction_work_Nmm=jnp.asarray(h["friction_work_Nmm"], float),
            x=jnp.asarray(state.x),
            gauss=state.gauss,
            positions=coords + lay.nodal(jnp.asarray(state.x))[:, :2],
            coords=coords,
            codes=jnp.zeros(n, jnp.int32),
            iterations=jnp.asarray(h["newton_iterations"][1:], jnp.int32),
            contact_status=jnp.zeros((0, lay.n_contact), jnp.int32),
            temperature_K=None,
            final_state=state,
        ))  # fmt: skip
    return ProcessTrajectory(tuple(out))


def check_process(plan: ProcessPlan, ptraj: ProcessTrajectory) -> None:
    """Raise :class:`jaxform.gradients.GradientRunError` (naming the operation) if a step
    of the process's differentiable run failed (outside jit)."""
    from jaxform.gradients import GradientRunError

    for stage, traj in zip(plan.stages, ptraj.operations):
        try:
            check(traj)
        except GradientRunError as err:
            raise GradientRunError(f"{stage.operation.label}: {err}") from None
