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
from pathlib import Path

from jaxform.cache import enable_compilation_cache
from jaxform.config import dump_config
from jaxform.io import write_csv
from jaxform.precision import require_x64
from jaxform.process_config import Process, check_process_design, process_document
from jaxform.simulation import simulate


def forward_plan(process: Process, progress=None, announce=None):
    """The forward process run (adaptive steps, remeshes, trims) and its
    :class:`jaxform.process_gradients.ProcessPlan`; ``progress`` is each operation's
    step callback (:func:`jaxform.simulation.simulate`), ``announce`` gets a line as each
    operation starts.  Raises ConfigError, SimulationError."""
    from jaxform.process import prepare, run_process
    from jaxform.process_gradients import ProcessPlan

    require_x64()
    ops = process.operations
    initial = prepare(ops)
    enable_compilation_cache(ops[0].config.solver.compilation_cache_dir)
    labels = iter(op.label for op in ops if op.forming or getattr(op.keys, "time_s", None))
    t0 = time.perf_counter()

    def stepped(scene, step_progress, start=None):
        if announce is not None:
            took = time.perf_counter() - t0
            announce(f"  forward run of {next(labels, 'an operation')} ({took:.1f} s)")
        return simulate(scene, step_progress, start)

    result = run_process(ops, initial, progress, simulate_fn=stepped)
    return result, ProcessPlan.of(result)


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
    already, :func:`problem_of_plan`); write design_history.csv, design_report.csv (start
    and best: the objective, each term, each blow's peak force, each constraint),
    objective.png and config.toml (the process as configured) to ``out_dir``."""
    from jaxform.design import optimize
    from jaxform.driver import design_report, optimizer_settings
    from jaxform.plot import design_objective

    if problem is None:
        problem = process_problem(process, None, forward_progress, announce)
    d = process.operations[0].config.design
    if announce is not None:
        meshes = sum(len(s.segments) for s in problem.plan.stages)
        programs = problem.plan.step_programs()
        announce(f"  compiling the gradient programs ({meshes} meshes, {programs} step "
                 "programs) and evaluating the start design")  # fmt: skip
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if announce is not None:  # the start design's terms, before a long optimization
        start = problem.report(problem.start)
        terms = ", ".join(f"{k} {v:.6g}" for k, v in start.items() if k != "constraints")
        announce(f"  start design: {terms}")
    hist = optimize(problem, optimizer_settings(d), progress=progress)
    dump_config(process_document(process.document), out / "config.toml")
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
