"""Scene set-up from a config: workpiece mesh, boundary sets, material, die or load, solver.

    config file --load_config--> document --typed--> Config --build_scene--> Scene

:func:`build_scene` is where a scene's pieces are made: the workpiece
(:mod:`jaxform.workpieces`) builds the section mesh and names its sets, the sets give the
Dirichlet conditions and the die's contact candidates, the material preset gives the law
and its parameters, and the die (``die.profile_mm``, or a flat die on the top face) moves
along the path table or at half the ram speed (the mid-plane is fixed, so the top die
travels half the stroke; a block's die all of it).  The run ends when the ram stroke
reaches ``die.reduction`` x the workpiece height.  :class:`Inputs` holds everything a
design may differentiate; :class:`Scene` the rest, static.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import jax
import jax.numpy as jnp
import numpy as np

from jaxform import mesh as meshing
from jaxform.assembly import Indices, Model, build_indices
from jaxform.config import Config, DieConfig, FrictionConfig, RemeshConfig, typed
from jaxform.config.stroke import closing_time
from jaxform.contact import (
    Candidates,
    ContactLaw,
    Coulomb,
    EachDie,
    FrictionLaw,
    Frictionless,
    NearestDie,
    Shear,
    Sticking,
)
from jaxform.dies import (
    DieError,
    DieSet,
    RigidDie,
    catmull_rom,
    check_clearance_of_facets,
    check_profile,
    has_convex_corner,
    make_die,
)
from jaxform.errors import ConfigError
from jaxform.formulations import formulation
from jaxform.heat import ThermalInputs, exposed_edges
from jaxform.linear import LinearSolver, choose_backend
from jaxform.loads import FacetLoad
from jaxform.materials import load_material
from jaxform.precision import require_x64
from jaxform.presses import (
    J_TO_NMM,
    CrankMotion,
    CrankPress,
    EnergyPress,
    SpeedPress,
    crank_start_angle,
)
from jaxform.rezone import gap_function
from jaxform.section_mesh import quads_of, sized_polygon
from jaxform.solver import NewtonSettings, newton_variant
from jaxform.wear import WearInputs, die_stations
from jaxform.workpieces import Workpiece, workpiece_of

# Dirichlet conditions by node set: the displacement components held at 0
FIXED_COMPONENTS = {"symmetry": (1,), "axis": (0,), "base": (1,), "clamped": (0, 1)}
# u_y dofs of this set carry the support reaction (for checks)
REACTION_SETS = ("symmetry", "base", "clamped")


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class Inputs:
    """Everything a design may differentiate, passed to the compiled step as arguments."""

    coords: jax.Array  # initial nodal coordinates (mm)
    params: object  # material parameters
    die: RigidDie | DieSet | None  # profiles, paths, friction coefficients (None: no die)
    c_contact: jax.Array  # complementarity scale (N/mm), set-up constant
    load: FacetLoad | None = None  # traction load on idx.load_facets (None: no load)
    thermal: ThermalInputs | None = None  # temperatures, conductances (None: isothermal)
    wear: WearInputs | None = None  # Archard's law and die stations (None: no wear)


@dataclass(frozen=True)
class Scene:
    """A set-up scene (built by :func:`build_scene`): the caller runs it.

    ``settings`` is the typed config the scene came from, ``workpiece`` what its workpiece
    section knows (mesh, sets, stroke, extra history); the other fields are what the
    compiled steps take."""

    settings: Config
    workpiece: Workpiece
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
    chunk_output_mb: float = 64.0  # the most a chunk's output fields take (chunks.chunk_steps)
    symmetric_z: bool = True  # half-height model: stroke = 2 x die travel
    rezone_quality: float = 0.0  # rezone when the worst corner quality drops below (0: never)
    grid: tuple[int, int] | None = None  # (nr, nz) of a structured mesh (rezoning needs it)
    adjoint_memory_mb: float = 0.0  # forward factorizations a gradient run may keep (MB)
    dt_growth: float = 1.5  # an easy step lets the next one grow by this factor (to dt)
    # a Newton solve at the smallest step goes on from its last iterate this many times
    continuations: int = 0
    # a converged step whose element corner quality falls by more is cut back (0: no limit)
    max_quality_drop: float = 0.0
    # a step from rest first solves this fraction of itself for its predictor (0: never)
    first_step_probe: float = 0.0
    # when and how to remesh (element_size_mm resolved); None: never
    remesh: RemeshConfig | None = None
    # the machine that drives the top die (jaxform.presses); None: no die (a membrane)
    press: object = None

    @property
    def remeshes(self) -> bool:
        """Whether the run may go on new meshes (``[remesh]`` on)."""
        return _remeshes(self.remesh)

    @property
    def n_steps(self) -> int:
        """Steps to the end at the largest step."""
        return int(math.ceil(self.t_end / self.dt - 1e-9))

    def step_targets(self) -> np.ndarray:
        """End times of the steps at the largest step (the last one ends at t_end)."""
        k = np.arange(1, self.n_steps + 1)
        return np.minimum(k * self.dt, self.t_end)

    def full_newton(self) -> Scene:
        """This scene solved by full Newton, a new Jacobian every iteration, on its new
        meshes too (``solver.newton = 'newton'``): as a differentiable replay solves each
        step (:meth:`jaxform.solver.NewtonSettings.exact`).  The forward run that fixes a
        replay's steps runs it, so that every step it converged converges in the replay
        from the same start (modified Newton may take a step at a size where full Newton
        needs a cutback), and with no probe of a step from rest
        (``time.first_step_probe = 0``): a replay starts each step from the last one's
        rate alone, and a first step that converges only after a probe would fail there."""
        solver = replace(self.settings.solver, newton="newton")
        timing = replace(self.settings.time, first_step_probe=0.0)
        settings = replace(self.settings, solver=solver, time=timing)
        return replace(self, settings=settings, newton=self.newton.exact(), first_step_probe=0.0)


def _profile_points(points, kind: str, key: str, workpiece_below: bool = True) -> np.ndarray:
    """Checked profile points (mm): the polyline, or the sampled Catmull-Rom spline."""
    try:
        pts = check_profile(np.asarray(points), key, workpiece_below)
        if kind != "polyline":  # a spline through the points, sampled
            pts = check_profile(catmull_rom(pts), f"{key} (sampled spline)", workpiece_below)
    except DieError as err:
        raise ConfigError(str(err)) from err
    return pts


def die_profile(d: DieConfig, top_z: float) -> np.ndarray:
    """The die's profile points (mm): the configured polyline or sampled spline, or a flat
    die on the top face (extended both ways)."""
    if not d.profile_mm:
        return np.array([[0.0, top_z], [1.0, top_z]])
    pts = _profile_points(d.profile_mm, d.profile_kind, "die.profile_mm")
    if d.closed and abs(pts[0, 0]) > 1e-9:
        raise ConfigError(
            f"die.closed = true: die.profile_mm must start on the axis (r = 0), "
            f"got r = {pts[0, 0]:g} mm"
        )
    return pts


_MIRROR = np.array([1.0, -1.0])


def bottom_die_profile(cfg: Config, top_profile: np.ndarray, bottom_z: float) -> np.ndarray:
    """The bottom die's profile points (mm), walked with the workpiece (above it) on the
    right, i.e. from the outside towards the axis: the top die's mirrored about z = 0
    (``bottom_die.mirror``), the configured points (given from the axis outward), or a
    flat die on the bottom face."""
    b = cfg.bottom_die
    if b.mirror:
        return (top_profile * _MIRROR)[::-1]
    if not b.profile_mm:
        return np.array([[1.0, bottom_z], [0.0, bottom_z]])
    # checked as the mirror image, a top die (the workpiece on its right when walked outward)
    mirrored = _profile_points(np.asarray(b.profile_mm) * _MIRROR, b.profile_kind,
                               "bottom_die.profile_mm")  # fmt: skip
    return (mirrored * _MIRROR)[::-1]


def _check_clearance(profile: np.ndarray, mesh: meshing.Mesh, sets, key: str) -> None:
    """ConfigError if the die overlaps the workpiece at t = 0: a point of a candidate or
    axis facet (9 points per facet) lies inside the die."""
    facets = [mesh.facet_sets[s] for s in (*sets, "axis") if s in mesh.facet_sets]
    if not facets:
        return
    try:
        check_clearance_of_facets(profile, mesh.coords, np.concatenate(facets), key)
    except DieError as err:
        raise ConfigError(str(err)) from None


def die_path(d: DieConfig, target_mm: float, speed_factor: float):
    """(times, travel of the top die, end time) for a die travel of ``target_mm``; the die
    moves along the path table, or at ``speed_factor`` x the ram speed (half-height
    models: the top die travels half the ram stroke at half the ram speed).  The end
    time is :func:`jaxform.config.stroke.closing_time`, as the config's step count."""
    t_end = closing_time(d, None, target_mm, speed_factor)
    if d.path_time_s:
        return np.asarray(d.path_time_s), np.asarray(d.path_travel_mm), t_end
    v = speed_factor * d.speed_mm_s
    return np.array([0.0, t_end]), np.array([0.0, v * t_end]), t_end


