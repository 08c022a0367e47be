"""A design problem: a scene, design variable groups, an objective, a step schedule.

    config --build_scene--> Scene --build_problem(scene, groups=...)--> DesignProblem
    problem.value(design) -> (J, trajectory)
    problem.value_and_grad(design) -> (J, dJ/d design, trajectory)

The design is a dict ``{group name: array}`` (see :mod:`jaxform.design.parametrize`).
The step schedule is fixed when the problem is built: the scene's steps, split where the
forward run of the initial design needed a cutback (:func:`jaxform.gradients.schedule`).
Both functions are compiled once per problem; a step that fails raises
:class:`jaxform.gradients.GradientRunError`.
"""

from __future__ import annotations

import csv
import dataclasses
from dataclasses import dataclass, replace
from functools import cached_property, partial

import jax
import jax.numpy as jnp
import numpy as np

from jaxform import program_store
from jaxform.damage import CRITERIA
from jaxform.design import objectives as obj
from jaxform.design import parametrize as par
from jaxform.design.requirements import check_groups, check_objective, unmet_group
from jaxform.design.spline import Manufacturability, SplineBasis
from jaxform.errors import ConfigError
from jaxform.gradients import check, release, remeshed_schedule, trajectory
from jaxform.mesh import boundary_polygon
from jaxform.postprocess import nodal_volumes
from jaxform.scenes import DIE_SECTIONS, Scene
from jaxform.workpieces import DIE_GROUPS
from jaxform.xla_options import jit

GROUPS = DIE_GROUPS  # every design group, in the order problems list them


@dataclass(frozen=True, eq=False)
class DesignProblem:
    scene: Scene
    groups: tuple
    objective: object
    times: np.ndarray  # the fixed step schedule (s)
    start: dict  # initial design
    single_program: bool = False  # value() runs the gradient program too: one compile
    # instead of two (pays off for small scenes and tests; more run time per value)
    # the forward run's meshes when the scene remeshes (jaxform.gradients.RemeshPlan)
    plan: object = None

    def run_inputs(self, design, times=None):
        """(inputs, times) of a design on the schedule ``times`` (None: ``self.times``)."""
        times = jnp.asarray(self.times) if times is None else times
        return par.apply_all(self.groups, design, self.scene.inputs, times)

    def _j(self, design, idx, times=None, reuse_factorizations: bool = False):
        """(J, trajectory) of a design; ``idx`` is ``scene.idx`` and ``times`` the step
        schedule (None: ``self.times``), passed through the compiled program's arguments
        (see :func:`jaxform.gradients.trajectory`): the stored program is keyed by the
        schedule's length, not its values."""
        inputs, times = self.run_inputs(design, times)
        traj = trajectory(self.scene, inputs, times, reuse_factorizations, idx=idx, plan=self.plan)
        value = self.objective(traj, inputs)
        if any(hasattr(g, "penalty") for g in self.groups):  # the constraints' penalty
            value = value + par.penalty_of(self.groups, design)
        return value, traj

    def _compiled(self, fn, name: str):
        """One program for the whole run, except through remeshes: there each mesh's steps
        run the program of its capacity bucket (shared by the meshes of one bucket), which
        one program around them all would compile again for every mesh.  The program is
        stored (:mod:`jaxform.program_store`) under the problem's content (the scene but
        its index arrays, and the step schedule but its length: both come in as arguments):
        a warm start skips its tracing."""
        remeshed = self.plan is not None and len(self.plan.segments) > 1
        if remeshed:
            return fn
        static, compiled, times = self._stored(fn)

        def run(design, idx):
            return program_store.call(name, static, compiled, design, idx, times)

        return run

    def _stored(self, fn):
        """(description, compiled fn, schedule): what :func:`jaxform.program_store.call`
        takes besides the program's name, the design and the index arrays."""
        static = program_store.fingerprint(
            replace(self, scene=replace(self.scene, idx=None), times=None)
        )
        return static, jit(fn), jax.device_put(np.asarray(self.times))

    def _gradient_program(self):
        return jax.value_and_grad(partial(self._j, reuse_factorizations=True), has_aux=True)

    def prefetch_gradient(self):
        """Start loading the stored gradient program for a schedule of ``len(self.times)``
        steps (:func:`jaxform.program_store.prefetch`; the schedule's values do not key
        it): the thread to join, or None."""
        static, program, times = self._stored(self._gradient_program())
        return program_store.prefetch("design_value_and_grad", static, program, self.start,
                                      self.scene.idx, times)  # fmt: skip

    @cached_property
    def _value(self):
        return self._compiled(self._j, "design_value")

    @cached_property
    def _value_and_grad(self):
        # the reverse pass reuses the forward factorizations that fit the scene's
        # adjoint_memory_mb; they are freed by _released once the program has run
        return self._compiled(self._gradient_program(), "design_value_and_grad")

    def _released(self, traj):
        return release(self.scene, jax.block_until_ready(traj))

    def value(self, design):
        if self.single_program:
            (val, traj), _ = self._value_and_grad(design, self.scene.idx)
        else:
            val, traj = self._value(design, self.scene.idx)
        traj = self._released(traj)
        check(traj)
        return val, traj

    def value_and_grad(self, design):
        (val, traj), grad = self._value_and_grad(design, self.scene.idx)
        traj = self._released(traj)
        check(traj)
        return val, grad, traj

    def bounds(self):
        return par.design_bounds(self.groups)

    def physical(self, design) -> dict:
        return par.physical_values(self.groups, design)

    def report(self, design) -> dict:
        """What the design reaches, for the design report: the objective (with the
        constraints' penalty), each term of a weighted sum, the penalty, and each
        constraint's value, limit and margin (``constraints``: rows)."""
        val, traj = self.value(design)
        inputs, _ = self.run_inputs(design)
        out = {"objective": float(val)}
        if hasattr(self.objective, "values"):
            out.update({k: float(v) for k, v in self.objective.values(traj, inputs).items()})
        out["constraint_penalty"] = float(par.penalty_of(self.groups, design))
        out["constraints"] = par.constraint_report(self.groups, design)
        return out


