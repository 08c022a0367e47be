"""The host loop: a scene run to its end, with progress, rezoning and the history.

The caller owns the loop (jax-md style): :func:`init` gives the state at t = 0 and the
step control, :func:`step` advances one converged step of adaptive size (compiled once
per scene), and the caller decides what to do between steps.  :func:`simulate` is that
loop, written once for the command line and scripts: it advances the scene chunk by
chunk through the compiled ``lax.scan`` of :func:`jaxform.stepping.run_chunk` (a
:class:`Run` from one chunk to the next), hands each converged step to an optional
progress callback, lets the scene's adaptation (:mod:`jaxform.adaptation`: none,
rezoning, remeshing) answer a step that paused the chunk, and collects the history (one
row per converged step, column ``dt_s``; the workpiece's and the die's extra columns,
:func:`jaxform.postprocess.extra_history`).  When a step fails at the smallest step size
the run stops, keeping the last converged state, and :class:`SimulationError` names the
step, the time, the cause and the worst element.

A run takes a workpiece in and hands one on (:class:`PartState`: the mesh and every state
field): ``simulate(scene, progress, start=part)`` and :attr:`Result.part`, the seam the
operations of a process pass the part through (:mod:`jaxform.process`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxform.adaptation import Adapted, OnMesh, OwnedFactorization, Remeshing, adaptation_of
from jaxform.chunks import converged_rows, failure_message, host_failure, run_on
from jaxform.fields import OUTPUT_FIELDS
from jaxform.forming_outputs import damage_columns
from jaxform.geometry import min_quality
from jaxform.host_memory import give_back_after
from jaxform.laps import laps, pockets
from jaxform.postprocess import HEAT_COLUMNS, extra_history
from jaxform.precision import require_x64
from jaxform.scenes import Inputs, Scene, analyzed
from jaxform.status import OK
from jaxform.stepping import (
    SimState,
    StepControl,
    attempt_step,
    initial_state,
    step_outputs,
    stepper_of,
)
from jaxform.triggers import CAPACITY, FAILED_STEP, Armed, causes, off
from jaxform.xla_options import jit


class SimulationError(RuntimeError):
    """A step failed after all cutbacks; ``result`` holds the history up to the last good step."""

    def __init__(self, message: str, result):
        super().__init__(message)
        self.result = result


@dataclass(frozen=True)
class Segment:
    """The rows of a run on one mesh: from ``first_row`` to the next segment's first row,
    on ``scene`` (its mesh, sets, dofs and reference coordinates), reached from the last
    row before it through ``transfer`` (:class:`jaxform.remesh.StateMap`; None for the
    first segment) and stepped ``padded`` to its capacity bucket
    (:class:`jaxform.capacity.Padded`; None without remeshing)."""

    first_row: int
    scene: Scene
    transfer: object = None
    padded: object = None


@dataclass(frozen=True)
class PartState:
    """The workpiece between two runs: the scene it is on (its mesh, sets and reference
    coordinates) and its state there (every field: the unknowns with the temperature, the
    Gauss state, damage, friction work, heat, wear).  What :func:`simulate` starts from
    (``start``) and what a run hands on (:attr:`Result.part`): the seam between the
    operations of a process (:mod:`jaxform.process`)."""

    scene: Scene
    state: SimState


@dataclass
class Result:
    """History (one row per converged load step, row 0 = initial state) and fields."""

    history: dict[str, np.ndarray]
    # per row: x, stress, s, eqps, slip_mm, contact_status, damage; arrays stacked over the rows, or
    # after remeshing a list of per-row arrays (each on its row's mesh, scene_at(row)); a
    # field simulate() was not asked to keep for every row (keep_fields): the last row's
    # alone (one entry)
    fields: dict
    scene: Scene
    final_state: SimState
    newton_histories: np.ndarray  # per step: ||R_k|| / F of the last (sub)step's Newton
    failure: str | None = None
    inputs: Inputs | None = None  # the inputs final_state refers to (coords change on rezoning)
    rezones: list = field(default_factory=list)  # jaxform.rezone.RezoneReport per rezoning
    # the meshes of the run: segments[k] holds from row segments[k].first_row on (one
    # segment without remeshing); jaxform.remesh.RemeshReport per remesh
    segments: list = field(default_factory=list)
    remeshes: list = field(default_factory=list)
    step_programs: int = 1  # distinct compiled step programs (capacity buckets) the run used
    # the free surface's folds that persist to the end (jaxform.laps): laps (wedges:
    # row, stroke_mm, r_mm, z_mm, angle_deg, ..., depth_mm) and pockets (air between the
    # material and a die: ..., gap_mm, length_mm)
    laps: list = field(default_factory=list)
    pockets: list = field(default_factory=list)

    def scene_at(self, row: int) -> Scene:
        """The scene (mesh, sets, reference coordinates) of history row ``row``."""
        if not self.segments:
            return self.scene
        return _scene_of_row(self.segments, row % len(self.history["time_s"]))

    @property
    def final_scene(self) -> Scene:
        """The scene of the last row (the last mesh) that ``final_state`` refers to."""
        return self.segments[-1].scene if self.segments else self.scene

    @property
    def part(self) -> PartState:
        """The workpiece the run leaves: its last mesh and final state."""
        return PartState(self.final_scene, self.final_state)


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
    "remeshed",
)
FIELD_KEYS = tuple(OUTPUT_FIELDS)  # the per-step fields indexed over the mesh
PROGRESS_KEYS = ("time_s", "stroke_mm", "force_N", "iterations", "cutbacks", "dt_s")


def _initial_row(scene: Scene, state: SimState) -> dict:
    """History row 0: the initial state."""
    out = jax.device_get(_outputs(scene.model, state, scene.inputs, scene.idx, scene.symmetric_z))
    q = min_quality(np.asarray(scene.inputs.coords), np.asarray(scene.mesh.elements))
    out.update(damage_columns(scene, out["x"], out["damage"]))
    return dict(out, iterations=0, factorizations=0, cutbacks=0, code=OK, rezoned=0,
                remeshed=0, new_nodes=0, dt_s=0.0, mesh_quality=float(q),
                pause_cause=0)  # fmt: skip


def _progress(scene: Scene, step: int, row: dict, chunk_end: bool) -> dict:
    """What the progress callback gets after a step: its number, an estimate of the
    number of steps (the rest at the largest step), whether it is the last converged step
    of its compiled chunk, and the row's scalars."""
    left = max(scene.t_end - float(row["time_s"]), 0.0)
    n_steps = step + int(math.ceil(left / scene.dt - 1e-9))
    remeshed = int(row["new_nodes"])
    return dict(step=step, n_steps=n_steps, chunk_end=chunk_end, remeshed=remeshed,
                remesh_trigger=causes(int(row["pause_cause"])) if remeshed else "",
                **{k: row[k] for k in PROGRESS_KEYS})  # fmt: skip


