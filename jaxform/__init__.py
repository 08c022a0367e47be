"""jaxform: differentiable finite-element simulation of metal forming in JAX.

The entry points a script needs, one import away (see ``examples/tutorial.py``)::

    import jaxform
    jaxform.enable_x64()
    result = jaxform.run("configs/upsetting_seed.toml", ["mesh.nr=4"], out_dir="out/seed")

* set-up: :func:`enable_x64`, :func:`require_x64` (:mod:`jaxform.precision`),
  :func:`enable_compilation_cache` (a warm start, :mod:`jaxform.cache`; the command line
  and :func:`run` call it);
* runs: :func:`load_config` -> :func:`build_scene` -> :func:`simulate`, or :func:`run`
  for all three and the output files;
* gradients: :func:`trajectory` (a differentiable run), :func:`build_problem` (a design
  problem: groups, objective, compiled value and gradient), :func:`optimize` with
  :class:`OptimizerSettings`, :func:`taylor_test`; :func:`run_design` for a config's
  [design] (a scene's or a process's, ``examples/process_design.py``) with its files.

Beside :func:`simulate` (the host loop, progress and rezoning included), the caller may own
the loop: :func:`init` and :func:`step` advance a scene one converged step at a time.

Importing jaxform imports nothing else (not JAX) and changes no global setting: each
name is loaded from its module on first use (PEP 562).
"""

import importlib as _importlib

# exported name -> the module that defines it
_EXPORTS = {
    "enable_compilation_cache": "jaxform.cache",
    "enable_x64": "jaxform.precision",
    "require_x64": "jaxform.precision",
    "run": "jaxform.driver",
    "run_design": "jaxform.driver",
    "load_config": "jaxform.config",
    "build_scene": "jaxform.scenes",
    "simulate": "jaxform.simulation",
    "init": "jaxform.simulation",
    "step": "jaxform.simulation",
    "trajectory": "jaxform.gradients",
    "build_problem": "jaxform.design.problem",
    "optimize": "jaxform.design.optimizers",
    "OptimizerSettings": "jaxform.design.optimizers",
    "taylor_test": "jaxform.design.taylor",
}
__all__ = [
    "OptimizerSettings",
    "build_problem",
    "build_scene",
    "enable_compilation_cache",
    "enable_x64",
    "load_config",
    "optimize",
    "require_x64",
    "run",
    "run_design",
    "simulate",
    "init",
    "step",
    "taylor_test",
    "trajectory",
]
__version__ = "0.1.0"


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'jaxform' has no attribute {name!r}")
    value = getattr(_importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
