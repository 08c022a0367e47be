"""klujax's solve with a pattern analysis, with and without its sort of the pattern.

    python experiments/bench_klu_sort.py [--meshes 10 20 30 40 100] [--repeats 7]

``klujax.solve_with_symbol`` (and ``tsolve_with_symbol``) lexsorts the pattern row-major
inside the program at every call; :func:`jaxform.klu.solve_with_symbol` binds the same
primitive to jaxform's pattern, which is built sorted.  On the seed scene's Jacobian
(``bench_linear.jacobian``: the first step's homogeneous compression, n x n q1q1 mesh),
the pattern an argument of the program (as jaxform passes it: a constant pattern's sort
is folded at compile time), each way in one compiled program, interleaved, best of
``--repeats``: prints the time per call (factorization, solve and free included) and
whether the two solutions are equal to the last bit.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from bench_linear import jacobian


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--meshes", type=int, nargs="+", default=[10, 20, 30, 40, 100])
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()

    import jax
    import jax.numpy as jnp
    import klujax

    from jaxform import klu

    head = ("mesh", "unknowns", "nonzeros", "klujax (ms)", "without the sort (ms)",
            "transposed: klujax / without (ms)", "equal")  # fmt: skip
    print("| " + " | ".join(head) + " |")
    print("|---|---|---|---|---|---|---|")
    for m in args.meshes:
        rows, cols, vals, b, n = jacobian(m)
        r, c = jnp.asarray(rows, jnp.int32), jnp.asarray(cols, jnp.int32)
        v, bb = jnp.asarray(vals), jnp.asarray(b)
        sym = klu.symbolic(rows, cols, n)
        ways = {
            "klujax": jax.jit(lambda r, c, v, b: klujax.solve_with_symbol(r, c, v, b, sym)),
            "ours": jax.jit(lambda r, c, v, b: klu.solve_with_symbol(r, c, v, b, sym)),
            "klujax T": jax.jit(lambda r, c, v, b: klujax.tsolve_with_symbol(r, c, v, b, sym)),
            "ours T": jax.jit(lambda r, c, v, b: klu.solve_with_symbol(r, c, v, b, sym, True)),
        }
        x = {k: np.asarray(f(r, c, v, bb)) for k, f in ways.items()}
        equal = np.array_equal(x["klujax"], x["ours"]) and np.array_equal(
            x["klujax T"], x["ours T"]
        )
        best = {k: np.inf for k in ways}
        for _ in range(args.repeats):
            for k, f in ways.items():
                t0 = time.perf_counter()
                jax.block_until_ready(f(r, c, v, bb))
                best[k] = min(best[k], time.perf_counter() - t0)
        ms = {k: 1e3 * t for k, t in best.items()}
        print(f"| {m}x{m} | {n} | {len(vals)} | {ms['klujax']:.2f} | {ms['ours']:.2f} | "
              f"{ms['klujax T']:.2f} / {ms['ours T']:.2f} | {'yes' if equal else 'NO'} |",
              flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