def _scene_of_row(segments, row: int) -> Scene:
    """The scene of the segment that holds row ``row`` (``row`` >= 0)."""
    return next(s.scene for s in reversed(segments) if s.first_row <= row)


def _report(scene: Scene, run: Run, first: int, progress, on_row) -> None:
    """Hand the rows from ``first`` on to the caller: each row with its scene and every
    output field to ``on_row``, its scalars to ``progress`` (either may be None)."""
    for k in range(first, len(run.rows)):
        row = run.rows[k]
        if on_row is not None:
            on_row(k, _scene_of_row(run.segments, k), {f: row[f] for f in FIELD_KEYS})
        if progress is not None:
            progress(_progress(scene, k, row, k == len(run.rows) - 1))


def _each_row(result: Result, on_row) -> None:
    """Hand every row of a finished ``result`` to ``on_row`` (a run whose rows came at
    once: a screw press's or a hammer's blows)."""
    if on_row is None:
        return
    for k in range(len(result.history["time_s"])):
        on_row(k, result.scene_at(k), {f: result.fields[f][k] for f in FIELD_KEYS})


def die_force_column(name: str) -> str:
    """The history column of the force die ``name`` carries (N)."""
    return f"force_{name}_N"


class Before(NamedTuple):
    """What a run was on just before its newest mesh: to go back to (a failed first step
    on that mesh, :func:`_undone`)."""

    state: SimState
    mesh: OnMesh
    control: StepControl


