"""Design runs from a config: what `jaxform design` and `jaxform taylor-test` do.

config --load_config/build_scene--> Scene --build_problem--> DesignProblem
  design:      optimize -> design_history.csv, objective.png, shapes.png, config.toml
  taylor-test: taylor_test over every design group of the scene (available_groups)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jaxform.config import dump_config, load_config
from jaxform.design.optimize import OptimizerSettings, optimize
from jaxform.design.problem import available_groups, build_problem
from jaxform.design.taylor import taylor_test
from jaxform.io import write_csv
from jaxform.plot import design_objective, design_shapes
from jaxform.precision import require_x64
from jaxform.scenes import build_scene


def run_design(config, overrides=(), out_dir: str | Path = "out/design", progress=None):
    """Optimize the config's [design] problem; write the history and plots to out_dir."""
    require_x64()
    cfg = load_config(config, overrides)
    scene = build_scene(cfg)
    problem = build_problem(scene)
    d = cfg["design"]
    settings = OptimizerSettings(d["optimizer"], d["iterations"], d["learning_rate"])
    hist = optimize(problem, settings, progress=progress)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    dump_config(cfg, out / "config.toml")
    cols = {
        "iteration": np.arange(len(hist.objective)),
        "objective": np.array(hist.objective),
        "grad_norm": np.array(hist.grad_norm),
    }
    phys = [problem.physical(u) for u in hist.designs]
    for key in phys[0]:
        cols[key] = np.array([p[key] for p in phys])
    write_csv(out / "design_history.csv", cols)
    unit = getattr(problem.objective, "unit", "-")
    design_objective(
        hist.objective, out / "objective.png", f"{d['objective']} ({d['optimizer']})", unit
    )
    _, traj0 = problem.value(hist.designs[0])
    _, traj1 = problem.value(hist.designs[-1])
    shapes = {
        "initial design, start": np.asarray(traj0.coords),
        "initial design, end": np.asarray(traj0.positions),
        "optimized, start": np.asarray(traj1.coords),
        "optimized, end": np.asarray(traj1.positions),
    }
    design_shapes(
        shapes,
        np.asarray(scene.mesh.elements),
        out / "shapes.png",
        f"shapes: {d['objective']} {hist.objective[0]:.4g} -> {hist.objective[-1]:.4g} {unit}",
    )
    return problem, hist


def run_taylor(config, overrides=(), groups=None, h=(1.0, 0.5, 0.25, 0.125), progress=None):
    """Taylor test of every design group of the scene (or the ones named)."""
    require_x64()
    scene = build_scene(load_config(config, overrides))
    names = available_groups(scene) if not groups else tuple(groups)
    problem = build_problem(scene, groups=names)
    return taylor_test(problem, h=h, progress=progress)