# ----------------------------------------------------------------------------------
# from a config


def check_design_scene(scene: Scene) -> None:
    """Raise ConfigError (one line) unless ``scene`` has what design problems read: a die
    and friction (billet, ring and block scenes; a membrane under a load has neither)."""
    if not scene.workpiece.pressed:
        raise ConfigError(
            f"design problems (jaxform design, taylor-test) need a scene pressed by a die: "
            f"this [{scene.workpiece.name}] scene has no [die] or [friction] section; "
            f"allowed workpieces: [billet], [ring], [block]"
        )


def available_groups(scene: Scene) -> tuple[str, ...]:
    """The design variable groups that make sense for ``scene``: those of its workpiece
    whose requirements (:data:`jaxform.design.requirements.GROUPS`) the config meets.

    Arguments:
        scene: a scene from :func:`jaxform.scenes.build_scene` (with a die).

    Returns:
        the group names, a subset of :data:`GROUPS` in that order.
    """
    check_design_scene(scene)
    return tuple(
        g for g in scene.workpiece.design_groups() if unmet_group(scene.settings, g) is None
    )


def friction_variables(scene: Scene) -> tuple[par.FrictionCoefficient, ...]:
    """One design variable per coefficient of each die's friction law (the law's fields),
    in the order of the dies."""
    die = scene.inputs.die
    out = []
    for i, (d, name) in enumerate(zip(die.members, die.names)):
        law = d.friction
        for f in dataclasses.fields(law):
            out.append(par.FrictionCoefficient(
                die=i, die_name=name, field=f.name, value0=float(getattr(law, f.name)),
                high=law.coefficient_range[f.name][1],
                key=scene.settings.friction_key(DIE_SECTIONS[name], f.name)))  # fmt: skip
    return tuple(out)