@dataclass(frozen=True)
class Run:
    """The host loop's state between two compiled chunks: the mesh the run is on, the
    state on it and the step control, the rows so far (row 0 the initial state), the
    meshes (:class:`Segment`) and the adaptation's reports, the converged steps since the
    last new mesh, the armed triggers, the compiled step programs (layouts) used, the
    failure (None: going on), what it was on before the last new mesh, and the
    output fields every row keeps (the others only the last row: :func:`_thinned`)."""

    mesh: OnMesh
    state: SimState
    control: StepControl
    armed: Armed
    rows: tuple = ()
    segments: tuple = ()
    reports: tuple = ()
    since: int = 0
    programs: frozenset = frozenset()
    failure: str | None = None
    before: Before | None = None
    keep: tuple = FIELD_KEYS
    rescued: str | None = None  # the failure a new mesh answers until a step converges on it
    went_back: int = 0  # new meshes in a row whose first step failed (_back_on_old_mesh)


def _thinned(rows: tuple, first: int, keep: tuple) -> tuple:
    """``rows`` with the rows from ``first`` to the one before the last without the
    output fields not in ``keep``: a row's fields live as long as a row holds them
    (a chunk's outputs, one array per field over its steps), and the 200 x 200 seed
    scene's stresses, damage and strains are 18 MB a row."""
    drop = [k for k in FIELD_KEYS if k not in keep]
    if not drop:
        return rows
    first = max(first, 0)
    lean = tuple({k: v for k, v in r.items() if k not in drop} for r in rows[first:-1])
    return rows[:first] + lean + rows[-1:]


def _started(scene: Scene, adaptation, start: SimState | None, keep: tuple) -> Run:
    """The run at its start: the adaptation's first mesh, the state (``start`` or the
    scene's initial one), the triggers armed from the scene's thresholds."""
    state, control = init(scene)
    state = state if start is None else start
    mesh = adaptation.first_mesh(scene)
    armed = Armed.of(scene, mesh.stepper.triggers)
    return Run(
        mesh,
        state,
        replace(control, thresholds=armed.thresholds()),
        armed,
        rows=(_initial_row(scene, state),),
        segments=(Segment(0, scene, padded=mesh.padded),),
        programs=frozenset({mesh.stepped.model.layout}),
        keep=keep,
    )


def _stepped(run: Run, owned: OwnedFactorization) -> Run:
    """``run`` after one compiled chunk (:func:`jaxform.chunks.run_on`): its state, control
    and converged rows, and the failure that ends it (:func:`jaxform.chunks.converged_rows`)."""
    thresholds = run.armed.for_chunk(run.control.thresholds, run.since)
    control = replace(run.control, thresholds=thresholds)
    started = time.perf_counter()
    state, control, outs, fac = run_on(run.mesh, run.state, control, owned.lend())
    owned.keep(fac)
    give_back_after(time.perf_counter() - started)  # what a long chunk left free in the heap
    rows, failure = converged_rows(run.mesh, state, outs, len(run.rows))
    for row in rows:  # computed while the row has its damage field
        row.update(damage_columns(run.mesh.scene, row["x"], row["damage"]))
    return replace(
        run,
        state=state,
        control=control,
        rows=run.rows + tuple(rows),
        since=run.since + len(rows),
        failure=failure,
    )


def _adapts(run: Run, t_stop: float) -> bool:
    """Whether the run's paused last row is answered by its adaptation: not at the end,
    and not where the step planned next ends the run and only triggers for the steps ahead
    fired (:meth:`Armed.only_ahead`): such a new mesh would serve the last step alone, and
    a remesh costs a transient of the force that recovers over some microns of die travel
    (docs/remeshing.md, "Where a dip comes from"), so the run's last row would read it."""
    t = float(run.state.t)
    if t >= t_stop:
        return False
    last_step = t + float(run.control.h) >= t_stop
    return not (last_step and run.armed.only_ahead(run.rows[-1]))


