"""What `jaxform taylor-test` and `jaxform design` do with a process config
([[process.operation]] tables): the forward process run that fixes every operation's
steps and meshes, the process's design problem from [design], the Taylor test or the
optimization, the files.

    Process --forward_plan--> ProcessPlan --process_problem--> ProcessDesignProblem
      --taylor_test / optimize--> rows / DesignHistory

[design] of a process: ``design.variables`` (``preform``, ``nodes``, ``billet``,
``material``, ``thermal`` act on the process; ``die``, ``friction``, ``speed``,
``thermal``, ``dwell`` on ``design.operation``, the first forming operation by default;
``--groups`` may name the operation of each, ``finisher.friction``), ``design.objective``
of the run of ``design.objective_operation`` (the last forming operation by default).
"""

from __future__ import annotations

import csv
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from jaxform.cache import enable_compilation_cache
from jaxform.config import dump_config
from jaxform.designed_config import write_design_files, write_designed
from jaxform.io import write_csv
from jaxform.precision import require_x64
from jaxform.process_config import Process, check_process_design, process_document
from jaxform.simulation import SimulationError, simulate


def forward_plan(process: Process, progress=None, announce=None, at=None):
    """The forward process run (adaptive steps, remeshes, trims) and its
    :class:`jaxform.process_gradients.ProcessPlan`; ``progress`` is each operation's
    step callback (:func:`jaxform.simulation.simulate`), ``announce`` gets a line as each
    operation starts.  ``at`` (``(problem, design)``: a
    :class:`jaxform.design.process_problem.ProcessDesignProblem` of this process and a
    design of it): the run at that design, each operation's scene with the problem's
    groups applied as it starts (its time step and end scaled where a speed or dwell
    group scales its times); the plan's operations keep the inputs and times as
    configured, so that the problem's groups apply to them as to the first plan's
    (:class:`_Designed`).  Raises ConfigError, SimulationError."""
    from jaxform.process import prepare, run_process
    from jaxform.process_gradients import ProcessPlan

    require_x64()
    ops = process.operations
    initial = prepare(ops)
    enable_compilation_cache(ops[0].config.solver.compilation_cache_dir)
    labels = iter(op.label for op in ops if op.forming or getattr(op.keys, "time_s", None))
    t0 = time.perf_counter()
    designed = _Designed(*at) if at is not None else None

    def stepped(scene, step_progress, start=None):
        if announce is not None:
            took = time.perf_counter() - t0
            announce(f"  forward run of {next(labels, 'an operation')} ({took:.1f} s)")
        if designed is not None:
            scene = designed.scene(scene)
        # by the replay's full Newton: each step it converges, the replay converges
        return simulate(scene.full_newton(), step_progress, start)

    result = run_process(ops, initial, progress, simulate_fn=stepped)
    plan = ProcessPlan.of(result)
    return result, plan if designed is None else designed.as_configured(plan)


@dataclass
class _Designed:
    """A design applied to each stepped operation's scene as the forward run starts it
    (the k-th call: the k-th stage that takes steps in ``problem``'s plan), and the
    configured inputs and time scale of each kept to undo it in the plan."""

    problem: object
    design: dict
    kept: dict = field(default_factory=dict)  # stage -> (configured inputs, time factor)

    def scene(self, scene):
        k = [k for k, s in enumerate(self.problem.plan.stages) if s.stepped][len(self.kept)]
        one = jnp.ones(1, dtype=jnp.asarray(scene.inputs.coords).dtype)
        inputs, factor = self.problem.on_stage(self.design, k, scene.inputs, one)
        f = float(factor[0])
        self.kept[k] = (scene.inputs, f)
        return replace(scene, inputs=inputs, dt=scene.dt * f, t_end=scene.t_end * f)

    def as_configured(self, plan):
        stages = list(plan.stages)
        for k, (inputs, f) in self.kept.items():
            st = stages[k]
            stages[k] = replace(st, scene=replace(st.scene, inputs=inputs),
                                times=np.asarray(st.times) / f)  # fmt: skip
        return replace(plan, stages=tuple(stages))


