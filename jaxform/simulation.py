"""The host loop: a scene run to its end, with progress, rezoning and the history.

The caller owns the loop (jax-md style): :func:`init` gives the state at t = 0 and the
step control, :func:`step` advances one converged step of adaptive size (compiled once
per scene), and the caller decides what to do between steps.  :func:`simulate` is that
loop, written once for the command line and scripts: it advances the scene chunk by
chunk through the compiled ``lax.scan`` of :func:`jaxform.stepping.run_chunk`, hands each
converged step to an optional progress callback, rezones the mesh when the scene asks for
it (:mod:`jaxform.rezone`), and collects the history (one row per converged step, column
``dt_s``; the workpiece's and the die's extra columns, :func:`jaxform.postprocess.extra_history`).
When a step fails at the smallest step size the run stops, keeping the last converged
state, and :class:`SimulationError` names the step, the time, the cause and the worst
element.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import jax
import jax.numpy as jnp
import numpy as np
from jax.errors import JaxRuntimeError

from jaxform import program_store
from jaxform.capacity import padded
from jaxform.fields import OUTPUT_FIELDS
from jaxform.forming_outputs import damage_history
from jaxform.postprocess import HEAT_COLUMNS, extra_history, laps
from jaxform.precision import require_x64
from jaxform.presses import capacity_message
from jaxform.remesh import RemeshError, remesh
from jaxform.rezone import RezoneError, corner_qualities, min_quality, rezone
from jaxform.scenes import Inputs, Scene
from jaxform.status import CAUSES, NOT_FINITE, OK, SINGULAR
from jaxform.stepping import (
    SimState,
    StepControl,
    Stepper,
    attempt_step,
    initial_state,
    run_chunk,
    step_outputs,
)
from jaxform.triggers import CORNER, FOLD, causes
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


@dataclass
class Result:
    """History (one row per converged load step, row 0 = initial state) and fields."""

    history: dict[str, np.ndarray]
    # per row: x, stress, s, eqps, slip_mm, contact_status, damage; arrays stacked over the rows, or
    # after remeshing a list of per-row arrays (each on its row's mesh, scene_at(row))
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
    # laps found (jaxform.postprocess.laps): row, stroke_mm, r_mm, z_mm, angle_deg
    laps: list = field(default_factory=list)

    def scene_at(self, row: int) -> Scene:
        """The scene (mesh, sets, reference coordinates) of history row ``row``."""
        if not self.segments:
            return self.scene
        row = row % len(self.history["time_s"])
        return next(s.scene for s in reversed(self.segments) if s.first_row <= row)

    @property
    def final_scene(self) -> Scene:
        """The scene of the last row (the last mesh) that ``final_state`` refers to."""
        return self.segments[-1].scene if self.segments else self.scene


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


def _failure_message(scene: Scene, inp: Inputs, state: SimState, step: int | None, row) -> str:
    """Why step ``step`` (None: the step from ``state``) failed, where: the cause, the
    time reached, the smallest step tried, and the worst element of the last converged
    mesh (its centre and corner quality), which names the place when the cause is
    geometric (an element folding)."""
    pos = scene.model.nodal_positions(np.asarray(state.x), np.asarray(inp.coords), scene.idx)
    elements = np.asarray(scene.mesh.elements)
    q = corner_qualities(np.asarray(pos), elements).min(axis=1)
    e = int(np.argmin(q))
    centre = np.asarray(pos)[elements[e]].mean(axis=0)
    h_min = scene.dt * 0.5**scene.max_cutbacks
    t = float(state.t)
    name = "the step" if step is None else f"step {step}"
    return (
        f"{name} (last converged time {t:g} s, target time "
        f"{min(t + h_min, scene.t_end):g} s) failed after {int(row['cutbacks'])} attempts, "
        f"the last at the smallest step dt = {h_min:g} s (time.dt_s / 2**solver.max_cutbacks): "
        f"{CAUSES.get(int(row['code']), 'unknown')}; worst element {e} at "
        f"({centre[0]:.4g}, {centre[1]:.4g}) mm, corner quality {q[e]:.3g}{_remedy(scene, q[e])}"
    )


def _remedy(scene: Scene, quality: float) -> str:
    """The setting that lets a run stopped by a distorted element go on: a new mesh
    before the elements fold (remeshing, or a higher trigger than the one set)."""
    if quality >= 0.3:
        return ""
    rm = scene.remesh
    if rm is not None and rm.on and rm.quality_below < 0.3:
        return (
            f"; remesh.quality_below = {rm.quality_below:g} fired too late: 0.3 replaces the "
            f"mesh earlier"
        )
    if rm is not None and rm.on:
        return "; remesh.element_size_mm smaller (a finer new mesh) may let the run go on"
    if scene.rezone_quality > 0.0:
        return (
            "; the mesh folds faster than rezoning can mend it: remeshing "
            "(mesh.rezone_quality = 0, remesh.quality_below = 0.3) replaces it"
        )
    return "; to go on, let the run replace the mesh before it folds: remesh.quality_below = 0.3"


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
    return dict(out, iterations=0, factorizations=0, cutbacks=0, code=OK, rezoned=0,
                remeshed=0, new_nodes=0, dt_s=0.0, mesh_quality=float(q),
                pause_cause=0)  # fmt: skip


def _host_failure(row: dict, err: Exception) -> str:
    """The one line for an error raised between the compiled chunks (a remesh, a
    transfer, the history): where the run was and what was raised."""
    return (
        f"the run stopped after the converged time {float(row['time_s']):g} s (stroke "
        f"{float(row['stroke_mm']):.4g} mm): {type(err).__name__}: {err}"
    )


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


def die_force_column(name: str) -> str:
    """The history column of the force die ``name`` carries (N)."""
    return f"force_{name}_N"


def _finite(row: dict) -> bool:
    """Whether a converged step's force and unknowns are finite numbers."""
    return bool(np.isfinite(row["force_N"]) and np.all(np.isfinite(row["x"])))