def membrane_load(cfg: Config, mesh: meshing.Mesh) -> FacetLoad:
    """The traction (per unit initial edge length) whose resultant is load.force_*_N."""
    ld = cfg.load
    facets = mesh.facet_sets["loaded"]
    length = float(
        np.sum(np.linalg.norm(mesh.coords[facets[:, 1]] - mesh.coords[facets[:, 0]], axis=1))
    )
    traction = np.array([ld.force_x_N, ld.force_y_N]) / length
    return FacetLoad(traction=jnp.asarray(traction), ramp_end_s=jnp.asarray(ld.ramp_time_s))


def _indices(mesh: meshing.Mesh, n_fields: int, contact_sets: tuple[str, ...], corner: bool,
             temperature: bool = False, copies: int = 1):  # fmt: skip
    """(Layout, Indices) of the mesh: Dirichlet dofs from the named sets
    (:data:`FIXED_COMPONENTS`), the reaction dofs, the contact candidates and facets (with
    a corner-contact multiplier each where ``corner``), each contact node ``copies`` times
    (once per die where candidates are (node, die) pairs, :class:`EachDie`); with
    ``temperature`` one more nodal field (the last) and the edges that exchange heat.  No
    sparsity pattern yet: the model's terms give it
    (:meth:`jaxform.assembly.Model.with_pattern`)."""
    sets = mesh.node_sets
    n_fields = n_fields + temperature  # the temperature is the last nodal field
    fixed = [sets[s] * n_fields + k for s, comps in FIXED_COMPONENTS.items() if s in sets
             for k in comps]  # fmt: skip
    reaction = next((sets[s] * n_fields + 1 for s in REACTION_SETS if s in sets),
                    np.zeros(0, np.int64))  # fmt: skip
    if contact_sets:
        contact = np.unique(np.concatenate([sets[s] for s in contact_sets])).astype(np.int64)
        facets = np.concatenate([mesh.facet_sets[s] for s in contact_sets if s in mesh.facet_sets])
    else:
        contact, facets = np.zeros(0, dtype=np.int64), np.zeros((0, 2), dtype=np.int64)
    loaded = mesh.facet_sets.get("loaded")
    layout, idx = build_indices(mesh, n_fields, np.concatenate(fixed),
                                Candidates.paired(contact, facets, copies),
                                reaction_dofs=reaction, load_facets=loaded,
                                corner_contact=corner and len(facets) > 0)  # fmt: skip
    if temperature:  # the last nodal field (no Dirichlet rows) and the edges exchanging heat
        layout = replace(layout, temperature=True)
        edges = exposed_edges(mesh.elements, mesh.facet_sets)
        idx = replace(idx, exposed_edges=jnp.asarray(edges))
    return layout, idx


