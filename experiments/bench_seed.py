"""Seed-scene timing: compile vs run time and Newton iterations per step, by mesh size.

    python experiments/bench_seed.py [--meshes 10 20 40] [--element q1q1]
    python experiments/bench_seed.py --friction     # friction scene and ring vs frictionless

Run time is measured on a second, identical run (the compiled program is reused);
compile time = first run - second run.  The thesis needed 25 minutes (MATLAB) for 10x10.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from timing import cold_and_warm

import jaxform
from jaxform.config import load_config
from jaxform.scenes import build_scene
from jaxform.simulation import simulate


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--meshes", type=int, nargs="+", default=[10, 20, 40])
    ap.add_argument("--element", default="q1q1")
    ap.add_argument("--linear", default="auto")
    ap.add_argument(
        "--friction",
        action="store_true",
        help="time configs/upsetting_friction.toml and configs/ring_compression.toml "
        "against the same scenes without friction",
    )
    args = ap.parse_args()
    jaxform.enable_x64()
    if args.friction:
        return friction_rows()
    print(
        f"{'mesh':>7} {'unknowns':>8} {'backend':>7} {'first(s)':>9} {'run(s)':>8} "
        f"{'compile(s)':>10} {'newton/step':>11} {'force(N)':>9}"
    )
    for n in args.meshes:
        cfg = load_config(
            "configs/upsetting_seed.toml",
            [
                f"mesh.nr={n}",
                f"mesh.nz={n}",
                f"mesh.element={args.element}",
                f"solver.linear={args.linear}",
                "output.fields=false",
                "output.plots=false",
            ],
        )
        scene, res, first, second = cold_and_warm(cfg)
        its = res.history["newton_iterations"][1:]
        print(
            f"{n:>3}x{n:<3} {scene.model.layout.n_dofs:>8} {scene.linear.backend:>7} "
            f"{first:9.2f} {second:8.2f} {first - second:10.2f} {np.mean(its):11.2f} "
            f"{res.history['force_N'][-1]:9.2f}",
            flush=True,
        )


def _timed(path, overrides):
    cfg = load_config(path, overrides + ["output.fields=false", "output.plots=false"])
    simulate(build_scene(cfg))  # compile
    t0 = time.perf_counter()
    res = simulate(build_scene(cfg))
    return time.perf_counter() - t0, float(np.mean(res.history["newton_iterations"][1:]))


def friction_rows():
    print(f"{'scene':>36} {'run(s)':>7} {'newton/step':>11} {'ratio to frictionless':>22}")
    for path, label in (
        ("configs/upsetting_friction.toml", "upsetting, Coulomb mu = 0.3"),
        ("configs/ring_compression.toml", "ring 6:3:2, shear m = 0.3"),
    ):
        t_f, it_f = _timed(path, [])
        t_0, it_0 = _timed(path, ["friction.model=none"])
        print(f"{label:>36} {t_f:7.2f} {it_f:11.2f} {it_f / it_0:22.2f}")
        print(f"{'  same, frictionless':>36} {t_0:7.2f} {it_0:11.2f}", flush=True)


if __name__ == "__main__":
    main()