class Replanning:
    """A process's design problem whose plan follows the design: where the replay of the
    current plan (the steps, meshes and maps of the forward run at the design it was made
    at) fails at a design, the forward process runs again at that design
    (:func:`forward_plan` with ``at``) and the design is evaluated on its plan.

    A replay solves each step by full Newton from the forward run's solution, with no
    cutback: a design far enough from the plan's (another contact path, another remesh)
    can fail where its own forward run, with its own steps and meshes, goes through.  The
    groups, bounds and start are the first problem's (they act on the inputs as
    configured, which every plan keeps); the objective is rebuilt on each plan's final
    meshes (``objective_of(plan)``; default design.objective of the process's config).
    Where the forward run at a design fails too or refuses an operation (its die overlaps
    the part the operation before left), the evaluation raises
    :class:`jaxform.gradients.GradientRunError` (the optimizer rejects the trial); so does
    a design whose run starts a forming operation's top die inside the part it receives
    (:class:`jaxform.design.process_problem.DieIntoPart`, no new plan tried), which a run
    of its config would refuse.

    ``replan_distance`` (design.replan_distance; 0: off): a design farther than that from
    the design the current plan was made at (the start, or where :meth:`adopt` was), in any
    variable as a fraction of its bound box, gets a new plan before it is evaluated, so
    that the values the optimizer sees stay those of forward runs near their own plans
    (far from it a replay may converge to another solution of the contact conditions)."""

    def __init__(self, process: Process, problem, announce=None, objective_of=None,
                 replan_distance: float = 0.0):  # fmt: skip
        from jaxform.design.process_problem import config_objective

        d = process.operations[0].config.design
        self.process, self.first, self.current = process, problem, problem
        self.announce = announce
        self.objective_of = objective_of or (lambda plan: config_objective(plan, d))
        self.replans = 0
        self.replan_distance = float(replan_distance)
        self.made_at = {k: np.asarray(v) for k, v in problem.start.items()}  # see adopt
        self.kept = {}  # see _keep: the first and the best evaluation, for reports
        self._forward = None  # (design key, problem on its plan, out) of the last forward run

    start = property(lambda self: self.first.start)
    groups = property(lambda self: self.first.groups)
    plan = property(lambda self: self.current.plan)
    objective = property(lambda self: self.current.objective)

    def bounds(self):
        return self.first.bounds()

    def physical(self, design) -> dict:
        return self.first.physical(design)

    def value(self, design):
        kept = self.kept.get(_key(design))
        if kept is not None:  # evaluated already: the same numbers, no second run
            val, _, ptraj = kept[1]
            return val, ptraj
        val, ptraj = self._on_a_plan(lambda pb: self._clear(pb, design, pb.value(design)), design)
        self._keep(design, (val, None, ptraj))
        return val, ptraj

    def value_and_grad(self, design):
        kept = self.kept.get(_key(design))
        if kept is not None and kept[1][1] is not None:
            return kept[1]
        out = self._on_a_plan(lambda pb: self._clear(pb, design, pb.value_and_grad(design)), design)
        self._keep(design, out)
        return out

    def _keep(self, design, out, problem=None) -> None:
        """Keep the first evaluation and the one of least objective (with the problem on
        the plan it ran on, default the current one; ``out`` (value, gradient or None,
        run)), so that the report at the start and at the best design, and a second
        evaluation of either, cost no run (on the disk each is a forward or gradient run
        of minutes)."""
        key, val = _key(design), float(out[0])
        problem = self.current if problem is None else problem
        if not np.isfinite(val):
            return
        if key in self.kept:  # a gradient run where a value run was kept: the fuller one
            if out[1] is not None or self.kept[key][1][1] is None:
                self.kept[key] = (problem, out, self.kept[key][2])
        elif not self.kept:
            self.kept[key] = (problem, out, "first")
        elif val < min(float(o[0]) for _, o, _ in self.kept.values()):
            self.kept = {k: v for k, v in self.kept.items() if v[2] != "best"}
            self.kept[key] = (problem, out, "best")

    @staticmethod
    def _clear(pb, design, out):
        """``out`` (its last item the run) where every die of the design starts clear of
        the part it receives, as `jaxform run` of its config requires; else
        :class:`jaxform.design.process_problem.DieIntoPart` (the optimizer rejects it)."""
        pb.check_dies_clear(design, out[-1])
        return out

    def report(self, design) -> dict:
        """The report at ``design`` (:meth:`ProcessDesignProblem.report`): from the run
        kept there (the first, the least), else from the design's own forward run, what
        `jaxform run` of its config gives; never a replay on a plan made at another design
        (whose value can differ: after a stalled line search the disk's best design read
        2.622 there against its own run's 2.526)."""
        kept = self.kept.get(_key(design))
        if kept is not None:
            return kept[0].report(design, kept[1])
        problem, out = self._forward_run(design)
        return problem.report(design, out)

    def on_own_plan(self, design):
        """The problem on the plan of the forward run at ``design`` (its steps, meshes;
        the last forward run's where that was at ``design``).  Raises SimulationError,
        OperationRefused as the forward run does."""
        return self._run_at(design)[0]

    def adopt(self, design) -> None:
        """Evaluate from now on on the plan of the forward run at ``design``."""
        self.current = self.on_own_plan(design)
        self.made_at = {k: np.asarray(v) for k, v in design.items()}

    def forward_value(self, design) -> float:
        """The objective at ``design`` of the forward process at that design, read from
        the run itself (:func:`jaxform.process_gradients.forward_trajectory`: no replay,
        nothing more to compile): what `jaxform run` of the design's config gives, and
        what a sampling optimizer evaluates (a forward simulation each, as the commercial
        codes run).  The plan stays; the evaluation is kept as a replay's is (the first,
        the least).  Raises :class:`jaxform.gradients.GradientRunError` where that run
        fails or an operation is refused."""
        problem, out = self._forward_run(design)
        self._keep(design, out, problem)
        return out[0]

    def _forward_run(self, design):
        """:meth:`_run_at`, its failure a :class:`jaxform.gradients.GradientRunError` (the
        optimizers reject such a design)."""
        from jaxform.gradients import GradientRunError
        from jaxform.process import OperationRefused

        try:
            return self._run_at(design)
        except (SimulationError, OperationRefused) as err:  # no process at this design
            raise GradientRunError(f"the forward process at this design failed: {err}") from None

    def _run_at(self, design):
        """(the problem on the plan of the forward run at ``design``, (objective, None,
        run) read from that run); the last one's again without a run (a gradient, a new
        plan or a report there needs no second forward run).  Raises SimulationError,
        OperationRefused as the forward run does."""
        from jaxform.process_gradients import forward_trajectory

        key = _key(design)
        if self._forward is None or self._forward[0] != key:
            result, plan = forward_plan(self.process, at=(self.first, design))
            problem = replace(self.first, plan=plan, objective=self.objective_of(plan))
            ptraj = forward_trajectory(result)
            self._forward = (key, problem, (problem.value_of(design, ptraj), None, ptraj))
        return self._forward[1], self._forward[2]

    def _on_a_plan(self, evaluate, design):
        from jaxform.design.process_problem import DieIntoPart
        from jaxform.gradients import GradientRunError
        from jaxform.process import OperationRefused

        if not self._far(design):
            try:
                return evaluate(self.current)
            except DieIntoPart:  # its forward run would start the same way: no new plan
                raise
            except GradientRunError as err:
                if self.announce is not None:
                    self.announce(f"  the replay failed ({err}): the forward process at this "
                                  "design")  # fmt: skip
        try:
            self.adopt(design)
        except (SimulationError, OperationRefused) as err:  # no process at this design
            raise GradientRunError(f"the forward process at this design failed: {err}") from None
        self.replans += 1
        return evaluate(self.current)

    def _far(self, design) -> bool:
        """Whether ``design`` lies farther than replan_distance from the current plan's."""
        if self.replan_distance <= 0.0:
            return False
        lo, hi = self.first.bounds()
        for k, v in design.items():
            box = np.asarray(hi[k]) - np.asarray(lo[k])
            step = np.abs(np.asarray(v) - self.made_at[k])
            if np.any(step > self.replan_distance * np.where(np.isfinite(box), box, np.inf)):
                return True
        return False


