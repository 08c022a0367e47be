"""Gradient-based design: parametrizations, objectives, problems, optimizers, Taylor test.

    problem = build_problem(build_scene(load_config(path)))   # groups/objective from [design]
    history = optimize(problem, OptimizerSettings("lbfgs", iterations=20))
    rows = taylor_test(problem)

Layers: :mod:`parametrize` (design variables -> run inputs), :mod:`objectives` (run ->
scalar), :mod:`problem` (scene + groups + objective + schedule, compiled value and
gradient), :mod:`optimize` (optax loops with bounds), :mod:`taylor` (gradient check).
"""

from jaxform.design.optimize import DesignHistory, OptimizerSettings, optimize
from jaxform.design.problem import DesignProblem, available_groups, build_problem
from jaxform.design.taylor import format_table, taylor_test

__all__ = [
    "DesignHistory",
    "DesignProblem",
    "OptimizerSettings",
    "available_groups",
    "build_problem",
    "format_table",
    "optimize",
    "taylor_test",
]
