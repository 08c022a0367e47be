"""A design problem over a multi-stage process: design groups acting on chosen operations'
inputs, an objective of any operation's run, exact gradients through the whole sequence.

    ProcessPlan (jaxform.process_gradients) --build_process_problem(plan, groups, objective)
        --> ProcessDesignProblem: value(design), value_and_grad(design), bounds(), physical()

The interface is that of the single-scene :class:`jaxform.design.problem.DesignProblem`
(``start``, ``groups`` with ``name``, ``value``, ``value_and_grad``, ``bounds``,
``physical``), so the optimizers and the Taylor test take either.

A group is named ``<operation>.<group>`` where it acts on one operation's inputs
(``blocker.die``: the blocker's top die profile points; ``finisher.friction``: each die's
friction coefficient of the finisher; ``blocker.speed``: its die speed;
``transfer.dwell``: the dwell's time; ``finisher.thermal``: its die temperature and
conductance) or by the group's name alone where it acts on the process (``preform``,
``nodes``, ``billet``: the first mesh's coordinates; ``material``, ``thermal``: every
operation's inputs; the billet temperature, the origin of the temperature unknown, is the
process's).  The physical values carry the same prefix (``blocker.die_dz3_mm``).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import jax
import jax.numpy as jnp
import numpy as np

from jaxform.design import objectives as obj
from jaxform.design import parametrize as par
from jaxform.design.problem import build_group, friction_variables, lap_penalty
from jaxform.design.requirements import (
    OPERATION_GROUPS,
    PROCESS_GROUPS,
    PROCESS_OBJECTIVES,
    PROCESS_WEIGHTED_SUM,
)
from jaxform.dies import DieError, check_clearance_of_facets
from jaxform.gradients import GradientRunError
from jaxform.process_gradients import ProcessPlan, check_process, process_trajectory

# the thermal inputs of one operation (the billet temperature is the process's): a
# forming operation's dies, a dwell's or furnace's air
OPERATION_THERMAL = ("die_temperature_K", "htc_die_W_m2K")
AIR_THERMAL = ("air_temperature_K", "htc_air_W_m2K")


@dataclass(frozen=True)
class OnStages:
    """A design group (``inner``, of :mod:`jaxform.design.parametrize`) applied to the
    inputs and step times of the process's stages ``stages``; named
    ``<prefix>.<inner name>`` (the operation's name), or the inner name for the process."""

    inner: object
    stages: tuple[int, ...]
    prefix: str = ""

    @property
    def name(self) -> str:
        return f"{self.prefix}.{self.inner.name}" if self.prefix else self.inner.name

    @property
    def kind(self) -> str:
        """The group's kind (its inner group's name: die, friction, ...)."""
        return self.inner.name

    def initial(self):
        return self.inner.initial()

    def bounds(self):
        return self.inner.bounds()

    def apply(self, u, inputs: tuple, times: tuple):
        inputs, times = list(inputs), list(times)
        for k in self.stages:
            inputs[k], times[k] = self.inner.apply(u, inputs[k], times[k])
        return tuple(inputs), tuple(times)

    def physical(self, u) -> dict:
        pre = f"{self.prefix}." if self.prefix else ""
        return {pre + k: v for k, v in self.inner.physical(u).items()}

    def penalty(self, u):
        """The inner group's constraint penalty (a die spline's), else 0."""
        return self.inner.penalty(u) if hasattr(self.inner, "penalty") else 0.0

    def report(self, u) -> list[dict]:
        """The inner group's constraint rows (a die spline's), else none."""
        return self.inner.report(u) if hasattr(self.inner, "report") else []


def _stage_of(plan: ProcessPlan, name: str, spec: str) -> int:
    try:
        return plan.index(name)
    except ValueError as err:
        raise ValueError(f"design group {spec!r}: {err}") from None


def build_process_group(plan: ProcessPlan, spec: str, default_operation: str = "") -> OnStages:
    """The group ``spec`` (``<operation>.<group>`` or ``<group>``; an operation group
    without an operation acts on ``default_operation``, else the first forming one).
    Raises ValueError for an unknown operation or group, a group the operation cannot
    vary (a dwell's die, a forming operation's dwell time)."""
    op_name, _, group = spec.rpartition(".")
    stages = plan.stages
    first = stages[0].scene
    if not op_name and group in PROCESS_GROUPS:
        every = tuple(range(len(stages)))
        if group in ("preform", "nodes"):
            return OnStages(build_group(first, group), (0,))
        if group in ("billet", "billet_volume"):
            axi = first.model.formulation.axisymmetric
            kind = par.BilletAspect if group == "billet" else par.BilletVolume
            return OnStages(kind(axi), (0,))
        return OnStages(build_group(first, group), every)  # material, thermal
    if group not in OPERATION_GROUPS:
        allowed = ", ".join([*PROCESS_GROUPS, *(f"<operation>.{g}" for g in OPERATION_GROUPS)])
        raise ValueError(f"design group {spec!r}: must be one of {allowed}")
    if not op_name:
        op_name = default_operation or next(s.name for s in stages if s.operation.forming)
    k = _stage_of(plan, op_name, spec)
    stage = stages[k]
    forming = stage.operation.forming
    if group == "dwell":
        if forming or not stage.stepped:
            raise ValueError(
                f"design group {spec!r}: {stage.operation.label} is no dwell or furnace "
                "that takes steps (with coupled heat)"
            )
        return OnStages(par.DwellTime(float(stage.times[-1])), (k,), op_name)
    if group == "thermal":
        scene = stage.scene
        th = scene.settings.thermal
        own = OPERATION_THERMAL if forming else AIR_THERMAL
        names = tuple(n for n in scene.settings.design.thermal_params if n in own) or own
        start = tuple(float(getattr(th, n)) for n in names)
        d = scene.settings.design
        return OnStages(par.Thermal(names, start, float(np.log(d.bound_factor))), (k,), op_name)
    if not forming:
        raise ValueError(f"design group {spec!r}: {stage.operation.label} is no forming operation")
    if group == "friction":
        return OnStages(par.Friction(friction_variables(stage.scene)), (k,), op_name)
    return OnStages(build_group(stage.scene, group), (k,), op_name)  # die, die_spline, speed


def uncertain_groups(plan: ProcessPlan, friction: bool, die_temperature: bool) -> tuple:
    """The groups a robust design fixes per scenario: each forming operation's friction
    coefficients (``<operation>.friction``) and its die temperature
    (``<operation>.die_temperature``: u = (T - T_configured) / 100 K)."""
    out = []
    for k, stage in enumerate(plan.stages):
        if not stage.operation.forming:
            continue
        if friction:
            out.append(OnStages(par.Friction(friction_variables(stage.scene)), (k,), stage.name))
        if die_temperature:
            t0 = float(stage.scene.settings.thermal.die_temperature_K)
            inner = par.Thermal(("die_temperature_K",), (t0,), name="die_temperature")
            out.append(OnStages(inner, (k,), stage.name))
    return tuple(out)


def scenario_designs(groups, friction=(), die_temperature_K=()) -> tuple[dict, ...]:
    """Every combination of the friction coefficients and die temperatures (K) given, as
    the variables of ``groups`` (:func:`uncertain_groups`): a friction group's every
    coefficient at the value, a die temperature group at (T - T0) / 100 K."""
    out = []
    for m in friction or (None,):
        for t in die_temperature_K or (None,):
            scenario = {}
            for g in groups:
                if isinstance(g.inner, par.Friction) and m is not None:
                    scenario[g.name] = jnp.full(len(g.inner.variables), float(m))
                elif isinstance(g.inner, par.Thermal) and t is not None:
                    t0 = g.inner.start[0]
                    scenario[g.name] = jnp.asarray([(float(t) - t0) / g.inner.KELVIN_PER_UNIT])
            out.append(scenario)
    return tuple(out)


def with_groups(problem: ProcessDesignProblem, extra: tuple) -> ProcessDesignProblem:
    """``problem`` with the groups ``extra`` added (at their start values)."""
    groups = (*problem.groups, *extra)
    names = [g.name for g in groups]
    if len(set(names)) != len(names):
        raise ValueError(f"design groups {names}: each may be named once")
    start = {**problem.start, **par.initial_design(extra)}
    return ProcessDesignProblem(problem.plan, groups, problem.objective, start,
                                problem.single_program)  # fmt: skip


@dataclass(frozen=True, eq=False)
class OnOperation(obj._Identity):
    """A single-scene objective (:mod:`jaxform.design.objectives`) of one operation's run
    (``stage``: its index in the process) and inputs."""

    inner: object
    stage: int

    @property
    def unit(self):
        return self.inner.unit

    def __call__(self, ptraj, inputs):
        return self.inner(ptraj.operations[self.stage], inputs[self.stage])


@dataclass(frozen=True, eq=False)
class WeightedSum(obj._Identity):
    """sum_i weight_i objective_i (each a process objective)."""

    terms: tuple  # ((weight, objective), ...)
    unit = "-"

    def __call__(self, ptraj, inputs):
        return sum(w * o(ptraj, inputs) for w, o in self.terms)


def _final_elements(plan: ProcessPlan, k: int) -> np.ndarray:
    return np.asarray(plan.stages[k].final_scene.mesh.elements)


def process_objective(plan: ProcessPlan, name: str, operation: str = "") -> OnOperation:
    """The process objective ``name`` of the operation named ``operation`` ('' = the last
    forming operation): ``peak_force`` (N), ``forging_work`` (N mm), ``press_capacity``
    (penalty above design.press_capacity_N), ``flash_volume`` (mm^3 beyond
    design.flash_radius_mm or its die's die.part_radius_mm, both halves), ``die_fill``
    (1 - fill of its closed die inside die.part_radius_mm), ``lap`` (penalty on the air
    wedges of the free surface of the mesh it ends on, design.lap_angle_deg),
    ``mean_temperature`` (K, at its end).
    Raises ValueError for another name or an operation that lacks what it reads."""
    stages = plan.stages
    if operation:
        k = plan.index(operation)
    else:
        k = max(i for i, s in enumerate(stages) if s.operation.forming)
    stage = stages[k]
    scene = stage.final_scene
    axi = scene.model.formulation.axisymmetric
    elements = _final_elements(plan, k)
    die = stage.scene.settings.die
    if name == "peak_force":
        return OnOperation(obj.PeakForce(), k)
    if name == "forging_work":
        return OnOperation(obj.ForgingWork(), k)
    d = stage.scene.settings.design
    if name == "press_capacity":
        return OnOperation(obj.PressCapacity(d.press_capacity_N, d.capacity_penalty), k)
    if name == "lap":  # the free surface of the mesh the operation ends on
        return OnOperation(lap_penalty(scene, d.lap_angle_deg), k)
    if name == "mean_temperature":
        if not scene.model.layout.temperature:
            raise ValueError("objective 'mean_temperature' needs thermal.model = 'coupled'")
        return OnOperation(obj.MeanTemperature(elements, scene.model.layout, axi), k)
    if name in ("flash_volume", "die_fill"):
        radius = die.part_radius_mm
        if name == "flash_volume":
            radius = stage.scene.settings.design.flash_radius_mm or radius
        if not stage.operation.forming or radius <= 0.0:
            raise ValueError(
                f"objective {name!r} reads die.part_radius_mm > 0 of a forming operation: "
                f"{stage.operation.label} has none"
            )
        if name == "flash_volume":
            halves = 2.0 if scene.symmetric_z else 1.0
            return OnOperation(obj.FlashVolume(elements, radius, axi, halves), k)
        if not die.closed or len(stage.scene.inputs.die.members) > 1:
            raise ValueError(
                f"objective 'die_fill' reads a closed top die of a half-height part: "
                f"{stage.operation.label} has none"
            )
        return OnOperation(obj.UnfilledPart(elements, die.part_radius_mm, axi), k)
    raise ValueError(f"process objective {name!r}: must be one of {', '.join(PROCESS_OBJECTIVES)}")


def config_objective(plan: ProcessPlan, d):
    """The objective of a process's [design] ``d``: design.objective of
    design.objective_operation, or its weighted sum (:class:`objectives.WeightedSum`, each
    term named as configured) of design.terms (of design.objective_operation) and
    design.operation_terms ('<operation>.<objective>') by design.term_weights."""
    if d.objective != PROCESS_WEIGHTED_SUM:
        return process_objective(plan, d.objective, d.objective_operation)
    names = (*d.terms, *d.operation_terms)
    terms = []
    for spec in names:
        op_name, _, name = spec.rpartition(".")
        op_name = op_name if spec in d.operation_terms else d.objective_operation
        terms.append(process_objective(plan, name, op_name))
    return obj.WeightedSum(names, tuple(terms), tuple(float(w) for w in d.term_weights))


class DieIntoPart(GradientRunError):
    """A design that starts a forming operation's top die inside the part it receives (a
    run of its config is refused): no forward run at it can help."""


def check_dies_clear(plan: ProcessPlan, inputs: tuple, ptraj) -> None:
    """Raise :class:`DieIntoPart` naming the operation where a forming operation's top die
    at its start (``inputs``: each operation's at the design) lies inside the part it
    receives (the first: the designed billet; the others: the operation before it as it
    left the part, ``ptraj``), by the config's own test
    (:func:`jaxform.dies.check_clearance_of_facets` of every facet of the part)."""
    for k, stage in enumerate(plan.stages):
        if not stage.operation.forming:
            continue
        if k == 0:
            mesh, coords = stage.scene.mesh, np.asarray(inputs[0].coords)
        else:
            mesh = plan.stages[k - 1].final_scene.mesh
            coords = np.asarray(ptraj.operations[k - 1].positions)
        facets = np.concatenate(list(mesh.facet_sets.values()))
        die = np.asarray(inputs[k].die.members[0].points)
        try:
            check_clearance_of_facets(die, coords, facets, stage.operation.label)
        except DieError as err:
            raise DieIntoPart(f"the design starts the top die inside the part: {err}") from None


@dataclass(frozen=True, eq=False)
class ProcessDesignProblem:
    """A process's design problem: its forward run's plan, the groups, the objective
    (``(ProcessTrajectory, inputs per operation) -> scalar``) and the start design.
    ``single_program``: value() runs the gradient programs too (one compile per mesh
    bucket instead of two; pays off for small processes and tests)."""

    plan: ProcessPlan
    groups: tuple[OnStages, ...]
    objective: object
    start: dict
    single_program: bool = False

    def _ordered(self):
        """The groups in the order they apply: the billet's groups, which lift the first
        top die with the billet's top, after those that set its heights (a die spline)."""
        return sorted(self.groups, key=lambda g: getattr(g.inner, "lifts_the_die", False))

    def run_inputs(self, design):
        """(inputs, step times) of every operation at ``design``."""
        inputs = self.plan.inputs()
        times = tuple(jnp.asarray(t) for t in self.plan.times())
        for g in self._ordered():
            inputs, times = g.apply(design[g.name], inputs, times)
        return inputs, times

    def on_stage(self, design, k: int, inputs, times):
        """One operation's (inputs, times) at ``design``: the groups that act on stage
        ``k`` applied to ``inputs`` (any mesh's: the groups set dies, coefficients and
        speeds, and the first stage's coordinates) and ``times`` (the speed and dwell
        groups scale them)."""
        for g in self._ordered():
            if k in g.stages:
                inputs, times = g.inner.apply(design[g.name], inputs, times)
        return inputs, times

    @cached_property
    def _inputs(self):
        return jax.jit(self.run_inputs)  # one program, not dozens of eager operations

    @cached_property
    def _objective(self):
        return jax.jit(self.objective)

    def _j(self, design):
        inputs, times = self._inputs(design)
        ptraj = process_trajectory(self.plan, inputs, times)
        value = self._objective(ptraj, inputs)
        return value + par.penalty_of(self.groups, design), ptraj  # die splines' constraints

    def value(self, design):
        if self.single_program:
            val, _, ptraj = self.value_and_grad(design)
            return val, ptraj
        val, ptraj = self._j(design)
        check_process(self.plan, ptraj)
        return val, ptraj

    def value_of(self, design, ptraj) -> float:
        """The objective at ``design`` of a run made already (``ptraj``: on this problem's
        plan, e.g. the forward run's own, :func:`jaxform.process_gradients.forward_trajectory`),
        with the groups' penalties, as :meth:`value` gives it for its replay."""
        inputs, _ = self._inputs(design)
        return float(self._objective(ptraj, inputs) + par.penalty_of(self.groups, design))

    def value_and_grad(self, design):
        (val, ptraj), grad = jax.value_and_grad(self._j, has_aux=True)(design)
        check_process(self.plan, ptraj)
        return val, grad, ptraj

    def check_dies_clear(self, design, ptraj) -> None:
        """:func:`check_dies_clear` at ``design`` (its run ``ptraj``)."""
        check_dies_clear(self.plan, self._inputs(design)[0], ptraj)

    def bounds(self):
        return par.design_bounds(self.groups)

    def physical(self, design) -> dict:
        return par.physical_values(self.groups, design)

    def report(self, design, evaluated=None) -> dict:
        """The objective (with the constraints' penalty), each term of a weighted sum
        (unweighted, its own unit), each forming operation's peak force
        (``<operation>.peak_force_N``), the penalty and each constraint's rows, from
        ``evaluated`` (value_and_grad's output at ``design`` on this plan) or by running
        the gradient program (compiled already where a design ran)."""
        val, _, ptraj = self.value_and_grad(design) if evaluated is None else evaluated
        inputs, _ = self._inputs(design)
        out = {"objective": float(val)}
        if hasattr(self.objective, "values"):
            out.update({k: float(v) for k, v in self.objective.values(ptraj, inputs).items()})
        for k, stage in enumerate(self.plan.stages):
            if stage.operation.forming:
                peak = OnOperation(obj.PeakForce(), k)(ptraj, inputs)
                out[f"{stage.name}.peak_force_N"] = float(peak)
        out["constraint_penalty"] = float(par.penalty_of(self.groups, design))
        out["constraints"] = par.constraint_report(self.groups, design)
        return out


def build_process_problem(
    plan: ProcessPlan,
    groups: tuple[str, ...],
    objective,
    default_operation: str = "",
    single_program: bool = False,
) -> ProcessDesignProblem:
    """A design problem over the process of ``plan`` (:meth:`ProcessPlan.of` of a forward
    run): ``groups`` as :func:`build_process_group` names them, ``objective`` a process
    objective (:func:`process_objective`, :class:`OnOperation`, :class:`WeightedSum`) or a
    name for :func:`process_objective` of the last forming operation."""
    built = tuple(build_process_group(plan, g, default_operation) for g in groups)
    names = [g.name for g in built]
    if len(set(names)) != len(names):
        raise ValueError(f"design groups {list(groups)}: each may be named once")
    if isinstance(objective, str):
        objective = process_objective(plan, objective)
    return ProcessDesignProblem(plan, built, objective, par.initial_design(built), single_program)
