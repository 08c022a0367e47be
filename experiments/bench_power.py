"""Powers in the assembly: libm's pow against exp and log.

    python experiments/bench_power.py [--meshes 30 100] [--elements q1q1 q1p0] [--repeats 7]

XLA's CPU programs evaluate exp and log vectorized, but a power with a traced or a
fractional exponent (``x ** a``, ``x ** (1/3)``) one element at a time through libm's
``pow``.  The assembly has two: the Anand hardening |u|^a
(``jaxform.materials.anand._signed_pow``) and the cube root of q1p0's mean dilatation
(``jaxform.formulations.cube_root``).  For the seed scene
(configs/upsetting_seed.toml) on n x n meshes, at the first step's homogeneous compression
(the state of bench_scale.py), this compiles ``Model.residual`` and
``Model.residual_and_jacobian`` with both as they are (exp and log) and as plain powers
(``au ** a``, ``x ** (1 / 3)``), times them interleaved (best of
``--repeats``) and prints the largest relative difference of the residual and the
Jacobian values between the two.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from bench_linear import first_step_state


def _as_power(u, a):
    import jax.numpy as jnp

    nz = u != 0.0
    au = jnp.where(nz, jnp.abs(u), 1.0)
    return jnp.where(nz, jnp.sign(u) * au**a, 0.0)


def _cube_root_as_power(x):
    return x ** (1.0 / 3.0)


def one(element: str, n: int, repeats: int) -> str:
    import jax

    from jaxform import formulations
    from jaxform.materials import anand

    sc, x, ctx = first_step_state(n, element)
    model = sc.model
    kept, fns, outs = (anand._signed_pow, formulations.cube_root), {}, {}
    try:
        for way, fn in (("exp/log", kept), ("pow", (_as_power, _cube_root_as_power))):
            anand._signed_pow, formulations.cube_root = fn  # traced now, with these
            fns[way, "R"] = jax.jit(lambda x, c: model.residual(x, c))
            fns[way, "R+J"] = jax.jit(lambda x, c: model.residual_and_jacobian(x, c)[:2])
            outs[way] = jax.block_until_ready(fns[way, "R+J"](x, ctx))
            jax.block_until_ready(fns[way, "R"](x, ctx))
    finally:
        anand._signed_pow, formulations.cube_root = kept
    best = dict.fromkeys(fns, np.inf)
    for _ in range(repeats):
        for key, f in fns.items():
            t0 = time.perf_counter()
            jax.block_until_ready(f(x, ctx))
            best[key] = min(best[key], time.perf_counter() - t0)
    (r1, v1), (r2, v2) = (
        (np.asarray(a) for a in outs["exp/log"]),
        (np.asarray(a) for a in outs["pow"]),
    )
    dr = np.max(np.abs(r1 - r2)) / np.max(np.abs(r2))
    dv = np.max(np.abs(v1 - v2)) / np.max(np.abs(v2))
    ms = {k: 1e3 * v for k, v in best.items()}
    return (
        f"| {element} {n}x{n} | {model.layout.n_dofs} | {ms['pow', 'R']:.2f} | "
        f"{ms['exp/log', 'R']:.2f} | {ms['pow', 'R+J']:.2f} | {ms['exp/log', 'R+J']:.2f} | "
        f"{dr:.1e} / {dv:.1e} |"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--meshes", type=int, nargs="+", default=[30, 100])
    ap.add_argument("--elements", nargs="+", default=["q1q1", "q1p0"])
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    import jaxform

    jaxform.enable_x64()
    head = ("mesh", "unknowns", "residual, pow (ms)", "residual, exp/log (ms)",
            "residual + Jacobian, pow (ms)", "residual + Jacobian, exp/log (ms)",
            "difference R / J")  # fmt: skip
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for element in args.elements:
        for n in args.meshes:
            print(one(element, n, args.repeats), flush=True)


if __name__ == "__main__":
    main()