def build_group(scene: Scene, name: str):
    """The parametrization of design group ``name`` for ``scene``; ConfigError where the
    config does not meet the group's requirements (:mod:`jaxform.design.requirements`)
    or names parameters, points the scene lacks."""
    cfg, d = scene.settings, scene.settings.design
    check_groups(cfg, (name,), "design group")
    if name == "material":
        params = scene.inputs.params
        names = d.material_params or scene.model.law.design_params
        for p in names:
            if not hasattr(params, p):
                raise ConfigError(
                    f"design.material_params: {p!r} is not a parameter of this "
                    f"material; allowed: {', '.join(vars(params))}"
                )
        return par.MaterialParams(
            tuple(names),
            tuple(float(getattr(params, p)) for p in names),
            bound_log=float(np.log(d.bound_factor)),
        )
    if name == "friction":
        return par.Friction(friction_variables(scene))
    if name == "speed":
        speed = cfg.die.speed_mm_s or float("nan")
        return par.RamSpeed(speed, bound_log=float(np.log(d.bound_factor)))
    if name == "preform":
        b = scene.workpiece
        return par.PreformCosine(
            d.preform_modes,
            0.5 * b.height_mm,
            0.5 * b.diameter_mm,
            np.asarray(scene.mesh.elements),
            axisymmetric=scene.model.formulation.axisymmetric,
            amplitude_max=d.preform_amplitude_max,
        )
    if name == "nodes":
        nf = scene.model.layout.n_fields
        held = np.zeros((scene.model.layout.n_nodes, 2), dtype=bool)
        fixed = np.asarray(scene.idx.fixed)
        fixed = fixed[fixed < scene.model.layout.n_node_dofs]
        node, comp = fixed // nf, fixed % nf
        held[node[comp < 2], comp[comp < 2]] = True
        nodes, comps = np.nonzero(~held)
        return par.NodalCoordinates(nodes, comps, offset_max_mm=d.node_offset_max_mm)
    if name == "die":
        n_pts = int(scene.inputs.die.members[0].points.shape[0])  # the top die
        pts = d.die_points or tuple(range(n_pts))
        if any(p != int(p) or not 0 <= p < n_pts for p in pts):
            raise ConfigError(
                f"design.die_points = {list(d.die_points)!r}: must be integer "
                f"indices in [0, {n_pts - 1}] of the die profile points"
            )
        return par.DieProfile(tuple(int(p) for p in pts), offset_max_mm=d.die_offset_max_mm)
    if name == "die_spline":
        return _die_spline(scene)
    if name == "thermal":
        th = cfg.thermal
        names = d.thermal_params or par.THERMAL_VARIABLES
        bad = sorted(set(names) - set(par.THERMAL_VARIABLES))
        if bad:
            raise ConfigError(
                f"design.thermal_params: {bad} are not thermal design variables; allowed: "
                f"{', '.join(par.THERMAL_VARIABLES)}"
            )
        start = tuple(float(getattr(th, n)) for n in names)
        return par.Thermal(tuple(names), start, bound_log=float(np.log(d.bound_factor)))
    raise ConfigError(f"design group {name!r}: must be one of {', '.join(GROUPS)}")


def _die_spline(scene: Scene) -> par.DieSpline:
    """The 'die_spline' group: the top die's points in [design.die_spline_r0_mm,
    r1_mm] at the heights of a spline fitted to them (the start design)."""
    d = scene.settings.design
    pts = np.asarray(scene.inputs.die.members[0].points)
    r0 = d.die_spline_r0_mm
    r1 = d.die_spline_r1_mm if d.die_spline_r1_mm > 0.0 else float(pts[:, 0].max())
    where = f"design.die_spline_r0_mm, r1_mm = {r0:g}, {r1:g} mm"
    if r1 <= r0:
        raise ConfigError(f"{where}: r1 must exceed r0 (r1 0: the die's largest radius)")
    tol = 1e-9 * max(1.0, r1)
    idx = np.nonzero((pts[:, 0] >= r0 - tol) & (pts[:, 0] <= r1 + tol))[0]
    if len(idx) < 2 or np.any(np.diff(idx) != 1) or np.any(np.diff(pts[idx, 0]) <= 0.0):
        raise ConfigError(
            f"{where}: the top die's profile needs at least 2 points there, consecutive, with "
            f"increasing radii (a wall or an undercut inside the range cannot be a height z(r));"
            f" found radii {[round(float(r), 4) for r in pts[idx, 0]]}"
        )
    n_all = d.die_spline_controls + (2 if d.die_spline_fixed_ends else 0)
    spline = SplineBasis(r0, r1, n_all, pts[idx, 0])
    z = pts[idx, 1]
    pinned = {}
    if d.die_spline_fixed_ends:
        pinned = {0: float(np.interp(r0, pts[idx, 0], z)),
                  n_all - 1: float(np.interp(r1, pts[idx, 0], z))}  # fmt: skip
    free = np.array([j for j in range(n_all) if j not in pinned], dtype=int)
    return par.DieSpline(
        spline, idx, spline.fit(z, pinned), free,
        Manufacturability(d.die_draft_deg, d.die_fillet_radius_min_mm),
        offset_max_mm=d.die_spline_offset_max_mm, weight=d.constraint_penalty,
    )  # fmt: skip


