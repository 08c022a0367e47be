"""One factorization of a real Jacobian by klujax (KLU) and by MKL PARDISO, interleaved.

    python experiments/bench_factor.py [--mesh 10 20 50 100 200] [--repeats 3]

The seed scene's Jacobian on an n x n mesh at its first step (``bench_linear.jacobian``).
KLU as jaxform calls it for a kept factorization (the pattern's analysis done once,
``KLU.refactor`` and ``KLU.solve_factored`` in jit); PARDISO through
:mod:`jaxform.pardiso`'s instance (its analysis once, then its numeric phase alone, and
the analysis timed apart: jaxform runs both with every factorization).  Best of
``--repeats``, the two solvers in turn, two rounds.  Prints the times, PARDISO's memory
(its ``iparm(15)``-``iparm(18)``) and the relative residuals.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from bench_linear import jacobian


def best(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def one_mesh(n_mesh: int, repeats: int) -> None:
    import jax
    import jax.numpy as jnp
    import scipy.sparse as sp

    from jaxform import pardiso
    from jaxform.linear import KLU

    rows, cols, vals, b, n = jacobian(n_mesh)
    a = sp.csr_matrix((vals, (rows, cols)), shape=(n, n))
    r, c = jnp.asarray(rows, jnp.int32), jnp.asarray(cols, jnp.int32)
    klu = KLU()
    sym = klu.analyze(r, c, n)
    empty = klu.empty_factorization(n, jnp.float64)
    factor = jax.jit(lambda v: klu.refactor(r, c, v, n, sym, empty))
    solve = jax.jit(lambda f, bb: klu.solve_factored(f, bb, sym))
    v, bj = jnp.asarray(vals), jnp.asarray(b)
    fac = jax.block_until_ready(factor(v))
    klu.release_now(fac)
    fac = jax.block_until_ready(factor(v))
    x = np.asarray(solve(fac, bj))
    print(f"{n_mesh} x {n_mesh}: {n} unknowns, {len(vals)} entries; KLU residual "
          f"{np.linalg.norm(a @ x - b) / np.linalg.norm(b):.1e}")  # fmt: skip
    pid = int(np.asarray(pardiso.analyze(rows, cols, n))[0])
    inst = pardiso._Instance()
    inst.pattern, inst.values = pid, np.array(vals)
    t = time.perf_counter()
    inst._call(11)
    analysis = time.perf_counter() - t
    inst._call(22)
    inst.ok = True
    xp = np.zeros(n)
    for rnd in range(2):

        def klu_factor():
            f = jax.block_until_ready(factor(v))
            klu.release_now(f)

        tk = best(klu_factor, repeats)
        tks = best(lambda: jax.block_until_ready(solve(fac, bj)), repeats)
        tp = best(lambda: inst._call(22), repeats)
        tps = best(lambda: inst.solve(b, xp, False), repeats)
        res = np.linalg.norm(a @ xp - b) / np.linalg.norm(b)
        print(f"  round {rnd}: KLU factor {tk * 1e3:.1f} ms, solve {tks * 1e3:.2f} ms | PARDISO "
              f"factor {tp * 1e3:.1f} ms (analysis {analysis * 1e3:.1f} ms), solve "
              f"{tps * 1e3:.2f} ms, residual {res:.1e}")  # fmt: skip
    print(f"  PARDISO memory (KB): analysis peak {inst.iparm[14]}, permanent {inst.iparm[15]}, "
          f"numeric peak {inst.iparm[16]}; entries of L and U {inst.iparm[17]}; perturbed "
          f"pivots {inst.iparm[13]}")  # fmt: skip
    klu.release_now(fac)
    inst.release()


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mesh", type=int, nargs="+", default=[10, 20, 50, 100, 200])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    import jaxform

    jaxform.enable_x64()
    for m in args.mesh:
        one_mesh(m, args.repeats)


if __name__ == "__main__":
    main()
