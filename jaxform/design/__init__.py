"""Gradient-based design: parametrizations, objectives, problems, optimizers, Taylor test.

    problem = build_problem(build_scene(load_config(path)))   # groups/objective from [design]
    history = optimize(problem, OptimizerSettings("lbfgs", iterations=20))
    rows = taylor_test(problem)

Layers: :mod:`requirements` (what each group and objective needs of a scene; no JAX, the
config layer reads it), :mod:`parametrize` (design variables -> run inputs),
:mod:`objectives` (run -> scalar), :mod:`problem` (scene + groups + objective + schedule,
compiled value and gradient), :mod:`optimizers` (optax loops with bounds),
:mod:`sampling` (Latin hypercube with a response surface, CMA-ES), :mod:`spline` (a die
profile as a B-spline and its manufacturability), :mod:`taylor` (gradient check).

Importing the package imports none of them: each name below is loaded from its module on
first use (PEP 562), so the config layer reads :mod:`requirements` without JAX.
"""

import importlib as _importlib

# exported name -> the module that defines it
_EXPORTS = {
    "DesignHistory": "jaxform.design.optimizers",
    "OptimizerSettings": "jaxform.design.optimizers",
    "optimize": "jaxform.design.optimizers",
    "CmaEs": "jaxform.design.sampling",
    "LhsRsm": "jaxform.design.sampling",
    "DesignProblem": "jaxform.design.problem",
    "available_groups": "jaxform.design.problem",
    "build_problem": "jaxform.design.problem",
    "format_table": "jaxform.design.taylor",
    "taylor_test": "jaxform.design.taylor",
}
__all__ = [
    "CmaEs",
    "DesignHistory",
    "DesignProblem",
    "OptimizerSettings",
    "available_groups",
    "build_problem",
    "LhsRsm",
    "format_table",
    "optimize",
    "taylor_test",
]


def __getattr__(name: str):
    """Load an exported name from its module on first use."""
    if name not in _EXPORTS:
        raise AttributeError(f"module 'jaxform.design' has no attribute {name!r}")
    value = getattr(_importlib.import_module(_EXPORTS[name]), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