def _read_columns(path: str, needed: tuple[str, ...]) -> dict[str, np.ndarray]:
    try:
        with open(path, newline="") as fh:
            rows = list(csv.DictReader(fh))
    except OSError as err:
        raise ConfigError(f"design.target_csv = {path!r}: {err}") from err
    if not rows or any(k not in rows[0] for k in needed):
        raise ConfigError(f"design.target_csv = {path!r}: needs columns {', '.join(needed)}")
    return {k: np.array([float(r[k]) for r in rows]) for k in needed}


def side_nodes(scene: Scene) -> np.ndarray:
    sets = scene.mesh.node_sets
    name = "side" if "side" in sets else "outer"
    nodes = np.asarray(sets[name])
    return nodes[np.argsort(np.asarray(scene.mesh.coords)[nodes, 1])]


def build_objective(scene: Scene):
    """The design objective of the config (with its temperature limit, if one is set);
    ConfigError where the config does not meet the objective's requirements
    (:data:`jaxform.design.requirements.OBJECTIVES`)."""
    check_objective(scene.settings)
    objective = _base_objective(scene)
    d = scene.settings.design
    if d.max_temperature_K > 0.0:
        return obj.TemperatureLimit(objective, d.max_temperature_K, d.temperature_penalty)
    return objective


def _base_objective(scene: Scene):
    d = scene.settings.design
    if d.objective == "weighted_sum":
        terms = tuple(_objective(scene, n) for n in d.terms)
        return obj.WeightedSum(tuple(d.terms), terms, tuple(float(w) for w in d.term_weights))
    return _objective(scene, d.objective)


def lap_penalty(scene: Scene, limit_deg: float) -> obj.LapPenalty:
    """The lap penalty on the free-surface vertices of the scene's mesh: those whose two
    boundary edges lie on sets a die may touch."""
    _, labels, loop = boundary_polygon(scene.mesh, np.asarray(scene.mesh.coords))
    free = set(scene.workpiece.contact_sets(scene.mesh))
    out = np.array([lab in free for lab in labels])
    keep = out & np.roll(out, 1)
    return obj.LapPenalty(np.roll(loop, 1)[keep], loop[keep], np.roll(loop, -1)[keep],
                          float(np.radians(limit_deg)))  # fmt: skip


