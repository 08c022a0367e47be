"""A multi-stage process run: the part's state flows from each operation to the next.

    Config --process_config.operations--> (Operation, ...) --run_process--> ProcessResult

Each operation starts from the state the one before it left (:class:`PartState`: the
scene, i.e. the mesh with its sets and reference coordinates, and every state field, the
temperature among the unknowns).  :func:`run_operation` is the seam: a part in, a
:class:`jaxform.simulation.Result` out whose :attr:`~jaxform.simulation.Result.part` the
next operation takes (a forming or heated operation's run starts from its part,
``simulate(scene, progress, start=part)``):

* **forming**: the operation's scene is built on the part's current mesh, the deformed
  positions its reference (:func:`jaxform.scenes.build_scene` with ``mesh``); the state
  comes over through :class:`Carry`, a fixed map (the displacement becomes 0 and F = I as
  after a remesh; stress, deformation resistance, equivalent plastic strain, temperature,
  friction work and heat carry over; the contact multipliers, slip and status start
  afresh against the new dies).  The dies must clear the part; the stroke (die.reduction
  of the initial height, travel_mm or final_gap_mm) becomes the reduction of the
  incoming part's height;
* **dwell** / **reheat** (furnace): with coupled heat, a scene on the part's mesh whose
  top die stands clear above it, the air (or the furnace) at the operation's temperature,
  convection and radiation on the free surface; without heat a dwell only advances the
  clock.  A reheat to a set temperature sets every node's temperature;
* **trim**: the part's section is cut at the radius (:func:`trimmed_polygon`), the kept
  polygon meshed anew (gmsh, all quads) and the state carried by a
  :class:`jaxform.remesh.StateMap` (the same fixed map a remesh uses, so a gradient run
  can follow it); the trimmed volume is reported.

Every operation's run is a :class:`jaxform.simulation.Result` on local time (each starts
at 0 s); :class:`ProcessResult` joins them into one history with the columns
``operation`` (1-based) and ``time_s`` over the process (``stroke_mm`` stays per
operation).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import jax
import jax.numpy as jnp
import numpy as np

from jaxform.config import TRIGGERS, Config
from jaxform.dies import make_die
from jaxform.errors import ConfigError
from jaxform.geometry import polygon_measure
from jaxform.mesh import Mesh, MeshError, boundary_polygon, element_areas
from jaxform.process_config import Operation
from jaxform.remesh import ContactMap, StateMap
from jaxform.scenes import Scene, bottom_die_profile, build_scene, die_profile, scene_on_mesh
from jaxform.section_mesh import quads_of, simplify, untangled
from jaxform.simulation import PartState, Result, SimulationError, simulate, state_result
from jaxform.transfer import Transfer
from jaxform.workpieces import workpiece_of

# a dwell's top die stands this fraction of the part's height above its top
CLEAR_FRACTION = 0.5
# in air a step whose element corner quality falls by more is cut back (solver.max_quality_drop,
# a tighter one configured kept): a converged step in air only springs back and cools, its
# corners' quality moves by ~1e-4; a root with a corner rolled over fell by 0.19 in one step
AIR_QUALITY_DROP = 0.05


@dataclass(frozen=True, eq=False)
class Carry:
    """The state of a part from one operation's scene to the next one's on the same mesh,
    a fixed map (NumPy or traced JAX values, ``xp``): the deformed positions become the
    reference (u = 0, F = I); the other nodal fields (pressure, temperature), the Gauss
    fields, friction work and heat carry over; the multipliers, predictor rates, slip and
    contact status start at 0 (new dies), and the clock at 0 (each operation's own)."""

    old: object  # Layout
    new: object  # Layout

    def apply(self, state, coords, xp=np):
        old, new = self.old, self.new
        nodal = old.nodal(state.x)
        pos = coords + nodal[:, :2]
        rest = nodal[:, 2:]
        cat = xp.concatenate
        x = cat([cat([xp.zeros((new.n_nodes, 2)), rest], axis=1).ravel(), xp.zeros(new.n_mult)])
        eye = xp.broadcast_to(xp.eye(3), (new.n_elements, 4, 3, 3))
        return replace(
            state,
            x=x,
            t=xp.zeros_like(state.t),
            gauss=replace(state.gauss, F=eye),
            x_rate=xp.zeros(new.n_dofs),
            slip_mm=xp.zeros(new.n_contact),
            contact_status=xp.zeros(new.n_contact, dtype=state.contact_status.dtype),
        ), pos


class OperationRefused(ConfigError):
    """An operation refused when the part reached it (its dies overlap the part, its
    stroke or trim does not fit it): ``result`` holds the operations done before it."""

    def __init__(self, message: str, result):
        super().__init__(message)
        self.result = result


@dataclass
class OperationRun:
    """One operation's run: the operation, its result (local time), the process time it
    started at, the map that brought the part in (Carry, StateMap; None for the first)
    and, for a trim, the volume removed (mm^3; plane strain mm^2)."""

    operation: Operation
    result: Result
    start_s: float
    transfer: object = None
    trimmed_volume: float = 0.0


@dataclass
class ProcessResult:
    """The process: each operation's run and their joined history (``operation``
    column, ``time_s`` over the process) and fields (a list per field, one array per
    row on its row's mesh, :meth:`scene_at`)."""

    runs: list[OperationRun]
    history: dict
    fields: dict
    failure: str | None = None
    rows: list = field(default_factory=list)  # (run index, local row) of each row

    def scene_at(self, row: int):
        k, local = self.rows[row % len(self.rows)]
        return self.runs[k].result.scene_at(local)

    @property
    def scene(self) -> Scene:
        return self.runs[0].result.scene

    @property
    def final_scene(self) -> Scene:
        return self.runs[-1].result.final_scene

    @property
    def final_state(self):
        return self.runs[-1].result.final_state

    @property
    def remeshes(self) -> list:
        return [r for run in self.runs for r in run.result.remeshes]

    @property
    def laps(self) -> list:
        """Each operation's laps (to its end), with the operation's name (``operation``)."""
        return [{**lap, "operation": r.operation.name} for r in self.runs for lap in r.result.laps]

    @property
    def pockets(self) -> list:
        """Each operation's pockets (to its end), with the operation's name: a blocker
        leaves air along its die that the finisher then fills."""
        return [{**p, "operation": r.operation.name} for r in self.runs for p in r.result.pockets]


def positions_of(part: PartState) -> np.ndarray:
    """The part's nodal positions (mm)."""
    lay = part.scene.model.layout
    return np.asarray(part.scene.inputs.coords) + lay.nodal(np.asarray(part.state.x))[:, :2]


def _heights(mesh: Mesh, full: bool) -> tuple[float, float]:
    """(top z, bottom z) of a mesh (bottom 0: a half-height model's mid-plane)."""
    top = float(mesh.coords[mesh.node_sets["top"], 1].max())
    bottom = float(mesh.coords[mesh.node_sets["bottom"], 1].min()) if full else 0.0
    return top, bottom


def closure_mm(op: Operation, mesh: Mesh, initial: Mesh) -> float:
    """How far the dies of a forming operation close (mm; half height: the top die's
    travel) from its stroke: die.reduction of the initial part's height, travel_mm, or
    final_gap_mm (the gap between the top die's lowest and the bottom die's highest point,
    half height: twice the top die's lowest point above the mid-plane)."""
    cfg = op.config
    full = cfg.bottom_die is not None and not _half(cfg)
    keys = op.keys
    if keys.travel_mm is not None:
        return keys.travel_mm
    if keys.final_gap_mm is None:
        top0, bottom0 = _heights(initial, full)
        return cfg.die.reduction * (top0 - bottom0)
    top, bottom = _heights(mesh, full)
    lowest = float(die_profile(cfg.die, top)[:, 1].min())
    if not full:
        return lowest - 0.5 * keys.final_gap_mm
    profile = die_profile(cfg.die, top)
    highest = float(bottom_die_profile(cfg, profile, bottom)[:, 1].max())
    return lowest - highest - keys.final_gap_mm


def _half(cfg: Config) -> bool:
    piece = cfg.billet if cfg.billet is not None else cfg.ring
    return piece is None or not piece.full_height


def forming_scene(op: Operation, mesh: Mesh, initial: Mesh) -> Scene:
    """The forming operation's scene on the part's mesh ``mesh`` (the deformed positions
    its reference); ConfigError naming the operation if its stroke does not fit the part
    or its dies overlap it."""
    cfg = op.config
    full = cfg.bottom_die is not None and not _half(cfg)
    top, bottom = _heights(mesh, full)
    closure = closure_mm(op, mesh, initial)
    reduction = closure / (top - bottom)
    if mesh is initial and op.keys.travel_mm is None and op.keys.final_gap_mm is None:
        reduction = cfg.die.reduction  # the config's own number, not a rounded quotient
    if not 0.0 < reduction < 1.0:
        raise ConfigError(
            f"{op.label}: the stroke closes the dies by {closure:.6g} mm, the incoming part "
            f"is {top - bottom:.6g} mm high: the dies must close by more than 0 and less "
            "than its height"
        )
    cfg = replace(cfg, die=replace(cfg.die, reduction=reduction))
    try:  # the first blow on the workpiece's own mesh (a structured one may rezone)
        return build_scene(cfg, None if mesh is initial else mesh)
    except ConfigError as err:
        raise ConfigError(f"{op.label}: {err} (the incoming part)") from None


def _carried(part: PartState, make_scene) -> tuple[PartState, Carry]:
    """(the part on the new scene, map): the part's deformed mesh as the new scene's
    reference (``make_scene(mesh)``), the state through :class:`Carry`."""
    scene = part.scene
    pos = positions_of(part)
    mesh = replace(scene.mesh, coords=pos)
    new_scene = make_scene(mesh)
    carry = Carry(scene.model.layout, new_scene.model.layout)
    host = jax.tree_util.tree_map(np.asarray, part.state)
    state, _ = carry.apply(host, np.asarray(scene.inputs.coords))
    # die wear is the new operation's dies' own: it starts at 0 at their stations
    wear = new_scene.inputs.wear
    state = replace(state, wear_mm=np.zeros((0, 0) if wear is None else wear.stations.shape[:2]))
    return PartState(new_scene, jax.tree_util.tree_map(jnp.asarray, state)), carry


def _air_config(op: Operation) -> Config:
    """The config of a dwell or a furnace reheat: the air (or furnace) temperature,
    convection and radiation of the operation, a flat top die (placed clear of the part
    by :func:`air_scene`), no remeshing.

    Its first step does not probe (``time.first_step_probe = 0``): a probe's change,
    extrapolated, suits a die starting to move, but the first step in air is a jump (the
    spring-back of the load the dies held, the die-chilled surface warming from inside),
    and from four times the probe's change Newton can fail and its cutback come to a root
    with a corner rolled over, which then flows on in air (docs/processes.md).  A step
    that lowers a corner's quality by more than :data:`AIR_QUALITY_DROP` is cut back
    (``solver.max_quality_drop``): such a root is not the part's in air."""
    cfg, k = op.config, op.keys
    th = cfg.thermal
    if not hasattr(k, "furnace_temperature_K"):  # a dwell
        air = dict(air_temperature_K=k.air_temperature_K, htc_air_W_m2K=k.htc_air_W_m2K,
                   emissivity=k.emissivity)  # fmt: skip
    else:
        air = dict(air_temperature_K=k.furnace_temperature_K, htc_air_W_m2K=k.htc_W_m2K,
                   emissivity=k.emissivity)  # fmt: skip
    air = {name: v for name, v in air.items() if v is not None}
    off = {t: 0 if t == "every_steps" else 0.0 for t in TRIGGERS}
    drop = min(AIR_QUALITY_DROP, cfg.solver.max_quality_drop or AIR_QUALITY_DROP)
    return replace(
        cfg,
        thermal=replace(th, **air),
        die=replace(
            cfg.die,
            profile_mm=(),
            closed=False,
            part_radius_mm=0.0,
            reduction=0.5,
            corner_contact=False,
        ),  # fmt: skip
        time=replace(cfg.time, dt_s=k.dt_s or cfg.time.dt_s, first_step_probe=0.0),
        remesh=replace(cfg.remesh, **off),
        solver=replace(cfg.solver, max_quality_drop=drop),
    )


def air_scene(op: Operation, mesh: Mesh) -> Scene:
    """A dwell's or a furnace's scene on the part's mesh: the top die stands
    :data:`CLEAR_FRACTION` of the part's height above it for the operation's time."""
    scene = build_scene(_air_config(op), mesh)
    top = float(mesh.coords[:, 1].max())
    z = top + CLEAR_FRACTION * float(np.ptp(mesh.coords[:, 1]))
    t_end = op.keys.time_s
    # the scene's friction law kept (never in contact): the forming steps' program serves
    friction = scene.inputs.die.members[0].friction
    die = make_die([[0.0, z], [1.0, z]], [0.0, t_end], [0.0, 0.0], friction, corner_radius=0.2)
    return replace(scene, inputs=replace(scene.inputs, die=die), t_end=t_end)


def _mean_size(mesh: Mesh) -> float:
    return float(np.sqrt(np.mean(np.abs(element_areas(mesh.coords, mesh.elements)))))


def trimmed_polygon(points: np.ndarray, labels: list[str], radius: float):
    """The part of the closed counter-clockwise polygon with r <= radius: (points,
    labels), the cut edges labelled ``side`` (a free surface).  Raises ValueError when
    nothing or more than one piece is kept."""
    inside = points[:, 0] <= radius
    nxt = np.roll(np.arange(len(points)), -1)
    out, out_labels = [], []
    for i, j in zip(range(len(points)), nxt):
        p, q = points[i], points[j]
        if inside[i]:
            out.append(p)
            out_labels.append(labels[i])
        if inside[i] != inside[j]:
            s = (radius - p[0]) / (q[0] - p[0])
            out.append(np.array([radius, p[1] + s * (q[1] - p[1])]))
            out_labels.append("side" if inside[i] else labels[i])
    if not out:
        raise ValueError("nothing is left")
    if int(np.count_nonzero(inside != inside[nxt])) > 2:
        raise ValueError("the cut leaves more than one piece")
    pts = np.asarray(out)
    keep = np.linalg.norm(pts - np.roll(pts, 1, axis=0), axis=1) > 1e-12 * max(radius, 1.0)
    pts, out_labels = pts[keep], [lab for lab, k in zip(out_labels, keep) if k]
    return pts, out_labels


def trim_part(part: PartState, op: Operation):
    """(new scene, state, StateMap, trimmed volume of the part, mm^3; plane strain mm^2
    per mm, both halves of a half-height model): the part cut at ``radius_mm``, the kept
    section meshed anew, the state carried (contact starts afresh)."""
    scene = part.scene
    pos = positions_of(part)
    axi = scene.model.formulation.axisymmetric
    radius = op.keys.radius_mm
    points, labels, _ = boundary_polygon(scene.mesh, pos)
    if radius >= points[:, 0].max():
        raise ConfigError(
            f"{op.label}: radius_mm = {radius:g}: the part reaches only r = "
            f"{points[:, 0].max():.6g} mm, nothing to trim"
        )
    try:
        kept, kept_labels = trimmed_polygon(points, labels, radius)
    except ValueError as err:
        raise ConfigError(f"{op.label}: radius_mm = {radius:g}: {err}") from None
    size = op.keys.element_size_mm or _mean_size(scene.mesh)
    idx, kept_labels = simplify(kept, kept_labels, 1e-9 * size)
    kept, kept_labels, _ = untangled(kept[idx], kept_labels)  # a fold pressed over: gmsh hangs
    try:  # gmsh's fallbacks as for a remesh (finer sizes, then split into quads)
        mesh, _ = quads_of(kept, kept_labels, np.full(len(kept), size))
    except MeshError as err:
        raise ConfigError(f"{op.label}: the kept part could not be meshed: {err}") from None
    new_scene = scene_on_mesh(scene, mesh)
    move = Transfer(pos, np.asarray(scene.mesh.elements), mesh.coords, mesh.elements)
    n_c = new_scene.model.layout.n_contact
    zero = np.zeros((n_c, 2))
    contact = ContactMap(np.zeros((n_c, 2), np.int64), zero, zero, np.zeros(n_c, np.int32))
    transfer = StateMap(scene.model.layout, new_scene.model.layout, move,
                        mesh.coords - move.nodal(pos), contact)  # fmt: skip
    host = jax.tree_util.tree_map(np.asarray, part.state)
    state, _ = transfer.apply(host, np.asarray(scene.inputs.coords))
    state = replace(state, t=np.zeros_like(host.t))
    before = float(np.sum(polygon_measure(pos[np.asarray(scene.mesh.elements)], axi)))
    after = float(polygon_measure(kept, axi))
    state = jax.tree_util.tree_map(jnp.asarray, state)
    halves = 2.0 if scene.symmetric_z else 1.0  # the part's, both halves of a half model
    return new_scene, state, transfer, halves * (before - after)


def _set_temperature(part: PartState, op: Operation):
    """The state with every node at ``set_temperature_K``."""
    lay = part.scene.model.layout
    x = np.array(part.state.x)
    t0 = float(part.scene.inputs.thermal.billet_temperature_K)
    lay.nodal(x)[:, lay.temperature_column] = op.keys.set_temperature_K - t0
    return replace(part.state, x=jnp.asarray(x), t=jnp.zeros_like(part.state.t))


def _clock(state, t: float):
    return replace(state, t=jnp.asarray(t, dtype=jnp.asarray(state.t).dtype))


def _forming(op: Operation, part: PartState | None, initial: Mesh, progress, simulate_fn):
    if part is None:  # the first blow, on the workpiece's own mesh
        scene = forming_scene(op, initial, initial)
        return simulate_fn(scene, progress), None, 0.0
    carried, carry = _carried(part, lambda m: forming_scene(op, m, initial))
    return simulate_fn(carried.scene, progress, carried), carry, 0.0


def _in_air(op: Operation, part: PartState, initial: Mesh, progress, simulate_fn):
    """A dwell, or a reheat in a furnace (or to a set temperature)."""
    if getattr(op.keys, "set_temperature_K", None) is not None:
        return state_result(part.scene, _set_temperature(part, op)), None, 0.0
    carried, carry = _carried(part, lambda m: air_scene(op, m))
    if op.config.thermal.model != "coupled":  # the dies are off, the clock moves on
        return state_result(carried.scene, _clock(carried.state, op.keys.time_s)), carry, 0.0
    return simulate_fn(carried.scene, progress, carried), carry, 0.0


def _trim(op: Operation, part: PartState, initial: Mesh, progress, simulate_fn):
    """The trim's one row: the dies where the blow before it left them (its die fill and
    flash columns refer to them), at the operation's time 0."""
    scene, state, transfer, removed = trim_part(part, op)
    result = state_result(scene, replace(state, t=part.state.t))
    result.history["time_s"] = np.zeros(1)
    result.final_state = state
    return result, transfer, removed


# how each kind of operation runs: (operation, part, initial mesh, progress, host loop) ->
# (its Result, the map that brought the part in, the trimmed volume)
RUNNERS = {"forming": _forming, "dwell": _in_air, "reheat": _in_air, "trim": _trim}


def run_operation(op: Operation, part: PartState | None, initial: Mesh, progress, simulate_fn):
    """One operation from the part ``part`` (None: the first forming operation, on the
    workpiece's own mesh): (its Result, whose ``part`` is the part it leaves; the map that
    brought the part in; the trimmed volume).  Raises ConfigError, SimulationError (with
    the operation's result)."""
    return RUNNERS[op.kind](op, part, initial, progress, simulate_fn)


def prepare(ops) -> Mesh:
    """The workpiece's initial mesh, the process checked against it
    (:func:`check_process`): nothing compiled yet."""
    initial = workpiece_of(ops[0].config).build_mesh()
    check_process(ops, initial)
    return initial


def _joined(runs: list[OperationRun]) -> tuple[dict, dict, list]:
    """(history, fields, (run, local row) of each row) over the process: each run's rows
    after the first run without its row 0 (the part as the run before left it, at the
    same time) unless the run is that one row (a trim, a set temperature, a dwell
    without heat); ``time_s`` over the process, ``operation`` the 1-based index, columns
    an operation lacks NaN."""
    picks = []
    for k, run in enumerate(runs):
        n = len(run.result.history["time_s"])
        first = 0 if k == 0 or n == 1 else 1
        picks += [(k, j) for j in range(first, n)]
    names: list[str] = []
    for run in runs:
        names += [c for c in run.result.history if c not in names]
    history = {"operation": np.array([runs[k].operation.index for k, _ in picks], float)}
    for c in names:
        history[c] = np.array([
            float(runs[k].result.history[c][j]) if c in runs[k].result.history else math.nan
            for k, j in picks
        ])  # fmt: skip
    history["time_s"] = history["time_s"] + np.array([runs[k].start_s for k, _ in picks])
    fields = {
        name: [np.asarray(runs[k].result.fields[name][j]) for k, j in picks]
        for name in runs[0].result.fields
    }
    return history, fields, picks


def _result(runs: list[OperationRun], failure: str | None = None) -> ProcessResult:
    history, fields, picks = _joined(runs)
    return ProcessResult(runs, history, fields, failure, picks)


def run_process(ops, initial: Mesh, progress=None, simulate_fn=simulate) -> ProcessResult:
    """Run the operations in order, each from the part the one before it left.

    Arguments:
        ops: from :func:`jaxform.process_config.operations` (checked with
            :func:`check_process`).
        initial: the workpiece's initial mesh.
        progress: the progress callback of each operation's run
            (:func:`jaxform.simulation.simulate`).
        simulate_fn: the host loop (a test may stand in for it).

    Raises:
        SimulationError: an operation's step failed; ``result`` is the
            :class:`ProcessResult` up to its last converged step (the message names the
            operation).  ConfigError: the first operation's set-up; OperationRefused (a
            ConfigError with the ``result`` of the operations before it): a later
            operation's dies overlap the incoming part, or its stroke or trim does not
            fit it (found when the part reaches it)."""
    runs: list[OperationRun] = []
    part, clock = None, 0.0
    for op in ops:
        if part is None and not op.forming:
            continue  # before the first blow the billet waits, cools or is trimmed: refused
        try:
            result, transfer, removed = run_operation(op, part, initial, progress, simulate_fn)
        except ConfigError as err:
            if not runs:
                raise
            raise OperationRefused(str(err), _result(runs, str(err))) from None
        except SimulationError as err:
            if err.result is not None:
                runs.append(OperationRun(op, err.result, clock))
            message = f"{op.label}: {err}"
            raise SimulationError(message, _result(runs, message) if runs else None) from None
        runs.append(OperationRun(op, result, clock, transfer, removed))
        clock += float(result.history["time_s"][-1])
        part = result.part
    return _result(runs)


def _top_end(op: Operation, initial: Mesh):
    """The top die's profile (mm) at the end of a forming operation, where it is known
    before the run (an explicit profile and a stroke that does not depend on the incoming
    part), else None."""
    d = op.config.die
    if not d.profile_mm:
        return None
    full = op.config.bottom_die is not None and not _half(op.config)
    top, _ = _heights(initial, full)
    profile = die_profile(d, top)
    closure = closure_mm(op, initial, initial)
    share = 1.0 - op.config.bottom_die.speed_share if full else 1.0
    return profile - np.array([0.0, share * closure])


def check_process(ops, initial: Mesh) -> None:
    """What can be refused before anything compiles: a process whose first operation is
    not a forming one; a forming operation whose top die, at its start, reaches below
    where the forming operation before it left its top die (within the initial part's
    radius, where the material is: the die would overlap the incoming part); a trim
    radius inside a ring's bore or beyond the initial part with no forming before it.
    Raises ConfigError naming the operation and key."""
    if not ops[0].forming:
        raise ConfigError(
            f"{ops[0].label}: kind = {ops[0].kind!r}: a process starts with a forming operation"
        )
    r_max = float(initial.coords[:, 0].max())
    r_min = float(initial.coords[:, 0].min())
    before = None
    for op in ops:
        radius = getattr(op.keys, "radius_mm", None)
        if radius is not None and radius <= r_min:
            raise ConfigError(
                f"{op.label}: radius_mm = {radius:g}: the part starts at r = "
                f"{r_min:.6g} mm (its bore): the trim would remove the whole part"
            )
        heated = op.config.thermal.model == "coupled" and getattr(op.keys, "time_s", None)
        if heated and not _half(op.config):
            raise ConfigError(
                f"{op.label}: time_s in air or a furnace with coupled heat needs a half-height "
                "part (a full-height one has no support off the dies yet)"
            )
        if not op.forming:
            continue
        if before is not None and op.config.die.profile_mm:
            full = op.config.bottom_die is not None and not _half(op.config)
            start = die_profile(op.config.die, _heights(initial, full)[0])
            r = np.linspace(0.0, r_max, 201)
            z_start = np.interp(r, start[:, 0], start[:, 1])
            below = z_start < np.interp(r, before[:, 0], before[:, 1]) - 1e-9
            if below.any():
                r0 = float(r[np.argmax(below)])
                raise ConfigError(
                    f"{op.label}: die.profile_mm reaches below the top die of the forming "
                    f"operation before it at its end (r = {r0:.4g} mm, inside the initial "
                    "part's radius): the die would overlap the incoming part"
                )
        before = _top_end(op, initial)  # None: where the part's top ends is not known yet