def _singular(err: Exception) -> bool:
    return "singular" in str(err)


def _run_chunk(stepper: Stepper, state, control, inp: Inputs, idx, n: int, fac):
    """:func:`run_chunk`, through the stored program of its stepper and chunk length where
    there is one (:mod:`jaxform.program_store`: a warm start without tracing)."""
    return program_store.call(
        "run_chunk",
        f"{stepper!r}|n={n}",
        lambda s, c, i, x, f: run_chunk(stepper, s, c, i, x, n, f),
        state,
        control,
        inp,
        idx,
        fac,
    )


def _chunk(scene: Scene, stepper: Stepper, state: SimState, control, inp: Inputs, fac):
    """:func:`run_chunk` over ``scene.chunk`` steps.  A linear solver that finds the
    Jacobian singular raises (klujax does, instead of returning a status); then the steps
    are retried one at a time, the step halved after each singular attempt as after any
    failed one, down to the smallest step, where the outputs carry the code SINGULAR."""
    try:  # blocking: an error of the asynchronous run surfaces here, not at the caller
        return jax.block_until_ready(
            _run_chunk(stepper, state, control, inp, scene.idx, scene.chunk, fac)
        )
    except JaxRuntimeError as err:
        if not _singular(err):
            raise
    # the factorization passed in may have been freed inside the failed chunk: a new one
    n = scene.model.layout.n_dofs
    modified = scene.newton.method == "modified"
    h_min = scene.dt * 0.5**scene.max_cutbacks
    h, cutbacks = float(control.h), 0
    while True:
        fac = scene.linear.empty_factorization(n, state.x.dtype) if modified else None
        try:
            st, ctl, outs, fac = jax.block_until_ready(
                _run_chunk(
                    stepper, state, replace(control, h=jnp.asarray(h)), inp, scene.idx, 1, fac
                )
            )
        except JaxRuntimeError as err:
            if not _singular(err):
                raise
            cutbacks += 1
            if h <= h_min * (1.0 + 1e-9):
                failed = dict(active=np.array([True]), code=np.array([SINGULAR]),
                              cutbacks=np.array([cutbacks]))  # fmt: skip
                return state, control, failed, None
            h = max(0.5 * h, h_min)
            continue
        return st, ctl, dict(outs, cutbacks=outs["cutbacks"] + cutbacks), fac


def _rezone_after(scene: Scene, state: SimState, inp: Inputs, control: StepControl):
    """Rezone after a step that paused the chunk: (state, inputs, control, report).  A
    rezoning that could not raise the quality keeps the mesh and waits until the quality
    has fallen by another 10 %.  Raises RezoneError."""
    state, inp, report = rezone(scene, state, inp)
    trigger = scene.rezone_quality if report.improved else 0.9 * report.quality_before
    return state, inp, replace(control, rezone_quality=jnp.asarray(trigger)), report