def thermal_inputs(cfg: Config) -> ThermalInputs | None:
    """The thermal inputs of a coupled run (None for thermal.model = 'none'): the
    [thermal] section and the material's thermal properties, units as in the keys."""
    th, mat = cfg.thermal, cfg.material
    if th.model == "none":
        return None
    values = dict(
        billet_temperature_K=th.billet_temperature_K,
        die_temperature_K=th.die_temperature_K,
        air_temperature_K=th.air_temperature_K,
        htc_die_W_m2K=th.htc_die_W_m2K,
        htc_air_W_m2K=th.htc_air_W_m2K,
        emissivity=th.emissivity,
        taylor_quinney=th.taylor_quinney,
        density_kg_m3=mat.density_kg_m3,
        specific_heat_J_kgK=mat.specific_heat_J_kgK,
        conductivity_W_mK=mat.conductivity_W_mK,
        dwell_s=th.dwell_s,
    )
    path = (th.die_path_time_s, th.die_path_change_K) if th.die_path_time_s else ((0.0,), (0.0,))
    return ThermalInputs(
        **{k: jnp.asarray(float(v)) for k, v in values.items()},
        die_path_time_s=jnp.asarray(path[0], dtype=float),
        die_path_change_K=jnp.asarray(path[1], dtype=float),
    )