def _key(design) -> tuple:
    """A design as a hashable key (its values' bytes, float64, by group name)."""
    return tuple((k, np.asarray(design[k], np.float64).tobytes()) for k in sorted(design))


def process_problem(process: Process, groups=None, progress=None, announce=None):
    """The design problem of a process config: its forward run's plan, the groups
    (``groups``, default ``design.variables``; checked by
    :func:`jaxform.process_config.check_process_design`) and ``design.objective`` of
    ``design.objective_operation``."""
    where = "design.variables" if groups is None else "--groups"
    check_process_design(process, groups, where)
    _, plan = forward_plan(process, progress, announce)
    return problem_of_plan(process, plan, groups)


def problem_of_plan(process: Process, plan, groups=None):
    """:func:`process_problem` on the plan of a forward run already made (checked)."""
    from jaxform.design.process_problem import build_process_problem, config_objective

    d = process.operations[0].config.design
    names = tuple(groups) if groups else (*d.variables, *d.operation_variables)
    return build_process_problem(plan, names, config_objective(plan, d), d.operation)


def robust(process: Process, problem, announce=None):
    """design.robust: ``problem`` (its design groups) over the scenarios of
    design.robust_friction x design.robust_die_temperature_K, each forming operation's
    friction and die temperature fixed per scenario (:class:`jaxform.design.robust.Scenarios`
    of one :class:`Replanning` problem per scenario, each on the plan of the forward run
    at the start design and that scenario's inputs: its own steps)."""
    from jaxform.design.process_problem import scenario_designs, uncertain_groups, with_groups
    from jaxform.design.robust import Scenarios

    d = process.operations[0].config.design
    extra = uncertain_groups(problem.plan, bool(d.robust_friction),
                             bool(d.robust_die_temperature_K))  # fmt: skip
    scenarios = scenario_designs(extra, d.robust_friction, d.robust_die_temperature_K)
    if announce is not None:
        temps = d.robust_die_temperature_K
        announce(f"  robust design ({d.robust}) over {len(scenarios)} scenarios: friction "
                 f"{list(d.robust_friction) or 'as configured'}, die temperature "
                 f"{f'{list(temps)} K' if temps else 'as configured'} (each evaluation "
                 f"replays the process {len(scenarios)} times)")  # fmt: skip
    names = tuple(g.name for g in problem.groups)
    full = with_groups(problem, extra)
    problems = []
    for k, scenario in enumerate(scenarios):
        if announce is not None:
            announce(f"  the forward process of scenario {k}")
        own = Replanning(process, full, announce, replan_distance=d.replan_distance)
        own.adopt({**full.start, **scenario})  # its first plan: the scenario's own run
        problems.append(own)
    return Scenarios(tuple(problems), names, scenarios, d.robust)


