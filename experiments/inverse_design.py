"""Inverse design studies with exact gradients: identify material parameters, design a die.

    python experiments/inverse_design.py material [--out docs/figures] [--mesh 4]
    python experiments/inverse_design.py die      [--out docs/figures] [--mesh 6]

Both are twin experiments: a target is made by a run with known "true" inputs, then the
design loop (L-BFGS with bounds, jaxform.design) starts away from them and must find them.

* ``material``: frictionless upsetting of the seed billet (Al 1100-O at 673 K, 56.3 %);
  the target is the force-stroke curve of the true Anand parameters; the design starts
  with s0, h0 and s_hat all 30 % low (x 0.7) and minimizes the relative L2 force misfit.
* ``die``: the seed billet upset 30 % with Coulomb friction 0.2 by a top die whose
  profile is a polyline of 4 points (r = 0, 1.5, 3, 4.5 mm); the target is the final
  shape of the top and side surfaces made by a dished die (points raised by 0, 0.05,
  0.12, 0.2 mm); the design starts from the flat die and moves the 4 points' heights
  (bounds +-0.3 mm; a trial die that cuts into the billet at the start is a rejected step).

Writes <study>_history.csv (iteration, objective, gradient norm, parameters) and
<study>_design.png (objective against iteration), and prints the recovered values.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import jaxform
from jaxform.config import load_config
from jaxform.design import OptimizerSettings, build_problem, optimize
from jaxform.design.objectives import ForceMisfit, ShapeTarget
from jaxform.io import write_csv
from jaxform.plot import design_objective
from jaxform.scenes import build_scene


def material_study(mesh: int):
    cfg = {
        "billet": {"diameter_mm": 5.0, "height_mm": 7.5},
        "mesh": {"nr": mesh, "nz": mesh, "element": "q1p0"},
        "die": {"speed_mm_s": 0.075, "reduction": 0.563},
        "time": {"dt_s": 2.0},
        "design": {
            "variables": ["material"],
            "objective": "forging_work",
            "material_params": ["s0_MPa", "h0_MPa", "s_hat_MPa"],
        },
    }
    scene = build_scene(load_config(cfg))
    truth = build_problem(scene, groups=("material",))
    _, traj = truth.value(truth.start)  # u = 0: the preset's parameters
    target = ForceMisfit(np.asarray(traj.stroke_mm)[1:], np.asarray(traj.force_N)[1:])
    problem = build_problem(scene, groups=("material",), objective=target, times=truth.times)
    start = {"material": np.full(3, np.log(0.7))}
    return problem, start, {"material": np.zeros(3)}


def die_study(mesh: int):
    top = 3.75
    r_pts = [0.0, 1.5, 3.0, 4.5]
    true_dz = np.array([0.0, 0.05, 0.12, 0.2])

    def scene_with(dz):
        cfg = {
            "billet": {"diameter_mm": 5.0, "height_mm": 7.5},
            "mesh": {"nr": mesh, "nz": mesh, "element": "q1p0"},
            "die": {
                "speed_mm_s": 0.075,
                "reduction": 0.3,
                "profile_mm": [[r, top + d] for r, d in zip(r_pts, dz)],
            },
            "friction": {"model": "coulomb", "mu": 0.2},
            "time": {"dt_s": 1.5},
            "design": {"variables": ["die"], "die_offset_max_mm": 0.3},
        }
        return build_scene(load_config(cfg))

    truth = build_problem(scene_with(true_dz), groups=("die",))
    _, traj = truth.value(truth.start)
    scene = scene_with(np.zeros(4))
    sets = scene.mesh.node_sets
    nodes = np.unique(np.concatenate([sets["top"], sets["side"]]))
    target = ShapeTarget(nodes, np.asarray(traj.positions)[nodes])
    problem = build_problem(scene, groups=("die",), objective=target, times=truth.times)
    return problem, {"die": np.zeros(4)}, {"die": true_dz}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("study", choices=("material", "die"))
    ap.add_argument("--out", default="docs/figures")
    ap.add_argument("--mesh", type=int, default=None)
    ap.add_argument("--iterations", type=int, default=25)
    args = ap.parse_args()
    jaxform.enable_x64()
    t0 = time.perf_counter()
    build = material_study if args.study == "material" else die_study
    problem, start, truth = build(args.mesh or (4 if args.study == "material" else 6))

    def progress(it, val, gnorm, design):
        print(
            f"iteration {it:3d}: objective {val:.6e} |grad| {gnorm:.3e} "
            f"({time.perf_counter() - t0:.1f} s)",
            flush=True,
        )

    hist = optimize(
        problem, OptimizerSettings("lbfgs", args.iterations), design=start, progress=progress
    )
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cols = hist.columns(problem)
    write_csv(out / f"{args.study}_history.csv", cols)
    design_objective(
        hist.objective,
        out / f"{args.study}_design.png",
        f"{args.study}: twin experiment (L-BFGS)",
        problem.objective.unit,
    )
    true_phys, found = problem.physical(truth), problem.physical(hist.designs[-1])
    start_phys = problem.physical(hist.designs[0])
    print(
        f"done in {time.perf_counter() - t0:.1f} s ({hist.stop_reason}): "
        f"{len(hist.objective) - 1} iterations, {hist.evaluations} gradient evaluations"
    )
    print(f"objective {hist.objective[0]:.4e} -> {hist.objective[-1]:.4e}")
    for k in true_phys:
        err = found[k] - true_phys[k]
        rel = f" ({100 * err / true_phys[k]:+.3f} %)" if true_phys[k] != 0 else ""
        print(
            f"  {k:>14}: start {start_phys[k]:.6g}  found {found[k]:.6g}  "
            f"true {true_phys[k]:.6g}  error {err:+.3e}{rel}"
        )


if __name__ == "__main__":
    main()