def _contact_scale(mesh: meshing.Mesh, shear_modulus: float, axisymmetric: bool) -> float:
    """The complementarity scale (N/mm): G x the smallest element size x the
    circumference at the outer radius (axisymmetric)."""
    areas = meshing.element_areas(mesh.coords, mesh.elements)
    if np.any(areas <= 0):
        raise ConfigError(
            "mesh: an element has non-positive area (check mesh.file or the billet profile)"
        )
    h = float(np.sqrt(areas.min()))
    r_out = float(mesh.coords[:, 0].max())
    return shear_modulus * h * (2.0 * np.pi * r_out if axisymmetric else 1.0)


def _die_or_load(cfg: Config, piece: Workpiece, mesh: meshing.Mesh):
    """(die, load, end time, press): the moving die of a pressed workpiece (a
    :class:`DieSet` of the top, bottom and side dies where there are several), each
    checked clear of it at t = 0, driven by the press (:func:`press_of`), or the
    traction load of a membrane (no press)."""
    if not piece.pressed:
        return None, membrane_load(cfg, mesh), cfg.load.ramp_time_s, None
    sets = piece.contact_sets(mesh)
    top_z = float(mesh.coords[mesh.node_sets["top"], 1].max())
    profile = die_profile(cfg.die, top_z)
    _check_clearance(profile, mesh, sets, "die.profile_mm")
    full = cfg.bottom_die is not None and not piece.half_height
    bottom_z = float(mesh.coords[mesh.node_sets["bottom"], 1].min()) if full else 0.0
    share = 0.5 if piece.half_height else 1.0  # the top die's share of the ram travel
    press, motion, driven = press_of(cfg, (top_z - bottom_z) / share, share)
    if driven is not None:  # the press moves the top die; a bottom die stands
        paths, t_end = [driven[:2]], driven[2]
        if full:
            paths.append((np.array([0.0, t_end]), np.zeros(2)))
    elif full:
        paths, t_end = _closing_paths(cfg, cfg.die.reduction * (top_z - bottom_z))
    else:
        times, travel, t_end = die_path(cfg.die, cfg.die.reduction * top_z, share)
        paths = [(times, travel)]
    profiles, names = [profile], ["top"]
    if full:
        bottom = bottom_die_profile(cfg, profile, bottom_z)
        _check_clearance(bottom, mesh, sets, "bottom_die.profile_mm")
        profiles, names = [profile, bottom], ["top", "bottom"]
    side = cfg.side_die
    if side is not None and side.profile_mm:
        pts = _profile_points(side.profile_mm, "polyline", "side_die.profile_mm", False)
        _check_clearance(pts, mesh, sets, "side_die.profile_mm")
        fixed = (np.array([0.0, t_end]), np.zeros(2))
        paths.append((np.asarray(side.path_time_s), np.asarray(side.path_travel_mm))
                     if side.path_time_s else fixed)  # fmt: skip
        profiles.append(pts)
        names.append("side")
    dwell = cfg.thermal.dwell_s
    if dwell > 0.0:  # the dies wait while the billet cools in air
        paths = [(np.r_[0.0, times + dwell], np.r_[0.0, travel]) for times, travel in paths]
        t_end = t_end + dwell
    radii = {"top": cfg.die.corner_radius_mm}
    if cfg.bottom_die is not None:
        radii["bottom"] = cfg.bottom_die.corner_radius_mm
    if side is not None:
        radii["side"] = side.corner_radius_mm
    dies = tuple(
        make_die(
            p,
            times,
            travel,
            friction=friction_law(cfg.friction_of(DIE_SECTIONS[name])),
            corner_radius=radii[name],
            motion=motion if name == "top" else None,
        )
        for p, (times, travel), name in zip(profiles, paths, names)
    )
    if len(dies) == 1:
        return dies[0], None, t_end, press
    return DieSet(dies, tuple(names)), None, t_end, press