def _last_step_broke_mesh(run: Run, t_stop: float) -> bool:
    """Whether ``run``'s step to the end, taken on a mesh whose adaptation was declined
    for it (:func:`_adapts`), left that mesh below :data:`jaxform.triggers.HOLDS` of the
    quality threshold: the last step is then taken again on the adapted mesh (generated
    die 29: quality 0.268 before its last step of 14 um, 0.0017 after it, an element of
    the flash collapsed, and the force fell 6.5 %).  Where the adaptation or the step
    taken again fails, the kept mesh's step stands."""
    done = run.failure is None and float(run.state.t) >= t_stop
    return done and not run.armed.holds(run.rows[-1])


def _on_new_mesh(run: Run) -> bool:
    """Whether ``run`` has a new mesh with no converged step on it yet."""
    return len(run.segments) > 1 and run.segments[-1].first_row == len(run.rows)


def _stepped_on(run: Run, owned: OwnedFactorization) -> Run:
    """:func:`_stepped`, and where the first step on a new mesh fails at every cutback
    below a step size the run had already cut to, once more from ``time.dt_s``: the
    transferred state is balanced on the old mesh, and on the new one a step of a few
    microseconds must take up the difference elastically, where a larger step lets the
    material flow (docs/remeshing.md, "Dies nobody tuned")."""
    new = _stepped(run, owned)
    if new.failure is None or not _on_new_mesh(new):
        return new
    dt = float(run.control.dt_max)
    if not float(run.control.h) < dt:
        return new
    again = _stepped(replace(run, control=replace(run.control, h=run.control.dt_max)), owned)
    if again.failure is None:
        return again
    return replace(again, failure=f"tried again from time.dt_s = {dt:g} s, {again.failure}")


def _adapted(run: Run, done: Adapted, owned: OwnedFactorization) -> Run:
    """``run`` after its adaptation answered the paused last row with ``done``: the row's
    columns, the mesh and state to go on from, the report, the triggers re-armed; a new
    mesh starts a segment and a factorization of its own."""
    if done.failure is not None:
        return replace(run, failure=f"step {len(run.rows) - 1}: {done.failure}")
    row = {**run.rows[-1], **done.row}
    out = replace(
        run,
        mesh=done.mesh,
        state=done.state,
        control=replace(run.control, thresholds=run.armed.thresholds(row, done.quality_after)),
        rows=run.rows[:-1] + (row,),
        reports=run.reports + ((done.report,) if done.report is not None else ()),
    )
    if not done.new_mesh:
        return out
    owned.renew(done.mesh.stepped)
    segment = Segment(len(run.rows), done.mesh.scene, done.transfer, done.mesh.padded)
    return replace(
        out,
        segments=run.segments + (segment,),
        since=0,
        before=Before(run.state, run.mesh, run.control),
        programs=run.programs | {done.mesh.stepped.model.layout},
    )


def _adapted_paused(run: Run, adaptation, owned: OwnedFactorization) -> Run:
    """``run`` with its paused last row answered by ``adaptation`` (:func:`_adapted`)."""
    return _adapted(run, adaptation.adapt(run.mesh, run.state, run.rows[-1]), owned)


def _rescued(run: Run, adaptation, owned: OwnedFactorization) -> Run:
    """``run``, whose step failed at the smallest step size on a mesh that had converged
    steps, on a new mesh made at its last converged state (the run goes on from there);
    ``run`` itself where the scene does not remesh, the failure is the press capacity or
    no step has converged yet, or the remesh fails.  A step that fails on a worn mesh
    (the two-stage disk's flash land: Newton stalled at ||R||/F 0.015 with the worst
    corner at quality 0.31, the quality trigger at 0.3) may go on from a fresh one; its
    first step failing as well stops the run with both causes (:func:`_without_empty_mesh`)."""
    if (
        not isinstance(adaptation, Remeshing)
        or run.failure is None
        or _on_new_mesh(run)
        or len(run.rows) < 2
        or int(run.rows[-1].get("pause_cause", 0)) & CAPACITY
    ):
        return run
    last = {**run.rows[-1], "pause_cause": FAILED_STEP, "paused": False}  # answered here
    paused = replace(run, failure=None, rows=run.rows[:-1] + (last,))
    done = adaptation.adapt(run.mesh, run.state, last)
    if done.failure is not None or not done.new_mesh:
        return run
    return replace(_adapted(paused, done, owned), rescued=run.failure)