def run_process_taylor(process: Process, groups=None, h=(1.0, 0.5, 0.25, 0.125), progress=None,
                       forward_progress=None, announce=None):  # fmt: skip
    """Taylor test of each group (default: design.variables) of a process's problem."""
    from jaxform.design import taylor_test

    problem = process_problem(process, groups or None, forward_progress, announce)
    if announce is not None:
        announce("  compiling the gradient programs and evaluating the start design")
    return taylor_test(problem, h=h, progress=progress)


def run_process_design(process: Process, out_dir, progress=None, forward_progress=None,
                       announce=None, problem=None):  # fmt: skip
    """Optimize a process's [design] problem (``problem``: the one of a forward run made
    already, :func:`problem_of_plan`), re-running the forward process at a design whose
    replay fails (:class:`Replanning`); write design_history.csv, design_report.csv (start
    and best: the objective, each term, each blow's peak force, each constraint),
    objective.png, config.toml (the process as configured), designed.toml (the process at
    the best design) and the designed dies' profiles (die_profiles.csv, .png;
    :func:`jaxform.designed_config.write_design_files`) to ``out_dir``.  config.toml is
    written first, design_history.csv and designed.toml after each iteration (a design
    stopped early leaves the rows and the best design so far); the report's start and
    best rows come from those designs' evaluations (kept, no further run)."""
    from jaxform.design import DesignHistory, optimize
    from jaxform.driver import design_report, optimizer_settings
    from jaxform.plot import design_objective

    if problem is None:
        problem = process_problem(process, None, forward_progress, announce)
    d = process.operations[0].config.design
    if d.robust:
        problem = robust(process, problem, announce)
    else:
        problem = Replanning(process, problem, announce, replan_distance=d.replan_distance)
    if announce is not None:
        meshes = sum(len(s.segments) for s in problem.plan.stages)
        programs = problem.plan.step_programs()
        announce(f"  compiling the gradient programs ({meshes} meshes, {programs} step "
                 "programs) and evaluating the start design")  # fmt: skip
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    dump_config(process_document(process.document), out / "config.toml")
    hist = DesignHistory()

    def after_each(k, *row):
        """The rows so far to design_history.csv and the best design so far to
        designed.toml after each iteration, so that a design stopped anywhere (interrupted,
        out of time) leaves what it reached; the start design's terms to ``announce``."""
        first = len(hist.objective) == 1  # (sampling counts its runs from 1)
        if first and announce is not None and np.isfinite(hist.objective[0]):
            start = problem.report(hist.designs[0])  # the evaluation just made, kept
            terms = ", ".join(f"{n} {v:.6g}" for n, v in start.items() if n != "constraints")
            announce(f"  start design: {terms}")
        write_csv(out / "design_history.csv", hist.columns(problem))
        write_designed(process, problem, hist.designs[hist.best], out)
        if progress is not None:
            progress(k, *row)

    optimize(problem, optimizer_settings(d), progress=after_each, history=hist)
    if announce is not None and problem.replans:
        announce(f"  {problem.replans} new plans (forward runs at designs whose replay failed "
                 "or that lay beyond design.replan_distance of their plan)")  # fmt: skip
    if announce is not None:  # the best design as `jaxform run` of its config runs it
        own = problem.forward_value(hist.designs[hist.best])
        best = float(hist.objective[hist.best])
        differs = abs(own - best) > 1e-6 * max(abs(best), 1e-12)
        note = (" (they differ: the forward run took other steps, or its Newton solves found "
                "another solution of the contact conditions)") if differs else ""  # fmt: skip
        announce(f"  the best design's own forward run: objective {own:.8g}, its replay "
                 f"{best:.8g}{note}")  # fmt: skip
    write_design_files(process, problem, hist, out, announce)
    write_csv(out / "design_history.csv", hist.columns(problem))
    rows = design_report(problem, hist)
    with open(out / "design_report.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    unit = getattr(problem.objective, "unit", "-")
    title = f"{d.objective} of {d.objective_operation or 'the last blow'} ({d.optimizer})"
    design_objective(hist.objective, out / "objective.png", title, unit)
    return problem, hist
