"""Side by side on one design problem: the gradient design (L-BFGS) against the sampling
optimizers of the commercial codes (a Latin hypercube with a quadratic response surface,
and CMA-ES), counted in simulations (runs of the process: a value-and-gradient run
counts one).

    python experiments/design_comparison.py CONFIG [--set section.key=value ...]
        [--out out/design_comparison] [--iterations N] [--budget N] [--seed S]

CONFIG is any config with a [design] section (its groups, objective, bounds; the problem
comes from :func:`jaxform.driver.design_problem`, the entry point of ``jaxform design``),
a scene's or a process's (evaluated on plans that follow the design, as ``jaxform
design`` does: :class:`jaxform.process_design.Replanning`).
L-BFGS runs design.iterations iterations (or --iterations); LHS-RSM
design.samples_per_variable runs per variable and design.rsm_rounds verifications;
CMA-ES design.population per generation up to --budget runs (default
design.max_simulations).  Writes design_comparison.csv (optimizer, simulations,
objective, best_objective: one row per history row), design_comparison.png (the best
objective against simulations for the three) and design_comparison_best.csv (each
optimizer's best design in the config's units), and prints a table: simulations used,
best objective, the runs each needed to come within 1 % of the best objective any of
them reached, wall time.
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import numpy as np

import jaxform
from jaxform.design import CmaEs, DesignHistory, LhsRsm, OptimizerSettings, optimize
from jaxform.driver import design_problem
from jaxform.plot import design_comparison
from jaxform.process_config import Process, load_typed
from jaxform.process_design import Replanning, process_problem, robust


def optimizers(d, args) -> dict:
    """label -> settings, from the config's [design] and the command line."""
    budget = args.budget or d.max_simulations
    return {
        "gradient (L-BFGS)": OptimizerSettings("lbfgs", args.iterations or d.iterations),
        "LHS-RSM": LhsRsm(d.samples_per_variable, d.rsm_rounds, d.max_simulations, args.seed),
        "CMA-ES": CmaEs(d.population, d.cmaes_sigma, budget, args.seed),
    }


def design_of(config, overrides):
    """([design], the design problem, its steps) of a scene config (jaxform design's
    problem) or of a process config (its problem on plans that follow the design, as
    `jaxform design` builds it; robust where design.robust says so)."""
    loaded = load_typed(config, overrides)
    if not isinstance(loaded, Process):
        cfg, problem = design_problem(loaded)
        return cfg.design, problem, len(problem.times)
    d = loaded.operations[0].config.design
    problem = process_problem(loaded)
    steps = sum(len(s.times) for s in problem.plan.stages if s.stepped)
    if d.robust:
        wrapped = robust(loaded, problem)
    else:
        wrapped = Replanning(loaded, problem, replan_distance=d.replan_distance)
    return d, wrapped, steps


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("config")
    ap.add_argument("--set", action="append", default=[], dest="overrides")
    ap.add_argument("--out", default="out/design_comparison")
    ap.add_argument("--iterations", type=int, default=0, help="L-BFGS iterations")
    ap.add_argument("--budget", type=int, default=0, help="CMA-ES runs")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--only", default="", help="comma-separated labels to run (default all)")
    args = ap.parse_args(argv)
    jaxform.enable_x64()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    d, problem, steps = design_of(args.config, args.overrides)
    sizes = {k: int(np.size(v)) for k, v in problem.start.items()}
    print(f"problem: {steps} steps, variables {sizes}, objective "
          f"{d.objective} ({time.perf_counter() - t0:.1f} s)", flush=True)  # fmt: skip
    runs, rows, best_rows = {}, [], []
    chosen = optimizers(d, args)
    if args.only:
        chosen = {k: v for k, v in chosen.items() if any(w in k for w in args.only.split(","))}
    for label, settings in chosen.items():
        t1 = time.perf_counter()
        hist = DesignHistory()

        def progress(k, val, extra, design, label=label, t1=t1, hist=hist):
            print(f"  {label} {k:4d}: objective {val:.8g} ({time.perf_counter() - t1:.1f} s, "
                  f"{hist.evaluations} runs)", flush=True)  # fmt: skip
            # the rows so far (a comparison stopped early leaves them)
            _write(out / "design_comparison.csv", rows + _rows(label, hist))

        print(f"{label}:", flush=True)
        hist = optimize(problem, settings, progress=progress, history=hist)
        runs[label] = (hist, time.perf_counter() - t1)
        rows += _rows(label, hist)
        best_rows.append(dict(optimizer=label, objective=hist.objective[hist.best],
                              **problem.physical(hist.designs[hist.best])))  # fmt: skip
        print(f"  {hist.stop_reason}", flush=True)
    _write(out / "design_comparison.csv", rows)
    _write(out / "design_comparison_best.csv", best_rows)
    unit = getattr(problem.objective, "unit", "-")
    curves = {}
    for label, (h, _) in runs.items():  # to the last run (a line search's rejected trials)
        best = h.best_so_far()
        curves[label] = (np.append(h.simulations, h.evaluations), np.append(best, best[-1]))
    design_comparison(curves, out / "design_comparison.png",
                      f"{Path(args.config).stem}: best objective vs simulations", unit)  # fmt: skip
    overall = min(float(h.objective[h.best]) for h, _ in runs.values())
    tol = overall + 0.01 * abs(overall)
    print(f"\n{'optimizer':<20}{'simulations':>12}{'best objective':>17}"
          f"{'runs to 1 %':>13}{'time (s)':>10}")  # fmt: skip
    for label, (h, wall) in runs.items():
        reach = np.nonzero(h.best_so_far() <= tol)[0]
        within = str(h.simulations[reach[0]]) if len(reach) else "-"
        print(f"{label:<20}{h.evaluations:>12d}{h.objective[h.best]:>17.8g}"
              f"{within:>13}{wall:>10.1f}")  # fmt: skip
    print(f"outputs in {out}: design_comparison.csv, design_comparison.png, "
          "design_comparison_best.csv")  # fmt: skip
    return 0


def _rows(label: str, hist) -> list[dict]:
    return [dict(optimizer=label, simulations=s, objective=f, best_objective=b)
            for s, f, b in zip(hist.simulations, hist.objective, hist.best_so_far())]  # fmt: skip


def _write(path: Path, rows: list[dict]) -> None:
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


if __name__ == "__main__":
    raise SystemExit(main())
