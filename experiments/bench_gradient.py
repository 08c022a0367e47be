"""Cost of exact gradients: time of one gradient / time of one forward run, and memory.

    python experiments/bench_gradient.py [--scenes seed friction] [--repeat 5]

For each scene (the seed config, and the seed billet with Coulomb friction 0.3 =
configs/upsetting_friction.toml) on the same fixed step schedule:

* forward:  the differentiable run's value only (problem.value, compiled);
* gradient: value and gradient with respect to every design group of the scene
  (material s0/h0/s_hat, friction, ram speed, 3 preform modes, die points) in one
  reverse pass (problem.value_and_grad, compiled);
* simulate: the ordinary forward run with cutback (jaxform.simulation), for reference.

Times are the best of --repeat runs after compilation; the forward and gradient runs
alternate (forward, gradient, forward, ...), so that load from other jobs on a shared
machine hits both alike, and the ratio is that of the two minima.  Memory: XLA's own account of
the compiled programs (arguments + outputs + temporaries, from memory_analysis()), i.e.
the peak the reverse pass needs, and the process's peak resident set size.
Target (issue): gradient / forward <= 2.

    python experiments/bench_gradient.py --adjoint 100 [--steps 6] [--repeat 3]

Reverse pass with and without the forward factorizations kept for it: the seed scene on
an N x N mesh over its first --steps steps (klujax), gradient with respect to the
material parameters, once with solver.adjoint_memory_mb = 0 (each reverse step factors
its Jacobian) and once with the default budget (each reverse step refines with the
forward pass's last factorization of that step).  Both programs alternate; reported:
forward, gradient, and gradient - forward (the reverse pass), the kept steps, the
difference of the two gradients and the process's peak resident set size.
"""

from __future__ import annotations

import argparse
import resource
import time
from dataclasses import replace

import numpy as np
from timing import interleaved

import jaxform
from jaxform.config import load_config
from jaxform.design import available_groups, build_problem
from jaxform.gradients import kept_steps
from jaxform.scenes import build_scene
from jaxform.simulation import simulate

CONFIGS = {"seed": "configs/upsetting_seed.toml", "friction": "configs/upsetting_friction.toml"}


def best(fn, repeat):
    return interleaved([fn], repeat)[0]


def program_bytes(jitted, *args) -> float:
    m = jitted.lower(*args).compile().memory_analysis()
    if m is None:
        return float("nan")
    return (m.argument_size_in_bytes + m.output_size_in_bytes + m.temp_size_in_bytes) / 2**20


def adjoint_reuse(n: int, steps: int, repeat: int) -> None:
    """Gradient with and without kept factorizations on an n x n seed mesh."""
    over = [
        "output.fields=false",
        "output.plots=false",
        f"mesh.nr={n}",
        f"mesh.nz={n}",
        "solver.linear=sparse",
    ]
    problems = {}
    for label, budget in (("factor again", "0"), ("reuse", "1e6")):
        scene = build_scene(
            load_config(CONFIGS["seed"], over + [f"solver.adjoint_memory_mb={budget}"])
        )
        pb = build_problem(scene, groups=("material",))
        pb = replace(pb, times=pb.times[:steps])
        t0 = time.perf_counter()
        val, grad, _ = pb.value_and_grad(pb.start)
        fac_mb = (
            scene.linear.factor_bytes(
                scene.model.layout.n_dofs, len(scene.idx.rows), scene.idx.lu_symbolic
            )
            / 2**20
        )
        print(
            f"{label}: compile + first run {time.perf_counter() - t0:.1f} s, kept steps "
            f"{kept_steps(scene, steps)} of {steps}, one factorization "
            f"{fac_mb:.1f} MB (estimate)",
            flush=True,
        )
        problems[label] = (pb, grad)
    (pa, ga), (pb, gb) = problems["factor again"], problems["reuse"]
    diff = max(float(np.max(np.abs(ga[k] - gb[k]) / np.maximum(np.abs(ga[k]), 1e-300))) for k in ga)
    u = pa.start
    t = interleaved(
        [
            lambda: pa.value(u)[0],
            lambda: pa.value_and_grad(u)[1],
            lambda: pb.value(u)[0],
            lambda: pb.value_and_grad(u)[1],
        ],
        repeat,
    )
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"\n{n} x {n} seed mesh, {steps} steps, best of {repeat} interleaved:")
    print("| adjoint solve | forward (s) | gradient (s) | reverse pass (s) |")
    print("|---|---|---|---|")
    print(f"| factor again | {t[0]:.2f} | {t[1]:.2f} | {t[1] - t[0]:.2f} |")
    print(f"| reuse the forward factorization | {t[2]:.2f} | {t[3]:.2f} | {t[3] - t[2]:.2f} |")
    print(
        f"largest relative difference of the gradients: {diff:.1e}; "
        f"peak resident set size {rss:.0f} MiB"
    )


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", nargs="+", default=list(CONFIGS), choices=list(CONFIGS))
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument(
        "--adjoint",
        type=int,
        default=0,
        metavar="N",
        help="compare the reverse pass with and without kept factorizations "
        "on an N x N seed mesh instead",
    )
    ap.add_argument("--steps", type=int, default=6)
    ap.add_argument(
        "--set",
        nargs="*",
        default=[],
        metavar="KEY=VALUE",
        help="config overrides for the scenes (e.g. solver.adjoint_memory_mb=0)",
    )
    args = ap.parse_args()
    jaxform.enable_x64()
    if args.adjoint:
        adjoint_reuse(args.adjoint, args.steps, args.repeat)
        return
    rows = []
    for name in args.scenes:
        scene = build_scene(
            load_config(CONFIGS[name], ["output.fields=false", "output.plots=false", *args.set])
        )
        problem = build_problem(scene, groups=available_groups(scene))
        u = problem.start
        t0 = time.perf_counter()
        problem.value(u)
        c_fwd = time.perf_counter() - t0
        t0 = time.perf_counter()
        problem.value_and_grad(u)
        c_grad = time.perf_counter() - t0
        t_fwd, t_grad = interleaved(
            [lambda: problem.value(u)[0], lambda: problem.value_and_grad(u)[1]], args.repeat
        )
        t_sim = best(lambda: simulate(scene).history["force_N"], args.repeat)
        mem_fwd = program_bytes(problem._value, u, scene.idx)
        mem_grad = program_bytes(problem._value_and_grad, u, scene.idx)
        n_var = sum(int(v.size) for v in u.values())
        rows.append(
            (
                name,
                len(problem.times),
                n_var,
                t_sim,
                t_fwd,
                t_grad,
                t_grad / t_fwd,
                c_fwd,
                c_grad,
                mem_fwd,
                mem_grad,
            )
        )
        print(f"{name}: done", flush=True)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(
        "\n| scene | steps | design variables | simulate (s) | forward (s) | gradient (s) | "
        "gradient / forward | compile fwd / grad (s) | memory fwd / grad (MiB) |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r[0]} | {r[1]} | {r[2]} | {r[3]:.2f} | {r[4]:.2f} | {r[5]:.2f} | {r[6]:.2f} | "
            f"{r[7]:.0f} / {r[8]:.0f} | {r[9]:.1f} / {r[10]:.1f} |"
        )
    print(f"\npeak resident set size of the process: {rss:.0f} MiB")


if __name__ == "__main__":
    main()
