"""Throughput of a batched design program (jaxform.batch) against a Python loop.

    python experiments/bench_batch.py [--mesh 4] [--batch 16] [--reduction 0.3] [--grad]
    XLA_FLAGS=--xla_force_host_platform_device_count=2 python experiments/bench_batch.py --shard

The friction scene (configs/upsetting_friction.toml: Anand billet, Coulomb friction, q1p0)
on an n x n mesh, a batch of friction coefficients mu in [0.05, 0.5].  Both variants run
the same differentiable run (fixed step schedule, jaxform.gradients.trajectory) and the
same objective (forging work); the loop calls the single-design program once per mu, the
batch calls the vmapped program once.  Times are best of 2 after compilation (compile
times printed separately); --grad times value and gradient instead of the value alone;
--shard lays the batch over every device (jax.devices()) with shard_map.
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxform
from jaxform.batch import BatchProblem, batch_mesh, stack_designs
from jaxform.config import load_config
from jaxform.design import build_problem
from jaxform.design.objectives import ForgingWork
from jaxform.scenes import build_scene


def best_of(fn, repeats=2):
    out, best = None, np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn())
        best = min(best, time.perf_counter() - t0)
    return best, out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--mesh", type=int, default=4)
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--reduction", type=float, default=0.3)
    ap.add_argument("--grad", action="store_true", help="time value and gradient")
    ap.add_argument("--shard", action="store_true", help="shard the batch over jax.devices()")
    args = ap.parse_args()
    jaxform.enable_x64()
    cfg = load_config(
        "configs/upsetting_friction.toml",
        [
            f"mesh.nr={args.mesh}",
            f"mesh.nz={args.mesh}",
            f"die.reduction={args.reduction}",
            "output.fields=false",
            "output.plots=false",
        ],
    )
    scene = build_scene(cfg)
    pb = build_problem(
        scene, groups=("friction",), objective=ForgingWork(), times=scene.step_targets()
    )
    mus = np.linspace(0.05, 0.5, args.batch)
    designs = stack_designs([{"friction": jnp.array([m])} for m in mus])
    batch = BatchProblem(pb, batch_mesh() if args.shard else None)
    single = pb.value_and_grad if args.grad else pb.value
    batched = batch.value_and_grad if args.grad else batch.value

    def loop():
        return [single({"friction": designs["friction"][i]})[0] for i in range(args.batch)]

    t0 = time.perf_counter()
    single({"friction": designs["friction"][0]})
    c_single = time.perf_counter() - t0
    t0 = time.perf_counter()
    batched(designs)
    c_batch = time.perf_counter() - t0
    t_loop, v_loop = best_of(loop)
    t_batch, out = best_of(lambda: batched(designs))
    v_batch, traj = np.asarray(out[0]), out[-1]
    err = np.max(np.abs(np.asarray(v_loop) - v_batch) / np.abs(v_batch))
    its = np.asarray(traj.iterations)
    what = "value+gradient" if args.grad else "value"
    print(
        f"scene: friction upsetting {args.mesh}x{args.mesh} q1p0, {scene.model.layout.n_dofs} "
        f"unknowns ({scene.linear.backend}), {len(pb.times)} steps, {what}, batch "
        f"{args.batch}, devices {len(jax.devices()) if args.shard else 1}"
    )
    print(f"compile: single {c_single:.1f} s, batch {c_batch:.1f} s (first call incl. run)")
    print(f"loop : {t_loop:8.3f} s  {args.batch / t_loop:8.2f} designs/s")
    print(
        f"batch: {t_batch:8.3f} s  {args.batch / t_batch:8.2f} designs/s  "
        f"speed-up {t_loop / t_batch:.2f}x  (max rel. difference {err:.1e})"
    )
    print(
        f"Newton iterations per design: {its.sum(axis=1).min()}..{its.sum(axis=1).max()}; "
        f"the batch pays the slowest lane per step: {its.max(axis=0).sum()}"
    )


if __name__ == "__main__":
    main()