# new meshes in a row whose first step may fail before the run stops (_back_on_old_mesh)
GO_BACK_LIMIT = 2


def _back_on_old_mesh(run: Run, owned: OwnedFactorization) -> Run:
    """``run``, whose first step on its newest mesh failed (also from ``time.dt_s``), back
    on the mesh before it at the last converged state, that remesh undone, to go on there;
    ``run`` itself where that mesh was made because a step had failed (:func:`_rescued`)
    or GO_BACK_LIMIT new meshes in a row have failed so.  The old mesh, worn but good for
    a step or more, moves the state on, and the remesh its trigger makes after that step
    is another mesh of another section: the two-stage disk's configured blocker at 0.98 of
    its billet on 0.35 mm elements stopped at the finisher's first step after the remesh
    at 0.29 s and, with this, goes on."""
    if (
        run.failure is None
        or not _on_new_mesh(run)
        or run.rescued is not None
        or run.went_back >= GO_BACK_LIMIT
    ):
        return run
    back = _undone(run)
    owned.renew(back.mesh.stepped)
    return replace(
        back,
        # not paused again: the same remesh of the same state would fail the same way
        rows=back.rows[:-1] + ({**back.rows[-1], "paused": False},),
        since=len(back.rows) - max(back.segments[-1].first_row, 1),  # its steps (row 0: none)
        failure=None,
        went_back=run.went_back + 1,
    )


def _undone(run: Run) -> Run:
    """``run`` back on what it was on before its newest mesh (:class:`Before`), that
    remesh undone: its segment and report dropped, its row's remesh columns 0."""
    state, mesh, control = run.before
    return replace(
        run,
        mesh=mesh,
        state=state,
        control=control,
        rows=run.rows[:-1] + ({**run.rows[-1], "remeshed": 0, "new_nodes": 0},),
        segments=run.segments[:-1],
        reports=run.reports[:-1],
        before=None,
    )


def _without_empty_mesh(run: Run) -> Run:
    """A run whose first step on its newest mesh failed ends on the mesh before it (the
    last converged state), that mesh's remesh undone; where that mesh was made because a
    step had failed (:func:`_rescued`), the message names that failure first."""
    if not _on_new_mesh(run):
        return run
    back = _undone(run)
    time_s = back.rows[-1]["time_s"]
    failure = f"the first step after the remesh at {time_s:g} s: {run.failure}"
    if run.rescued is not None:
        failure = (f"{run.rescued}; a new mesh at the last converged time {time_s:g} s "
                   f"did not help: its first step: {run.failure}")  # fmt: skip
    return replace(back, failure=failure)


def _result(scene: Scene, run: Run, adaptation) -> Result:
    """The :class:`Result` of a finished (or stopped) run."""
    rows, segments = list(run.rows), list(run.segments)
    fields = _fields(rows, len(segments) == 1, run.keep)
    history = _history(segments, rows, fields)
    # a remeshed scene may switch Newton variant with its size ('auto'), and with it the
    # length of the residual history: shorter ones are padded with inf
    width = max((len(r["hist"]) for r in rows[1:]), default=0)
    hists = np.array([np.pad(np.asarray(r["hist"], float), (0, width - len(r["hist"])),
                             constant_values=np.inf) for r in rows[1:]])  # fmt: skip
    reports = {adaptation.reports: list(run.reports)} if adaptation.reports else {}
    return Result(
        history=history,
        fields=fields,
        scene=scene,
        final_state=run.state,
        newton_histories=hists,
        failure=run.failure,
        inputs=run.mesh.inputs,
        segments=segments,
        step_programs=len(run.programs),
        laps=laps(history, scene.settings.output.lap_angle_deg),
        pockets=pockets(history, scene.settings.output.lap_angle_deg),
        **reports,
    )