# the config section of each die of a scene (its friction table is [<section>.friction])
DIE_SECTIONS = {"top": "die", "bottom": "bottom_die", "side": "side_die"}
# the friction law of each friction.model (the config's names end here)
FRICTION_LAWS = {
    "none": lambda fr: Frictionless(),
    "coulomb": lambda fr: Coulomb(mu=jnp.asarray(float(fr.mu))),
    "shear": lambda fr: Shear(m=jnp.asarray(float(fr.m))),
    "sticking": lambda fr: Sticking(),
}


def friction_law(fr: FrictionConfig) -> FrictionLaw:
    """The friction law object of a (resolved) friction table."""
    return FRICTION_LAWS[fr.model](fr)


def _speed_press(cfg: Config, height_mm: float, share: float):
    """Today's motion: the die path table or constant speed (set by the caller)."""
    return SpeedPress(capacity_N=cfg.press.capacity_N), None, None


def _crank_press(cfg: Config, height_mm: float, share: float):
    """The crank press whose ram travels die.reduction x the height to bottom dead
    centre (the shut height set for the part): its start angle and motion."""
    pr = cfg.press
    ram_mm = cfg.die.reduction * height_mm
    if ram_mm > pr.stroke_mm:
        raise ConfigError(
            f"press.stroke_mm = {pr.stroke_mm!r}: the crank press travels at most its "
            f"stroke, die.reduction x the height needs {ram_mm:.6g} mm"
        )
    theta0 = crank_start_angle(pr.stroke_mm, pr.rod_length_mm, ram_mm)
    motion = CrankMotion(
        radius_mm=jnp.asarray(0.5 * pr.stroke_mm),
        rod_mm=jnp.asarray(float(pr.rod_length_mm)),
        omega_rad_s=jnp.asarray(2.0 * np.pi * pr.strokes_per_min / 60.0),
        theta0_rad=jnp.asarray(theta0),
        share=jnp.asarray(share),
        delay_s=jnp.asarray(float(cfg.thermal.dwell_s)),
    )
    press = CrankPress(motion=motion, stroke_mm=pr.stroke_mm,
                       strokes_per_min=pr.strokes_per_min, capacity_N=pr.capacity_N)  # fmt: skip
    t_end = motion.end_s - float(cfg.thermal.dwell_s)  # the dwell is added by the caller
    return press, motion, (np.array([0.0, t_end]), np.array([0.0, share * ram_mm]), t_end)


def _energy_press(cfg: Config, height_mm: float, share: float):
    """A screw press or a hammer: the die stands until the blows move it
    (:mod:`jaxform.blows`); the end time is nominal (a uniform deceleration over the
    reduction, or half the height)."""
    pr = cfg.press
    press = EnergyPress(
        energy_Nmm=jnp.asarray(pr.energy_J * J_TO_NMM),
        efficiency=jnp.asarray(float(pr.efficiency)),
        impact_speed_mm_s=jnp.asarray(float(pr.impact_speed_mm_s)),
        blows=pr.blows,
        steps_per_blow=pr.steps_per_blow,
        capacity_N=pr.capacity_N,
        name=pr.model,
    )
    reduction = cfg.die.reduction if cfg.die.reduction is not None else 0.5
    t_end = press.nominal_duration_s(reduction * height_mm)
    return press, None, (np.array([0.0, t_end]), np.zeros(2), t_end)


