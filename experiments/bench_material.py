"""Material-point throughput: Anand updates and consistent tangents per second.

    python experiments/bench_material.py [--points 100000] [--repeats 5]

vmapped over N points (float64, CPU), each point a random plastic step of the Al 1100-O
preset from a pre-strained state.  Prints updates/s and tangent evaluations/s (the
tangent is jax.jacfwd of the update w.r.t. the 3x3 relative deformation gradient).
Compilation is excluded (timed separately).
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxform
from jaxform.kinematics import step_kinematics
from jaxform.materials import MaterialState, load_material


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--points", type=int, default=100_000)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    jaxform.enable_x64()
    law, params = load_material("al1100_673K")
    n = args.points
    rng = np.random.default_rng(0)
    f = np.eye(3) + 2e-3 * rng.standard_normal((n, 3, 3))
    f[:, 2, 2] -= 0.01  # compressive step
    f = jnp.asarray(f)
    stress0 = jnp.asarray(np.diag([0.0, 0.0, -15.0]))
    state = MaterialState(
        stress=jnp.broadcast_to(stress0, (n, 3, 3)),
        s=jnp.full((n,), 35.0),
        eqps=jnp.full((n,), 0.1),
    )
    dt = 1.0

    def upd(fi, st):
        return law.update(step_kinematics(fi), st, params, dt)

    update = jax.jit(jax.vmap(upd))
    tangent = jax.jit(jax.vmap(jax.jacfwd(lambda fi, st: upd(fi, st)[0])))

    for name, fn in (("update", update), ("tangent", tangent)):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(f, state))
        t_compile = time.perf_counter() - t0
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            out = jax.block_until_ready(fn(f, state))
            times.append(time.perf_counter() - t0)
        best = min(times)
        print(
            f"{name:8s}: {n / best:12.4g} points/s  ({best * 1e3:8.1f} ms per batch of {n}, "
            f"first call incl. compile {t_compile:.1f} s)"
        )
        if name == "update":
            assert bool(jnp.all(out[2])), "local solve failed"
    print(f"devices: {jax.devices()}")


if __name__ == "__main__":
    main()
