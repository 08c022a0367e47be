"""How many step programs a process's gradient replay compiles, what one gradient costs, and
(optionally) the design itself on the same forward run.

    PYTHONPATH=. python experiments/gradient_programs.py CONFIG [--gradient] \
        [--design OUT] [SECTION.KEY=VALUE ...]

Runs the forward process of CONFIG (a process config with [design], e.g.
experiments/two_stage_disk_design.toml) once and prints, per operation, its steps, its
remeshes (and how many a quality trigger fired), its peak force, and for an operation
with a die fill its fill and flash; then the distinct step programs of the gradient
replay (:meth:`jaxform.process_gradients.ProcessPlan.step_programs`), once with every
mesh's steps as one run (the rule before :func:`jaxform.gradients.step_chunks`) and once
in the runs that function makes.  With --gradient: one value_and_grad of the config's
[design] problem at its start design (compile included) and once more (warm), and the
peak resident memory so far (``ru_maxrss``; run under ``/usr/bin/time -v`` for the
whole process's).  With --design OUT: then the design itself
(:func:`jaxform.process_design.run_process_design` on this forward run: what ``jaxform
design CONFIG --out OUT`` does after its own forward run), its progress per iteration.
"""

from __future__ import annotations

import resource
import sys
import time

import numpy as np

import jaxform
from jaxform.process_config import load_typed
from jaxform.process_design import forward_plan, problem_of_plan, run_process_design


def _summary(result) -> None:
    for run in result.runs:
        h, rem = run.result.history, run.result.remeshes
        quality = sum("quality" in (r.trigger or "") for r in rem)
        force = max((float(np.max(np.abs(h[k]))) for k in h if k.startswith("force_")),
                    default=0.0)  # fmt: skip
        line = (f"  {run.operation.label}: {len(h['time_s']) - 1} steps, "
                f"{int(np.sum(h['newton_iterations']))} Newton iterations, {len(rem)} remeshes "
                f"({quality} by quality), peak force {force:.0f} N")  # fmt: skip
        if "die_fill" in h:
            line += (f", fill {100 * float(h['die_fill'][-1]):.3f} %, flash "
                     f"{float(h['flash_volume_mm3'][-1]):.2f} mm^3")  # fmt: skip
        print(line, flush=True)


def main(argv):
    jaxform.enable_x64()
    args = iter(argv)
    path, overrides, out, gradient = None, [], None, False
    for a in args:
        if a == "--design":
            out = next(args)
        elif a == "--gradient":
            gradient = True
        elif "=" in a:
            overrides.append(a)
        else:
            path = a
    process = load_typed(path, overrides)
    t0 = time.perf_counter()
    result, plan = forward_plan(process)
    print(f"forward process run: {time.perf_counter() - t0:.1f} s (compile included)", flush=True)
    _summary(result)
    meshes = [len(s.segments) for s in plan.stages]
    buckets = {seg.padded.bucket for s in plan.stages for seg in s.segments if seg.padded}
    print(f"meshes per operation {meshes}, {len(buckets)} capacity buckets", flush=True)
    for chunked in (False, True):
        how = "runs of 8, 4, 2, 1" if chunked else "one run a mesh"
        print(f"step programs ({how}): {plan.step_programs(chunked)} (x2 with their "
              f"reverse passes)", flush=True)  # fmt: skip
    problem = problem_of_plan(process, plan)
    if gradient:
        for label in ("compile included", "warm"):
            t0 = time.perf_counter()
            val, grad, _ = problem.value_and_grad(problem.start)
            took = time.perf_counter() - t0
            rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2
            print(f"value_and_grad ({label}): {took:.1f} s, J = {float(val):.8g}, "
                  f"peak RSS so far {rss:.2f} GB", flush=True)  # fmt: skip
        print("gradient:", {k: np.asarray(v).round(6).tolist() for k, v in grad.items()})
    if out is None:
        return
    t0 = time.perf_counter()

    def progress(it, val, gnorm, design):
        print(f"iteration {it:3d}: objective {val:.8g}  |projected grad| {gnorm:.3e}  "
              f"({time.perf_counter() - t0:.1f} s)", flush=True)  # fmt: skip

    problem, hist = run_process_design(process, out, progress, announce=print, problem=problem)
    print(f"design: {len(hist.objective)} iterations, best {hist.best}, "
          f"{time.perf_counter() - t0:.1f} s after the forward run", flush=True)  # fmt: skip


if __name__ == "__main__":
    main(sys.argv[1:])