def _remesh_triggers(control: StepControl, settings, row: dict | None = None, report=None,
                     stroke: float | None = None) -> StepControl:  # fmt: skip
    """The remesh triggers for the steps on a new mesh (after the remesh of ``report``,
    paused on ``row``; at the start: ``stroke`` = 0).  A trigger that the new mesh still
    fires (the corner quality, a die corner's depth or a fold, which keep the old
    boundary) waits until it has become 10 % worse, as rezoning does, so that a scene
    cannot remesh on every step."""
    stroke = float(row["stroke_mm"]) if row is not None else stroke
    s = settings
    q, depth, fold = s.quality_below, s.corner_depth_ratio, s.fold_angle_deg
    if report is not None:
        q = q if report.quality_after > q else 0.9 * report.quality_after
        if int(row["pause_cause"]) & CORNER:
            depth = max(depth, 1.1 * float(row["corner_depth_ratio"]))
        if int(row["pause_cause"]) & FOLD:
            fold = min(fold, 0.9 * float(row["free_fold_deg"]))
    every = s.every_stroke_mm
    return replace(control, rezone_quality=jnp.asarray(q),
                   pause_stroke_mm=jnp.asarray(stroke + every if every > 0 else 0.0),
                   corner_depth_ratio=jnp.asarray(depth),
                   fold_angle_deg=jnp.asarray(fold))  # fmt: skip


def _fields(rows: list[dict], one_mesh: bool) -> dict:
    """The fields of every row: arrays stacked over the rows on one mesh, else a list per
    field with one array per row (each on its row's mesh)."""
    if one_mesh:
        return {k: np.stack([np.asarray(r[k]) for r in rows]) for k in FIELD_KEYS}
    return {k: [np.asarray(r[k]) for r in rows] for k in FIELD_KEYS}


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
    out = segments[0].scene.settings.output
    damage = [
        damage_history(
            seg.scene,
            fields["x"][seg.first_row : end],
            fields["damage"][seg.first_row : end],
            out.damage_critical,
            out.damage_criterion,
        )  # fmt: skip
        for seg, end in zip(segments, ends)
    ]
    history.update({k: np.concatenate([p[k] for p in damage]) for k in damage[0]})
    die = segments[0].scene.inputs.die
    if "die_forces_N" in rows[0]:  # several dies: the force each carries
        per_die = np.array([np.asarray(r["die_forces_N"]) for r in rows])
        history.update({die_force_column(name): per_die[:, i] for i, name in enumerate(die.names)})
    if segments[0].scene.model.layout.temperature:
        heat = np.array([np.asarray(r["heat_mJ"]) for r in rows])
        history.update({k: heat[:, i] for i, k in enumerate(HEAT_COLUMNS)})
    return history