def _objective(scene: Scene, name: str):
    d = scene.settings.design
    axi = scene.model.formulation.axisymmetric
    if name == "forging_work":
        return obj.ForgingWork()
    if name == "peak_force":
        return obj.PeakForce()
    if name == "side_straightness":
        return obj.SideStraightness(side_nodes(scene))
    if name == "max_damage":
        return obj.MaxDamage(CRITERIA.index(scene.settings.output.damage_criterion), d.smooth_max_p)
    if name == "wear_depth":
        return obj.WearDepth(d.smooth_max_p)
    if name == "eqps_spread":
        return obj.EqpsSpread(np.arange(scene.model.layout.n_elements))
    if name == "die_fill":
        if len(scene.inputs.die.members) > 1:
            raise ConfigError(
                "design.objective = 'die_fill' reads the top die's cavity over the mid-plane: "
                "it needs a half-height scene with one die (no [bottom_die] or [side_die])"
            )
        return obj.UnfilledCavity(np.asarray(scene.mesh.elements), axi)
    if name == "flash_volume":
        radius = d.flash_radius_mm or scene.settings.die.part_radius_mm
        halves = 2.0 if scene.symmetric_z else 1.0
        return obj.FlashVolume(np.asarray(scene.mesh.elements), radius, axi, halves)
    if name == "press_capacity":
        return obj.PressCapacity(d.press_capacity_N, d.capacity_penalty)
    if name == "lap":
        return lap_penalty(scene, d.lap_angle_deg)
    if name == "mean_temperature":
        return obj.MeanTemperature(np.asarray(scene.mesh.elements), scene.model.layout, axi)
    if name == "force_misfit":
        c = _read_columns(d.target_csv, ("stroke_mm", "force_N"))
        keep = c["stroke_mm"] > 0
        return obj.ForceMisfit(c["stroke_mm"][keep], c["force_N"][keep])
    if name == "temperature_misfit":
        c = _read_columns(d.target_csv, ("time_s", "mean_temperature_K"))
        return obj.TemperatureMisfit(c["time_s"], c["mean_temperature_K"], nodal_volumes(scene))
    c = _read_columns(d.target_csv, ("node", "r_mm", "z_mm"))
    nodes = c["node"].astype(int)
    if np.any(nodes < 0) or np.any(nodes >= scene.mesh.n_nodes):
        raise ConfigError(f"design.target_csv: node ids must lie in [0, {scene.mesh.n_nodes - 1}]")
    return obj.ShapeTarget(nodes, np.column_stack([c["r_mm"], c["z_mm"]]))


def build_problem(
    scene: Scene,
    groups: tuple[str, ...] | None = None,
    objective=None,
    times=None,
    single_program: bool = False,
    progress=None,
) -> DesignProblem:
    """A design problem for ``scene``: design groups, objective and a fixed step schedule.

    Arguments:
        scene: from :func:`jaxform.scenes.build_scene`, a scene with a die.
        groups: design group names (default the config's ``design.variables``).
        objective: a callable ``(trajectory, inputs) -> scalar`` (default from
            ``design.objective``, see :mod:`jaxform.design.objectives`).
        times: the step end times (default: from a forward run of the scene, split where
            it needed a cutback; :func:`jaxform.gradients.schedule`).  A scene that
            remeshes takes the steps and meshes of its forward run
            (:func:`jaxform.gradients.remeshed_schedule`): no ``times`` then.
        single_program: value() runs the gradient program too (one compile, not two).
        progress: the forward run's progress callback (with ``times`` None), as
            :func:`jaxform.simulation.simulate` takes it.

    Returns:
        the :class:`DesignProblem`: ``start`` (the initial design), ``value(design)``,
        ``value_and_grad(design)``, ``bounds()``, ``physical(design)``.

    Raises:
        ConfigError: a scene without a die, an unknown group or an objective that needs
        a missing key.
    """
    check_design_scene(scene)
    names = tuple(scene.settings.design.variables) if groups is None else tuple(groups)
    check_groups(scene.settings, names, "design.variables" if groups is None else "groups")
    built = tuple(build_group(scene, n) for n in names)
    start = par.initial_design(built)
    if "material" in start:
        shifted = np.asarray(start["material"]) + np.log(
            scene.settings.design.material_start_factor
        )
        start["material"] = jax.device_put(shifted)
    objective = build_objective(scene) if objective is None else objective
    plan = None
    if times is None:
        # one program, not ~60 eager operations (each lowered and compiled or loaded)
        apply = jit(partial(par.apply_all, built))
        inputs, _ = apply(start, scene.inputs, jnp.asarray(scene.step_targets()))
        # a warm start loads the gradient program while the forward run fixes the
        # schedule, for the steps of a run without cutbacks (the schedule's length is
        # all the program's key holds of it)
        loading = None
        if not scene.remeshes:
            loading = DesignProblem(scene, built, objective, scene.step_targets(), start,
                                    single_program).prefetch_gradient()  # fmt: skip
        try:
            times, plan = remeshed_schedule(scene, inputs, progress)
        finally:
            if loading is not None:
                loading.join()
    elif scene.remeshes:
        raise ValueError(
            "build_problem: a scene that remeshes takes its forward run's steps: no times"
        )
    return DesignProblem(scene, built, objective, np.asarray(times), start, single_program, plan)