def _fields(rows: list[dict], one_mesh: bool, keep: tuple = FIELD_KEYS) -> dict:
    """The fields of every row (those not in ``keep``: of the last row alone): arrays
    stacked over the rows on one mesh, else a list per field with one array per row
    (each on its row's mesh)."""
    picked = {k: rows if k in keep else rows[-1:] for k in FIELD_KEYS}
    if one_mesh:
        return {k: np.stack([np.asarray(r[k]) for r in picked[k]]) for k in FIELD_KEYS}
    return {k: [np.asarray(r[k]) for r in picked[k]] for k in FIELD_KEYS}


def _history(segments: list[Segment], rows: list[dict], fields: dict) -> dict:
    """The history columns: the step's scalars, then per mesh the scene's extra columns."""
    history = {k: np.array([float(r[k]) for r in rows]) for k in HISTORY_KEYS}
    history["newton_iterations"] = history.pop("iterations")
    ends = [seg.first_row for seg in segments[1:]] + [len(rows)]
    parts = [
        extra_history(
            seg.scene, fields["x"][seg.first_row : end], history["time_s"][seg.first_row : end]
        )  # fmt: skip
        for seg, end in zip(segments, ends)
    ]
    history.update({k: np.concatenate([p[k] for p in parts]) for k in parts[0]})
    names = [k for k in rows[0] if k.startswith("damage_")]  # forming_outputs.damage_columns
    history.update({k: np.array([float(r[k]) for r in rows]) for k in names})
    die = segments[0].scene.inputs.die
    if "die_forces_N" in rows[0]:  # several dies: the force each carries
        per_die = np.array([np.asarray(r["die_forces_N"]) for r in rows])
        history.update({die_force_column(name): per_die[:, i] for i, name in enumerate(die.names)})
    if segments[0].scene.model.layout.temperature:
        heat = np.array([np.asarray(r["heat_mJ"]) for r in rows])
        history.update({k: heat[:, i] for i, k in enumerate(HEAT_COLUMNS)})
    return history