_PRESSES = {"speed": _speed_press, "crank": _crank_press, "screw": _energy_press,
            "hammer": _energy_press}  # fmt: skip


def press_of(cfg: Config, height_mm: float, share: float):
    """(press strategy, closed-form motion of the top die or None, (times, travel, end
    time) of the top die where the press sets them, else None) for ``[press]``;
    ``height_mm``: the ram travel that closes the dies on the workpiece's whole height,
    ``share``: the top die's share of the ram travel (1/2 in a half-height model)."""
    return _PRESSES[cfg.press.model](cfg, height_mm, share)


def _station_profile(points: np.ndarray, reach: float) -> np.ndarray:
    """The part of a die profile that carries wear stations: the profile itself, but for
    a flat die (two points at one height, extended both ways for contact) the span from
    the axis to ``reach`` (mm), in the profile's direction."""
    flat = len(points) == 2 and points[0, 1] == points[1, 1]
    if not flat:
        return points
    ends = [0.0, reach] if points[1, 0] > points[0, 0] else [reach, 0.0]
    return np.array([[ends[0], points[0, 1]], [ends[1], points[0, 1]]])


def wear_inputs(cfg: Config, die, coords: np.ndarray) -> WearInputs | None:
    """Archard's law of ``[wear]`` and each die's stations (None: wear off or no die):
    stations along each die profile, along a flat die from the axis to twice the
    workpiece's largest radius ``coords`` (mm)."""
    w = cfg.wear
    if w is None or not w.on or die is None:
        return None
    members = die.members
    hard = w.hardness_by_die_MPa or (w.hardness_MPa,) * len(members)
    if len(hard) != len(members):
        raise ConfigError(
            f"wear.hardness_by_die_MPa = {list(hard)}: give one hardness per die "
            f"({len(members)}: {', '.join(die.names)})"
        )
    reach = 2.0 * float(np.max(np.abs(coords[:, 0])))
    stations = [
        die_stations(_station_profile(np.asarray(d.points), reach), float(d.corner_radius),
                     w.stations)[0]
        for d in members
    ]  # fmt: skip
    return WearInputs(
        stations=jnp.asarray(np.stack(stations)),
        k=jnp.asarray(w.k),
        hardness_MPa=jnp.asarray(hard, dtype=float),
        b=jnp.asarray(w.b),
        c=jnp.asarray(w.c),
        slope_MPa_K=jnp.asarray(w.hardness_slope_MPa_K),
        reference_K=jnp.asarray(w.hardness_reference_K),
        die_temperature_K=jnp.asarray(cfg.thermal.die_temperature_K),
    )


def _closing_paths(cfg: Config, target_mm: float):
    """([(times, travel) of the top die, of the bottom die], end time) of a full-height
    scene whose dies close by ``target_mm``: at die.speed_mm_s shared by
    bottom_die.speed_share, or along the two path tables (the bottom die's travel is
    counted downward like every die's, so it is minus its rise).  The end time is
    :func:`jaxform.config.stroke.closing_time`, as the config's step count."""
    d, b = cfg.die, cfg.bottom_die
    t_end = closing_time(d, b, target_mm, 1.0)
    if not d.path_time_s:
        v = d.speed_mm_s
        times = np.array([0.0, t_end])
        share = b.speed_share
        return [(times, np.array([0.0, (1.0 - share) * v * t_end])),
                (times, np.array([0.0, -share * v * t_end]))], t_end  # fmt: skip
    top = (np.asarray(d.path_time_s), np.asarray(d.path_travel_mm))
    rise = (np.asarray(b.path_time_s), np.asarray(b.path_travel_mm)) if b.path_time_s else (
        np.array([0.0, 1.0]), np.zeros(2))  # fmt: skip
    return [top, (rise[0], -rise[1])], t_end