def simulate(
    scene: Scene, progress: Callable[[dict], None] | None = None, start: SimState | None = None
) -> Result:
    """Run the scene to its end; raises SimulationError (with .result) on failure.

    Steps adapt (:class:`Stepper`): ``scene.dt`` is the largest step, a failed attempt
    halves it, easy steps let it grow back; every converged step is a history row
    (column ``dt_s``), and the run ends exactly at ``scene.t_end``.  With
    ``scene.rezone_quality`` > 0, a step after which an element's worst corner quality
    is below it ends the compiled chunk; the mesh is rezoned (:mod:`jaxform.rezone`) and
    the run goes on from there (history column ``rezoned`` = 1 on that step).  With
    ``scene.remesh`` on, such a step (or every ``remesh.every_steps``-th) is followed by a
    new mesh (:mod:`jaxform.remesh`): the run goes on from the transferred state on it,
    a new :class:`Segment` of the result (history column ``remeshed`` = 1 on that step).

    Arguments:
        scene: a scene built by :func:`jaxform.scenes.build_scene`.
        progress: called after each converged step with a dict (step, n_steps estimate,
            chunk_end, time_s, stroke_mm, force_N, iterations, cutbacks, dt_s, and
            remeshed: the nodes of the new mesh after a remesh, else 0, with
            remesh_trigger naming what fired it), or None.
        start: the state to start from (None: the scene's initial state; an operation
            of a process starts from the part the one before it left, :mod:`jaxform.process`).

    A press capacity (``scene.press.capacity_N`` > 0) stops the run after the first step
    whose ram force reaches it: SimulationError ("press capacity ... reached at stroke
    ... mm, step N") with the history up to that step (the final state is the compiled
    chunk's last).  A screw press or hammer scene runs its blows
    (:func:`jaxform.blows.simulate_blows`).

    Returns:
        A :class:`Result`: the history (one row per converged step, row 0 the initial
        state), the fields, the final state and the rezoning and remeshing reports."""
    if scene.press is not None and scene.press.energy_limited:  # a screw press, a hammer
        from jaxform.blows import simulate_blows

        if start is not None:
            raise ValueError("simulate: a screw press or hammer run starts from t = 0")
        return simulate_blows(scene, progress)
    state, control = init(scene)
    if start is not None:
        state = start
    settings = scene.remesh
    capacity = scene.press.capacity_N if scene.press is not None else 0.0
    remeshing = settings is not None and settings.on
    trigger = settings.quality_below if remeshing else scene.rezone_quality
    control = replace(control, rezone_quality=jnp.asarray(trigger))
    if remeshing:
        control = _remesh_triggers(control, settings, stroke=0.0)
    # remeshed runs step a scene padded to a capacity bucket (jaxform.capacity): a new
    # mesh in the same bucket reuses the compiled program
    current, inp = scene, scene.inputs
    padder = padded(scene) if remeshing else None
    stepped = padder.scene if padder else scene
    stepper, programs = stepper_of(stepped), {stepped.model.layout}
    rows, rezones, remeshes, failure = [_initial_row(scene, state)], [], [], None
    segments, since = [Segment(0, scene, padded=padder)], 0
    t_stop = scene.t_end - 1e-9 * scene.dt

    def new_factorization():
        if stepped.newton.method != "modified":
            return None
        return stepped.linear.empty_factorization(stepped.model.layout.n_dofs, state.x.dtype)

    owned = [new_factorization()]
    before = None  # (state, inputs) of the last converged step, before the last remesh
    reporting, host_error = False, None  # host_error: what a host-loop failure chains
    try:
        while float(state.t) < t_stop and failure is None:
            every = settings.every_steps if remeshing else 0
            control = replace(control, pause_steps=jnp.asarray(every - since if every else 0,
                                                               jnp.int32))  # fmt: skip
            fac, owned[0] = owned[0], None  # the chunk frees it when it refactors
            start = padder.state(state) if padder else state
            # a rezoned run steps its rezoned reference (inp); a remeshed one the padded scene
            run_inputs = stepped.inputs if padder else inp
            state_new, control, outs, owned[0] = _chunk(
                stepped, stepper, start, control, run_inputs, fac
            )
            outs = jax.device_get(outs)
            if padder:
                state_new, outs = padder.trim(state_new), padder.trim_outputs(outs)
            first = len(rows)
            for j in range(len(outs["active"])):
                row = {k: v[j] for k, v in outs.items()}
                if not row["active"]:
                    break
                if int(row["code"]) == OK and not _finite(row):
                    row["code"] = NOT_FINITE  # converged to a meaningless (overflowed) state
                if int(row["code"]) != OK:
                    failure = _failure_message(current, inp, state_new, len(rows), row)
                    break
                paused = int(bool(row["paused"]))
                row.update(x=_absolute(current, inp, row["x"]), dt_s=float(row["h_used"]),
                           rezoned=paused * (not remeshing), remeshed=0,
                           new_nodes=0)  # fmt: skip
                rows.append(row)
                if capacity > 0.0 and float(row["force_N"]) >= capacity:  # the press stalls
                    failure = capacity_message(capacity, float(row["stroke_mm"]), len(rows) - 1)
                    break
            since += len(rows) - first
            state = state_new
            pause = bool(outs["paused"][len(rows) - first - 1]) if len(rows) > first else False
            if pause and float(state.t) >= t_stop:
                pause, rows[-1]["rezoned"] = False, 0  # the run ends here: nothing to do
            if pause and failure is None and remeshing:
                try:
                    done = remesh(current, state, settings)
                except RemeshError as err:
                    failure = f"step {len(rows) - 1}: remeshing failed: {err}"
                else:
                    report = replace(done.report, trigger=causes(int(rows[-1]["pause_cause"])))
                    start_pad = time.perf_counter()
                    new_padder = padded(done.scene)
                    # the padding to the bucket is part of the remesh's host time
                    report = replace(
                        report, seconds=report.seconds + time.perf_counter() - start_pad
                    )
                    if owned[0] is not None:
                        jax.block_until_ready(stepped.linear.release(owned[0]))
                        owned[0] = None
                    before = (state, inp)
                    current, state, padder = done.scene, done.state, new_padder
                    stepped = padder.scene
                    segments.append(Segment(len(rows), current, done.transfer, padder))
                    remeshes.append(report)
                    owned[0] = new_factorization()
                    inp, stepper, since = current.inputs, stepper_of(stepped), 0
                    programs.add(stepped.model.layout)
                    rows[-1].update(remeshed=1, new_nodes=report.nodes_after)
                    control = _remesh_triggers(control, settings, rows[-1], report)
            elif pause and failure is None:
                try:
                    state, inp, control, report = _rezone_after(current, state, inp, control)
                except RezoneError as err:
                    failure = f"step {len(rows) - 1}: {err}"
                else:
                    rezones.append(report)
                    rows[-1]["rezoned"] = int(report.improved)
            reporting = True  # an error of the caller's callback is the caller's
            for k in range(first, len(rows) if progress is not None else first):
                progress(_progress(current, k, rows[k], k == len(rows) - 1))
            reporting = False
    except Exception as err:  # a failure of the host loop itself: the last state is kept
        if reporting:
            raise
        failure, host_error = _host_failure(rows[-1], err), err
    finally:
        # the last factorization modified Newton kept is freed here; one a raising chunk
        # held is lost, never freed twice
        if owned[0] is not None:
            jax.block_until_ready(stepped.linear.release(owned[0]))
    if len(segments) > 1 and segments[-1].first_row == len(rows):
        # the first step on the newest mesh failed: the run ends on the mesh before it
        segments.pop()
        remeshes.pop()
        state, inp = before
        rows[-1].update(remeshed=0, new_nodes=0)
        failure = f"the first step after the remesh at {rows[-1]['time_s']:g} s: {failure}"
    fields = _fields(rows, len(segments) == 1)
    history = _history(segments, rows, fields)
    # a remeshed scene may switch Newton method with its size ('auto'), and with it the
    # length of the residual history: shorter ones are padded with inf
    width = max((len(r["hist"]) for r in rows[1:]), default=0)
    hists = np.array([np.pad(np.asarray(r["hist"], float), (0, width - len(r["hist"])),
                             constant_values=np.inf) for r in rows[1:]])  # fmt: skip
    result = Result(history=history, fields=fields, scene=scene, final_state=state,
                    newton_histories=hists, failure=failure, inputs=inp,
                    rezones=rezones, segments=segments, remeshes=remeshes,
                    step_programs=len(programs),
                    laps=laps(history, scene.settings.output.lap_angle_deg))  # fmt: skip
    if failure:
        raise SimulationError(failure, result) from host_error
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


