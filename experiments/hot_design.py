"""Design and identification with exact thermal gradients (coupled hot upsetting).

    python experiments/hot_design.py peak        [--out docs/figures] [--mesh 4]
    python experiments/hot_design.py conductance [--out docs/figures] [--mesh 4]

The scene is configs/hot_upsetting.toml (the seed billet between dies at 473 K, shear
friction 0.3, 50 % reduction) on a coarser mesh.

* ``peak``: choose the billet temperature (group 'thermal', design.thermal_params =
  billet_temperature_K, within +-200 K of 673 K) and the ram speed (group 'speed', within
  a factor 2 of 7.5 mm/s) that minimize the peak ram force, with the hottest node kept
  below --limit K (default 700 K).  The limit is an exterior quadratic penalty
  (design.max_temperature_K, design.temperature_penalty N/K^2, summed over the steps);
  the box bounds are projected.  A hotter billet flows at a lower stress; plastic work
  heats it further, so the limit caps how hot it may start.
* ``conductance``: a twin experiment: the target is the mean-temperature history of the
  run with h_die = 10 kW/m^2 K; the design starts from 5 kW/m^2 K (group 'thermal',
  htc_die_W_m2K) and minimizes the mean squared temperature misfit (K^2).

Writes hot_<study>_history.csv (iteration, objective, gradient norm, physical values) and
hot_<study>_design.png, and prints what was found.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import jaxform
from jaxform.config import load_config
from jaxform.design import OptimizerSettings, build_problem, optimize
from jaxform.design.objectives import TemperatureMisfit
from jaxform.io import write_csv
from jaxform.plot import design_objective
from jaxform.postprocess import nodal_volumes
from jaxform.scenes import build_scene


def scene(mesh: int, *overrides):
    over = [f"mesh.nr={mesh}", f"mesh.nz={mesh}", "time.dt_s=0.025", *overrides]
    return build_scene(load_config("configs/hot_upsetting.toml", over))


def peak_study(mesh: int, limit_k: float):
    sc = scene(mesh, "design.objective=peak_force", f"design.max_temperature_K={limit_k}",
               "design.temperature_penalty=5.0", 'design.thermal_params=["billet_temperature_K"]',
               "design.variables=[\"thermal\", \"speed\"]")  # fmt: skip
    problem = build_problem(sc, groups=("thermal", "speed"))
    return problem, problem.start, None


def conductance_study(mesh: int):
    sc = scene(mesh, 'design.thermal_params=["htc_die_W_m2K"]', 'design.variables=["thermal"]')
    truth = build_problem(sc, groups=("thermal",))
    _, traj = truth.value(truth.start)  # h_die = 10 kW/m^2 K
    w = nodal_volumes(sc)
    mean = np.asarray(traj.temperature_K) @ w / w.sum()
    target = TemperatureMisfit(np.asarray(traj.time_s)[1:], mean[1:], w)
    problem = build_problem(sc, groups=("thermal",), objective=target, times=truth.times)
    return problem, {"thermal": np.array([np.log(0.5)])}, {"thermal": np.zeros(1)}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("study", choices=("peak", "conductance"))
    ap.add_argument("--out", default="docs/figures")
    ap.add_argument("--mesh", type=int, default=4)
    ap.add_argument("--limit", type=float, default=700.0, help="peak: T_max limit (K)")
    ap.add_argument("--iterations", type=int, default=20)
    args = ap.parse_args()
    jaxform.enable_x64()
    t0 = time.perf_counter()
    if args.study == "peak":
        problem, start, truth = peak_study(args.mesh, args.limit)
    else:
        problem, start, truth = conductance_study(args.mesh)

    def progress(it, val, gnorm, design):
        phys = ", ".join(f"{k} {v:.6g}" for k, v in problem.physical(design).items())
        print(f"iteration {it:3d}: objective {val:.6e} |grad| {gnorm:.3e} ({phys}; "
              f"{time.perf_counter() - t0:.1f} s)", flush=True)  # fmt: skip

    hist = optimize(
        problem, OptimizerSettings("lbfgs", args.iterations), design=start, progress=progress
    )
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cols = hist.columns(problem)
    _, traj = problem.value(hist.designs[-1])
    n = len(hist.designs)
    cols["peak_force_N"] = np.full(n, np.nan)
    cols["peak_force_N"][-1] = float(np.max(np.asarray(traj.force_N)))
    cols["max_temperature_K"] = np.full(n, np.nan)
    cols["max_temperature_K"][-1] = float(np.max(np.asarray(traj.temperature_K)))
    write_csv(out / f"hot_{args.study}_history.csv", cols)
    design_objective(hist.objective, out / f"hot_{args.study}_design.png",
                     f"hot upsetting: {args.study}", problem.objective.unit)  # fmt: skip
    print(f"done in {time.perf_counter() - t0:.1f} s ({hist.stop_reason}): "
          f"{len(hist.objective) - 1} iterations, {hist.evaluations} evaluations")  # fmt: skip
    print(f"objective {hist.objective[0]:.6e} -> {hist.objective[-1]:.6e}")
    print(f"start {problem.physical(hist.designs[0])}\nfound {problem.physical(hist.designs[-1])}")
    print(f"peak force {cols['peak_force_N'][-1]:.2f} N, "
          f"max temperature {cols['max_temperature_K'][-1]:.2f} K")  # fmt: skip
    if truth is not None:
        print(f"true  {problem.physical(truth)}")


if __name__ == "__main__":
    main()