def scene_on_mesh(scene: Scene, mesh: meshing.Mesh) -> Scene:
    """The scene on a new mesh of its workpiece (a remesh, :mod:`jaxform.remesh`; a trim,
    :mod:`jaxform.process`): the mesh's coordinates become the reference
    (``inputs.coords``), its sets give the Dirichlet conditions, contact candidates and
    heat-exchanging edges as in :func:`build_scene`, the linear solver and Newton variant
    are chosen for its size; the rest of the scene stays.  The pattern's symbolic analysis
    is left to what steps it (:func:`analyzed`; a remeshed run steps the scene padded to
    its capacity bucket, :func:`jaxform.capacity.padded`, which analyses that pattern)."""
    model = scene.model
    layout, idx = _indices(
        mesh,
        model.formulation.n_fields,
        scene.workpiece.contact_sets(mesh),
        model.layout.n_facets > 0,
        temperature=model.layout.temperature,
        copies=_copies(model.contact, scene.inputs.die),
    )
    model, idx = replace(model, layout=layout).with_pattern(idx)
    so = scene.settings.solver
    linear = choose_backend(so.linear, layout.n_dofs)
    variant = newton_variant(so.newton, linear, layout.n_dofs, so.anderson_depth,
                             remeshes=scene.remeshes)  # fmt: skip
    newton = replace(scene.newton, variant=variant)
    return replace(
        scene,
        mesh=mesh,
        model=model,
        idx=idx,
        linear=linear,
        newton=newton,
        inputs=replace(scene.inputs, coords=jnp.asarray(mesh.coords)),
        grid=None,
    )


# the contact candidates of each die.contact_pairs (the config's names end here)
PAIRINGS = {"nearest": NearestDie, "each_die": EachDie}


def _copies(contact: ContactLaw, die) -> int:
    """How many candidates each contact node gives (one per die where they are pairs)."""
    return 1 if die is None else contact.pairing.copies(len(die.members))


def analyzed(scene: Scene) -> Scene:
    """The scene with its pattern's symbolic analysis (KLU's; None for the other linear
    solvers), done once per pattern outside jit: the scene itself where it has one."""
    if scene.idx.lu_symbolic is not None:
        return scene
    idx = scene.idx
    symbolic = scene.linear.analyze(idx.rows, idx.cols, scene.model.layout.n_dofs)
    return scene if symbolic is None else replace(scene, idx=replace(idx, lu_symbolic=symbolic))


def _remeshes(remesh: RemeshConfig | None) -> bool:
    """Whether a scene with these [remesh] settings (None: none) may get new meshes."""
    return remesh is not None and remesh.on


def _remesh_settings(settings: RemeshConfig, mesh: meshing.Mesh) -> RemeshConfig | None:
    """The scene's [remesh] settings, its bulk element size resolved (0: the mesh's
    mean), or None where no trigger is set."""
    if not settings.on:
        return None
    size = settings.element_size_mm or float(
        np.sqrt(np.mean(np.abs(meshing.element_areas(mesh.coords, mesh.elements))))
    )
    return replace(settings, element_size_mm=size)


def start_mesh(mesh: meshing.Mesh, die, settings: RemeshConfig, axisymmetric: bool) -> meshing.Mesh:
    """The remesher's own mesh of ``mesh``'s section at t = 0 (``remesh.from_start``):
    the same polygon and sizes a remesh would ask gmsh for (:mod:`jaxform.section_mesh`),
    finer where a die touches it.  Raises ConfigError where gmsh gives no all-quad mesh."""
    gap_fn = None if die is None else gap_function(die, 0.0)
    pos = np.asarray(mesh.coords)
    wanted = sized_polygon(mesh, pos, gap_fn, settings, axisymmetric, split=True)
    try:  # gmsh's fallbacks as for a remesh (finer sizes, then split into quads)
        return quads_of(wanted.points, wanted.labels, wanted.sizes)[0]
    except meshing.MeshError as err:
        raise ConfigError(f"remesh.from_start: no all-quad start mesh ({err})") from None