def stepper_of(scene: Scene) -> Stepper:
    """The static part of the scene's compiled steps."""
    rm = scene.remesh
    shape = rm is not None and (rm.corner_depth_ratio > 0.0 or rm.fold_angle_deg > 0.0)
    return Stepper(scene.model, scene.linear, scene.newton, scene.max_cutbacks,
                   scene.dt_growth, scene.symmetric_z, shape)  # fmt: skip


def init(scene: Scene) -> tuple[SimState, StepControl]:
    """The start of a run that the caller steps (:func:`step`).

    Arguments:
        scene: from :func:`jaxform.scenes.build_scene`.

    Returns:
        (state at t = 0, step control): the first step is the largest, ``scene.dt``;
        no rezoning trigger (:func:`step` does not rezone).
    """
    require_x64()
    if scene.press is not None and scene.press.energy_limited:
        raise ValueError(
            f"init: a {scene.press.name} press moves the die with the work done, not with "
            "time; run it with simulate() or jaxform.blows.blow_run"
        )
    zero = jnp.asarray(0.0)
    control = StepControl(h=jnp.asarray(scene.dt), dt_max=jnp.asarray(scene.dt),
                          t_end=jnp.asarray(scene.t_end), rezone_quality=zero,
                          pause_steps=jnp.asarray(0, jnp.int32), pause_stroke_mm=zero,
                          corner_depth_ratio=zero, fold_angle_deg=zero)  # fmt: skip
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
    fac = None
    if scene.newton.method == "modified":  # a factorization of this step alone
        fac = scene.linear.empty_factorization(scene.model.layout.n_dofs, state.x.dtype)
    new, info, fac = _attempt(stepper_of(scene), state, control, inp, scene.idx, fac)
    scene.linear.release_now(fac)
    if int(info["code"]) != OK:
        row = {"cutbacks": info["cutbacks"], "code": info["code"]}
        raise SimulationError(_failure_message(scene, inp, state, None, row), None)
    out = jax.device_get(_outputs(scene.model, new, inp, scene.idx, scene.symmetric_z))
    out.update(dt_s=float(info["h_used"]), iterations=int(info["iterations"]),
               cutbacks=int(info["cutbacks"]))  # fmt: skip
    return new, replace(control, h=info["h_next"]), out
