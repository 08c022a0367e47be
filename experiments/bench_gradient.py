"""Cost of exact gradients: time of one gradient / time of one forward run, and memory.

    python experiments/bench_gradient.py [--scenes seed friction] [--repeat 5]

For each scene (the seed config, and the seed billet with Coulomb friction 0.3 =
configs/upsetting_friction.toml) on the same fixed step schedule:

* forward:  the differentiable run's value only (problem.value, compiled);
* gradient: value and gradient with respect to every design group of the scene
  (material s0/h0/s_hat, friction, ram speed, 3 preform modes, die points) in one
  reverse pass (problem.value_and_grad, compiled);
* simulate: the ordinary forward run with cutback (jaxform.simulate), for reference.

Times are the best of --repeat runs after compilation; the forward and gradient runs
alternate (forward, gradient, forward, ...), so that load from other jobs on a shared
machine hits both alike, and the ratio is that of the two minima.  Memory: XLA's own account of
the compiled programs (arguments + outputs + temporaries, from memory_analysis()), i.e.
the peak the reverse pass needs, and the process's peak resident set size.
Target (issue): gradient / forward <= 2.
"""

from __future__ import annotations

import argparse
import resource
import time

import jax

import jaxform
from jaxform.config import load_config
from jaxform.design import available_groups, build_problem
from jaxform.scenes import build_scene
from jaxform.simulate import simulate
from timing import interleaved

CONFIGS = {"seed": "configs/upsetting_seed.toml", "friction": "configs/upsetting_friction.toml"}


def best(fn, repeat):
    return interleaved([fn], repeat)[0]


def program_bytes(jitted, *args) -> float:
    m = jitted.lower(*args).compile().memory_analysis()
    if m is None:
        return float("nan")
    return (m.argument_size_in_bytes + m.output_size_in_bytes + m.temp_size_in_bytes) / 2**20


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", nargs="+", default=list(CONFIGS), choices=list(CONFIGS))
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    jaxform.enable_x64()
    rows = []
    for name in args.scenes:
        scene = build_scene(load_config(CONFIGS[name], ["output.fields=false",
                                                       "output.plots=false"]))
        problem = build_problem(scene, groups=available_groups(scene))
        u = problem.start
        t0 = time.perf_counter()
        problem.value(u)
        c_fwd = time.perf_counter() - t0
        t0 = time.perf_counter()
        problem.value_and_grad(u)
        c_grad = time.perf_counter() - t0
        t_fwd, t_grad = interleaved([lambda: problem.value(u)[0],
                                     lambda: problem.value_and_grad(u)[1]], args.repeat)
        t_sim = best(lambda: simulate(scene).history["force_N"], args.repeat)
        mem_fwd = program_bytes(problem._value, u)
        mem_grad = program_bytes(problem._value_and_grad, u)
        n_var = sum(int(v.size) for v in u.values())
        rows.append((name, len(problem.times), n_var, t_sim, t_fwd, t_grad, t_grad / t_fwd,
                     c_fwd, c_grad, mem_fwd, mem_grad))
        print(f"{name}: done", flush=True)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print("\n| scene | steps | design variables | simulate (s) | forward (s) | gradient (s) | "
          "gradient / forward | compile fwd / grad (s) | memory fwd / grad (MiB) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r[0]} | {r[1]} | {r[2]} | {r[3]:.2f} | {r[4]:.2f} | {r[5]:.2f} | {r[6]:.2f} | "
              f"{r[7]:.0f} / {r[8]:.0f} | {r[9]:.1f} / {r[10]:.1f} |")
    print(f"\npeak resident set size of the process: {rss:.0f} MiB")


if __name__ == "__main__":
    main()