def simulate(
    scene: Scene,
    progress: Callable[[dict], None] | None = None,
    start: SimState | PartState | None = None,
    keep_fields: tuple[str, ...] = FIELD_KEYS,
    on_row: Callable[[int, Scene, dict], None] | None = None,
) -> Result:
    """Run the scene to its end; raises SimulationError (with .result) on failure.

    Steps adapt (:class:`Stepper`): ``scene.dt`` is the largest step, a failed attempt
    halves it, easy steps let it grow back; every converged step is a history row
    (column ``dt_s``), and the run ends exactly at ``scene.t_end``.  A trigger
    (:mod:`jaxform.triggers`) ends a compiled chunk after the step that fires it and the
    scene's adaptation (:mod:`jaxform.adaptation`) answers: with ``scene.rezone_quality``
    > 0, a step after which an element's worst corner quality is below it is followed by
    rezoning (:mod:`jaxform.rezone`; history column ``rezoned`` = 1 on that step); with
    ``scene.remesh`` on, such a step (or every ``remesh.every_steps``-th, ...) by a new
    mesh (:mod:`jaxform.remesh`): the run goes on from the transferred state on it, a new
    :class:`Segment` of the result (history column ``remeshed`` = 1 on that step).

    Arguments:
        scene: a scene built by :func:`jaxform.scenes.build_scene`.
        progress: called after each converged step with a dict (step, n_steps estimate,
            chunk_end, time_s, stroke_mm, force_N, iterations, cutbacks, dt_s, and
            remeshed: the nodes of the new mesh after a remesh, else 0, with
            remesh_trigger naming what fired it), or None.
        start: the state to start from, on ``scene`` (a :class:`PartState` whose scene
            is ``scene``, or its state; None: the scene's initial state): an operation of
            a process starts from the part the one before it left (:mod:`jaxform.process`).
        keep_fields: the output fields (:data:`FIELD_KEYS`) :attr:`Result.fields` holds
            for every row; the others it holds for the last row alone (one entry), and a
            row lets go of them once the next row has come (``x`` is always kept: the
            history's columns are read from it; a screw press's or a hammer's run,
            one compiled program, keeps every field).  Default: every field.
        on_row: called with (row number, its scene, its output fields) for every row as
            the run accepts it, row 0 first, before the row lets go of the fields not
            kept: a writer of every row's fields that holds none of them (the command
            line's ParaView series, :class:`jaxform.io.VtuSeries`).  A row taken again
            (the last step on an adapted mesh) comes again under its number.

    A press capacity (``scene.press.capacity_N`` > 0) stops the run after the first step
    whose ram force reaches it: SimulationError ("press capacity ... reached at stroke
    ... mm, step N") with the history and the final state of that step.  A screw press or
    hammer scene runs its blows (:func:`jaxform.blows.simulate_blows`).

    Returns:
        A :class:`Result`: the history (one row per converged step, row 0 the initial
        state), the fields, the final state (:attr:`Result.part`) and the reports of the
        rezonings or remeshes."""
    unknown = sorted(set(keep_fields) - set(FIELD_KEYS))
    if unknown:
        raise ValueError(f"simulate: keep_fields {unknown} are not output fields {FIELD_KEYS}")
    if scene.press is not None and scene.press.energy_limited:  # a screw press, a hammer
        from jaxform.blows import simulate_blows

        if start is not None:
            raise ValueError("simulate: a screw press or hammer run starts from t = 0")
        try:  # its rows come out of one compiled program: handed on at the end
            result = simulate_blows(scene, progress)
        except SimulationError as err:
            _each_row(err.result, on_row)
            raise
        _each_row(result, on_row)
        return result
    adaptation = adaptation_of(scene)
    keep = tuple(k for k in FIELD_KEYS if k in keep_fields or k == "x")
    run = _started(scene, adaptation, start.state if isinstance(start, PartState) else start, keep)
    owned = OwnedFactorization(run.mesh.stepped, run.state.x.dtype)
    t_stop = scene.t_end - 1e-9 * scene.dt
    reporting, host_error = False, None  # host_error: what a host-loop failure chains
    _report(scene, run, 0, None, on_row)
    reported = 1  # the rows handed to on_row
    try:
        declined = False  # the run paused before its last step and kept its mesh for it
        while float(run.state.t) < t_stop and run.failure is None:
            first = len(run.rows)
            stepped = _stepped_on(run, owned)
            if declined and _last_step_broke_mesh(stepped, t_stop):
                # the last step on the kept mesh left it below what holds: adapt after all
                # and take it again (where that fails, the kept mesh's step stands)
                again = _adapted_paused(run, adaptation, owned)
                retried = _stepped_on(again, owned) if again.failure is None else again
                if retried.failure is None:
                    stepped, first = retried, first - 1  # the paused row again, now adapted
            run = stepped
            if len(run.rows) > first:  # a step converged: a new mesh's rescue is done,
                # and where it converged on a new mesh, that mesh works
                fresh = run.segments[-1].first_row >= first
                run = replace(run, rescued=None, went_back=0 if fresh else run.went_back)
            if run.failure is not None and (
                (again := _back_on_old_mesh(run, owned)) is not run
                or (again := _rescued(run, adaptation, owned)) is not run
            ):
                # a failed first step on a new mesh goes back to the mesh before it; a
                # failed step on a worn mesh goes on from a new mesh at the last converged
                # row; either way that row is handed on again with its remesh columns
                run, first = again, min(first, len(run.rows) - 1)
            paused = len(run.rows) > first and bool(run.rows[-1]["paused"])
            declined = False
            if paused and run.failure is None:
                if _adapts(run, t_stop):
                    run = _adapted_paused(run, adaptation, owned)
                else:
                    declined = float(run.state.t) < t_stop
            reporting = True  # an error of the caller's callbacks is the caller's
            _report(scene, run, first, progress, on_row)
            reporting, reported = False, len(run.rows)
            run = replace(run, rows=_thinned(run.rows, first - 1, run.keep))
    except Exception as err:  # a failure of the host loop itself: the last state is kept
        if reporting:
            raise
        run, host_error = replace(run, failure=host_failure(run.rows[-1], err)), err
    finally:
        owned.release()  # the last factorization kept; one a raising chunk held is lost
    _report(scene, run, reported, None, on_row)  # rows a failure between chunks left
    result = _result(scene, _without_empty_mesh(run), adaptation)
    if result.failure:
        raise SimulationError(result.failure, result) from host_error
    return result