def build_scene(cfg: dict | Config, mesh: meshing.Mesh | None = None) -> Scene:
    """Set-up of a scene from a validated config: mesh, material, die or load, solver.

    Arguments:
        cfg: a config from :func:`jaxform.config.load_config` (every key present), or
            its typed :class:`jaxform.config.Config`.
        mesh: the workpiece's mesh (its coordinates the reference) where the scene does
            not start from the workpiece section's own (an operation of a process, on
            the part the operation before it left: :mod:`jaxform.process`); the die
            reduction then refers to this mesh's height, and the scene has no grid to
            rezone.

    Returns:
        the :class:`Scene` (nothing compiled yet).

    Raises:
        ConfigError: a bad material preset or file, a mesh file that does not fit, or a
        die that overlaps the workpiece at t = 0.
    """
    require_x64()
    cfg = cfg if isinstance(cfg, Config) else typed(cfg)
    m, tm, so = cfg.mesh, cfg.time, cfg.solver
    axi = m.geometry == "axisymmetric"
    piece = workpiece_of(cfg)
    own = mesh is None  # the scene starts from its workpiece's own section
    grid = piece.grid if own else None
    mesh = piece.build_mesh() if own else mesh
    law, params = load_material(cfg.material.preset)
    form = formulation(m.element, axisymmetric=axi, theta=m.stabilization, alpha=tm.alpha)
    die, load, t_end, press = _die_or_load(cfg, piece, mesh)
    remesh = _remesh_settings(cfg.remesh, mesh)
    if remesh is not None and remesh.from_start and own:
        mesh, grid = start_mesh(mesh, die, remesh, axi), None
    corner = (
        die is not None
        and cfg.die.corner_contact
        and any(has_convex_corner(d.points, float(d.corner_radius)) for d in die.members)
    )
    thermal = thermal_inputs(cfg)
    # a scene under a load (no [die]) has no candidates: the default pairing
    contact = ContactLaw(PAIRINGS[cfg.die.contact_pairs if cfg.die is not None else "nearest"]())
    layout, idx = _indices(mesh, form.n_fields, piece.contact_sets(mesh), corner,
                           temperature=thermal is not None,
                           copies=_copies(contact, die))  # fmt: skip
    law = law.for_points(4 * layout.n_elements)  # its local solve for the mesh's size
    model = Model(form, law, layout, contact)
    model, idx = model.with_pattern(idx)
    c = _contact_scale(mesh, float(law.shear_modulus(params)), axi)
    if m.rezone_quality > 0.0 and grid is None:
        raise ConfigError(
            f"mesh.rezone_quality > 0 needs a billet or ring scene on its "
            f"structured mesh (this scene: {piece.name})"
        )
    linear = choose_backend(so.linear, layout.n_dofs)
    try:
        variant = newton_variant(so.newton, linear, layout.n_dofs, so.anderson_depth,
                                 remeshes=_remeshes(remesh))  # fmt: skip
    except ValueError as err:
        raise ConfigError(str(err)) from None
    # a symbolic analysis once per pattern, outside jit (KLU's; None for the others)
    idx = replace(idx, lu_symbolic=linear.analyze(idx.rows, idx.cols, layout.n_dofs))
    return Scene(
        settings=cfg,
        workpiece=piece,
        mesh=mesh,
        model=model,
        idx=idx,
        linear=linear,
        newton=NewtonSettings(
            max_iterations=so.max_newton_iterations,
            rtol=so.rtol,
            line_search=so.line_search,
            variant=variant,
            stall_iterations=so.stall_iterations,
            stall_ratio=so.stall_ratio,
        ),
        inputs=Inputs(
            coords=jax.device_put(np.asarray(mesh.coords, dtype=float)),
            params=params,
            die=die,
            c_contact=jnp.asarray(c),
            load=load,
            thermal=thermal,
            wear=wear_inputs(cfg, die, np.asarray(mesh.coords)),
        ),
        dt=tm.dt_s,
        t_end=t_end,
        max_cutbacks=so.max_cutbacks,
        continuations=so.smallest_step_continuations,
        max_quality_drop=so.max_quality_drop,
        first_step_probe=tm.first_step_probe,
        dt_growth=tm.dt_growth,
        chunk=so.chunk_steps,
        chunk_output_mb=so.chunk_output_mb,
        symmetric_z=piece.half_height,
        rezone_quality=m.rezone_quality,
        grid=grid,
        adjoint_memory_mb=so.adjoint_memory_mb,
        remesh=remesh,
        press=press,
    )
