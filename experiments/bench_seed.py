"""Seed-scene timing: compile vs run time and Newton iterations per step, by mesh size.

    python experiments/bench_seed.py [--meshes 10 20 40] [--element q1q1]

Run time is measured on a second, identical run (the compiled program is reused);
compile time = first run - second run.  The thesis needed 25 minutes (MATLAB) for 10x10.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import jaxform
from jaxform.config import load_config
from jaxform.simulate import build_scene, simulate


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--meshes", type=int, nargs="+", default=[10, 20, 40])
    ap.add_argument("--element", default="q1q1")
    ap.add_argument("--linear", default="auto")
    args = ap.parse_args()
    jaxform.enable_x64()
    print(f"{'mesh':>7} {'unknowns':>8} {'backend':>7} {'first(s)':>9} {'run(s)':>8} "
          f"{'compile(s)':>10} {'newton/step':>11} {'force(N)':>9}")
    for n in args.meshes:
        cfg = load_config("configs/upsetting_seed.toml", [
            f"mesh.nr={n}", f"mesh.nz={n}", f"mesh.element={args.element}",
            f"solver.linear={args.linear}", "output.fields=false", "output.plots=false"])
        t0 = time.perf_counter()
        scene = build_scene(cfg)
        res = simulate(scene)
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        res = simulate(build_scene(cfg))
        second = time.perf_counter() - t0
        its = res.history["newton_iterations"][1:]
        print(f"{n:>3}x{n:<3} {scene.model.layout.n_dofs:>8} {scene.linear.backend:>7} "
              f"{first:9.2f} {second:8.2f} {first - second:10.2f} {np.mean(its):11.2f} "
              f"{res.history['force_N'][-1]:9.2f}", flush=True)


if __name__ == "__main__":
    main()
