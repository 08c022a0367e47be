"""Forward and gradient time of a process (default: configs/two_stage_disk.toml), and the
gradient checks of its design groups (central differences, Taylor rates).

    PYTHONPATH=. python experiments/bench_process_gradient.py [CONFIG] [--checks]

Prints: the forward process run (adaptive steps, remeshes) cold and warm, the
differentiable replay's value and gradient cold and warm, their ratio to the warm
forward run; with --checks, per group |FD - AD| / |AD| (h = 1e-4, unit direction) and the
Taylor test's smallest second-order rate.  The objective: the finisher's unfilled cavity
+ 1e-2 x its flash volume (mm^3) + 1e-5 x the blocker's peak force (N).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import jaxform  # noqa: E402
from jaxform.design import taylor_test  # noqa: E402
from jaxform.design.process_problem import (  # noqa: E402
    WeightedSum,
    build_process_problem,
    process_objective,
)
from jaxform.process import prepare, run_process  # noqa: E402
from jaxform.process_config import load_typed  # noqa: E402
from jaxform.process_gradients import ProcessPlan  # noqa: E402

GROUPS = ("blocker.die", "blocker.friction", "finisher.friction", "blocker.speed", "billet",
          "thermal", "transfer.dwell")  # fmt: skip


def main(argv):
    jaxform.enable_x64()
    from jaxform.cache import enable_compilation_cache

    path = next((a for a in argv if not a.startswith("--")), "configs/two_stage_disk.toml")
    process = load_typed(path)
    enable_compilation_cache(process.operations[0].config.solver.compilation_cache_dir)
    ops = process.operations
    times = {}
    for label in ("forward (first)", "forward (warm)"):
        t0 = time.perf_counter()
        result = run_process(ops, prepare(ops))
        times[label] = time.perf_counter() - t0
        print(f"{label}: {times[label]:.1f} s", flush=True)
    plan = ProcessPlan.of(result)
    steps = [len(s.times) for s in plan.stages]
    meshes = [len(s.segments) for s in plan.stages]
    print(f"steps per operation {steps}, meshes per operation {meshes}", flush=True)
    obj = WeightedSum((
        (1.0, process_objective(plan, "die_fill", "finisher")),
        (1e-2, process_objective(plan, "flash_volume", "finisher")),
        (1e-5, process_objective(plan, "peak_force", "blocker")),
    ))  # fmt: skip
    pb = build_process_problem(plan, GROUPS, obj)
    for label in ("gradient (first)", "gradient (warm)"):
        t0 = time.perf_counter()
        val, grad, _ = pb.value_and_grad(pb.start)
        times[label] = time.perf_counter() - t0
        print(f"{label}: {times[label]:.1f} s, J = {float(val):.10g}", flush=True)
    for label in ("value (first)", "value (warm)"):
        t0 = time.perf_counter()
        pb.value(pb.start)
        times[label] = time.perf_counter() - t0
        print(f"{label}: {times[label]:.1f} s", flush=True)
    ratio = times["gradient (warm)"] / times["forward (warm)"]
    print(f"gradient / forward (warm): {ratio:.2f}", flush=True)
    print("gradient:", {k: np.asarray(v).round(6).tolist() for k, v in grad.items()}, flush=True)
    if "--checks" not in argv:
        return
    from fd_check import directional_derivatives

    rows = []
    for g in GROUPS:
        exact, fd = directional_derivatives(pb, grad, g)
        rel = abs(fd - exact) / abs(exact)
        print(f"{g}: AD {exact:.8e} FD {fd:.8e} |FD-AD|/|AD| {rel:.2e}", flush=True)
        rows.append([g, rel])
    for r, row in zip(taylor_test(pb), rows):
        print(f"{r.group}: |FD-AD|/|AD| {row[1]:.2e}, Taylor min rate {r.min_rate:.3f}",
              flush=True)  # fmt: skip


if __name__ == "__main__":
    main(sys.argv[1:])