def state_result(scene: Scene, state: SimState) -> Result:
    """A one-row :class:`Result`: ``state`` of ``scene`` as a history row and its fields,
    with no step taken (a process's trim, a dwell without heat, :mod:`jaxform.process`)."""
    rows = [_initial_row(scene, state)]
    fields = _fields(rows, True)
    segments = [Segment(0, scene)]
    return Result(history=_history(segments, rows, fields), fields=fields, scene=scene,
                  final_state=state, newton_histories=np.zeros((0, 0)), inputs=scene.inputs,
                  segments=segments)  # fmt: skip


def init(scene: Scene) -> tuple[SimState, StepControl]:
    """The start of a run that the caller steps (:func:`step`).

    Arguments:
        scene: from :func:`jaxform.scenes.build_scene`.

    Returns:
        (state at t = 0, step control): the first step is the largest, ``scene.dt``;
        every trigger off (:func:`step` does not pause).
    """
    require_x64()
    if scene.press is not None and scene.press.energy_limited:
        raise ValueError(
            f"init: a {scene.press.name} press moves the die with the work done, not with "
            "time; run it with simulate() or jaxform.blows.blow_run"
        )
    control = StepControl(
        h=jnp.asarray(scene.dt),
        dt_max=jnp.asarray(scene.dt),
        t_end=jnp.asarray(scene.t_end),
        continuations=jnp.asarray(scene.continuations),
        max_quality_drop=jnp.asarray(scene.max_quality_drop),
        probe=jnp.asarray(scene.first_step_probe),
        thresholds=off(stepper_of(scene).triggers),
    )
    return initial_state(scene.model, scene.inputs), control


_attempt = jit(attempt_step, static_argnums=0)
# one compiled program for a row's outputs (eagerly, the die force and the die's motion
# would each dispatch, and on a cold start compile, dozens of small operations)
_outputs = jit(step_outputs, static_argnums=(0, 4))


def step(
    scene: Scene, state: SimState, control: StepControl, inputs: Inputs | None = None
) -> tuple[SimState, StepControl, dict]:
    """One converged step from ``state`` (adaptive size; the last one ends at t_end).
    With modified Newton the step factors at its first iteration and frees its
    factorization before returning (none is kept from one call to the next).

    Arguments:
        scene: from :func:`jaxform.scenes.build_scene`.
        state, control: from :func:`init` or the previous call.
        inputs: the differentiable inputs (default ``scene.inputs``).

    Returns:
        (state, control for the next step, info): info has the step's outputs
        (time_s, stroke_mm, force_N, ...), ``dt_s``, ``iterations`` and ``cutbacks``.

    Raises:
        SimulationError: the step failed at the smallest step size (its ``result`` is
        None; the state passed in is the last good one).
    """
    inp = scene.inputs if inputs is None else inputs
    scene = analyzed(scene)
    # modified Newton: a factorization of this step alone
    n = scene.model.layout.n_dofs
    fac = scene.newton.variant.factorization(scene.linear, n, state.x.dtype)
    new, info, fac = _attempt(stepper_of(scene), state, control, inp, scene.idx, fac)
    scene.linear.release_now(fac)
    if int(info["code"]) != OK:
        row = {"cutbacks": info["cutbacks"], "code": info["code"]}
        raise SimulationError(failure_message(scene, inp, state, None, row), None)
    out = jax.device_get(_outputs(scene.model, new, inp, scene.idx, scene.symmetric_z))
    out.update(dt_s=float(info["h_used"]), iterations=int(info["iterations"]),
               cutbacks=int(info["cutbacks"]))  # fmt: skip
    return new, replace(control, h=info["h_next"]), out
