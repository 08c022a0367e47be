"""Sparse direct solvers on one real Jacobian of the seed scene, interleaved in one process.

    python experiments/bench_linear.py [--mesh 100] [--repeats 3] [--skip NAME ...]

Assembles the seed scene's Jacobian on an n x n mesh (configs/upsetting_seed.toml, q1q1,
Anand) at the first step's homogeneous compression (the state bench_scale.py uses), then
times, per call (ordering + factorization + solve, as the Newton loop calls it), best of
``--repeats`` after one warm-up, all methods interleaved:

* ``klujax`` (the ``sparse`` backend), also on a METIS-permuted copy (KLU orders by AMD);
* SciPy SuperLU ``splu`` with COLAMD and MMD_AT_PLUS_A (diagonal pivot threshold 0.01;
  with the default 1.0 it did not finish in 300 s at 100x100), and NATURAL after a
  reverse Cuthill-McKee or a METIS nested-dissection permutation of the unknowns;
* ``jax-sparse`` on CPU (jax.experimental.sparse.linalg.spsolve = SciPy spsolve);
* Intel MKL PARDISO (``pypardiso``) and METIS (``pymetis``) where they are installed: they
  are not jaxform dependencies, this script only measures them.

Prints the time and the relative residual ||A x - b|| / ||b|| of each.  The numbers in
jaxform/linear.py's docstring come from this script.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

SEED = "configs/upsetting_seed.toml"


def first_step_state(n: int, element: str = "q1q1"):
    """(scene, x, ctx): the seed scene on an n x n mesh of ``element`` at its first step's
    homogeneous compression (u_r = e r / 2, u_z = -e z) and that step's context."""
    import jax.numpy as jnp

    import jaxform
    from jaxform.config import load_config
    from jaxform.scenes import build_scene
    from jaxform.stepping import initial_state, step_context

    jaxform.enable_x64()
    cfg = load_config(
        SEED,
        [f"mesh.nr={n}", f"mesh.nz={n}", f"mesh.element={element}", "output.fields=false",
         "output.plots=false"],
    )  # fmt: skip
    sc = build_scene(cfg)
    lay, idx, inp, model = sc.model.layout, sc.idx, sc.inputs, sc.model
    coords = np.asarray(inp.coords)
    e = cfg["die"]["speed_mm_s"] * sc.dt / cfg["billet"]["height_mm"]
    x = np.zeros(lay.n_dofs)
    u = x[: lay.n_node_dofs].reshape(-1, lay.n_fields)
    u[:, 0], u[:, 1] = 0.5 * e * coords[:, 0], -e * coords[:, 1]
    t = jnp.asarray(sc.dt)
    return sc, jnp.asarray(x), step_context(model, initial_state(model, inp), inp, idx, t, t)


def jacobian(n: int):
    """(rows, cols, vals, rhs, n_dofs) of the seed scene's Jacobian on an n x n mesh."""
    import jax

    sc, x, ctx = first_step_state(n)
    r, vals, *_ = jax.jit(sc.model.residual_and_jacobian)(x, ctx)
    return (
        np.asarray(sc.idx.rows),
        np.asarray(sc.idx.cols),
        np.asarray(vals),
        -np.asarray(r),
        sc.model.layout.n_dofs,
    )


def methods(rows, cols, vals, b, n):
    """name -> (callable returning x in the original numbering)."""
    import jax
    import jax.numpy as jnp
    import klujax
    import scipy.sparse as sp
    import scipy.sparse.csgraph as csg
    import scipy.sparse.linalg as spl

    from jaxform.linear import JaxSparse

    a = sp.csc_matrix((vals, (rows, cols)), shape=(n, n))
    s = (a + a.T).tocsr()
    s.setdiag(0)
    s.eliminate_zeros()
    out = {}

    def permuted(perm):  # symmetric permutation, entries re-sorted row-major
        inv = np.empty_like(perm)
        inv[perm] = np.arange(n)
        r, c = inv[rows], inv[cols]
        o = np.lexsort((c, r))
        return r[o], c[o], vals[o], b[perm]

    def back(perm, x):
        y = np.empty_like(x)
        y[perm] = x
        return y

    ks = jax.jit(klujax.solve)

    def klu(r, c, v, bb, perm=None):
        args = (
            jnp.asarray(r, jnp.int32),
            jnp.asarray(c, jnp.int32),
            jnp.asarray(v),
            jnp.asarray(bb),
        )

        def f():
            x = np.asarray(jax.block_until_ready(ks(*args)))
            return x if perm is None else back(perm, x)

        return f

    out["klujax"] = klu(rows, cols, vals, b)
    js = JaxSparse()
    jf = jax.jit(lambda r, c, v, bb: js.solve(r, c, v, bb, n))
    jargs = (
        jnp.asarray(rows, jnp.int32),
        jnp.asarray(cols, jnp.int32),
        jnp.asarray(vals),
        jnp.asarray(b),
    )
    out["jax-sparse (CPU: scipy spsolve)"] = lambda: np.asarray(jax.block_until_ready(jf(*jargs)))
    out["splu COLAMD"] = lambda: spl.splu(a, permc_spec="COLAMD").solve(b)
    out["splu MMD_AT_PLUS_A, pivot 0.01"] = lambda: spl.splu(
        a, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.01
    ).solve(b)
    perms = {"RCM": np.asarray(csg.reverse_cuthill_mckee(s, symmetric_mode=True))}
    try:
        import pymetis

        perms["METIS"] = np.asarray(pymetis.nested_dissection(xadj=s.indptr, adjncy=s.indices)[0])
    except ImportError:
        print("pymetis not installed: METIS orderings skipped")
    for name, perm in perms.items():
        r, c, v, bb = permuted(perm)
        ap = sp.csc_matrix((v, (r, c)), shape=(n, n))
        out[f"splu NATURAL after {name}"] = lambda ap=ap, bb=bb, perm=perm: back(
            perm, spl.splu(ap, permc_spec="NATURAL", diag_pivot_thresh=0.01).solve(bb)
        )
        if name == "METIS":
            out["klujax after METIS"] = klu(r, c, v, bb, perm)
    try:
        import pypardiso

        ps = pypardiso.PyPardisoSolver()
        acsr = a.tocsr()

        def pardiso():
            ps.free_memory(everything=True)  # analysis + factorization every call
            return ps.solve(acsr, b)

        out["pypardiso (MKL PARDISO)"] = pardiso
    except ImportError:
        print("pypardiso not installed: PARDISO skipped")
    return a, out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--mesh", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--skip", nargs="*", default=[])
    args = ap.parse_args()
    rows, cols, vals, b, n = jacobian(args.mesh)
    a, ms = methods(rows, cols, vals, b, n)
    ms = {k: f for k, f in ms.items() if not any(s in k for s in args.skip)}
    print(f"{args.mesh}x{args.mesh}: {n} unknowns, {len(vals)} nonzeros")
    times = {k: [] for k in ms}
    for rep in range(args.repeats + 1):  # the first round warms up (compiles)
        for k, f in ms.items():
            t0 = time.perf_counter()
            x = f()
            dt = time.perf_counter() - t0
            if rep == 0:
                res = np.linalg.norm(a @ x - b) / np.linalg.norm(b)
                print(f"  {k:34s} first call {dt:7.3f} s, residual {res:.1e}", flush=True)
            else:
                times[k].append(dt)
    ref = min(times["klujax"]) if times.get("klujax") else None
    for k, v in times.items():
        rel = f"  ({ref / min(v):.2f}x klujax's speed)" if ref else ""
        print(f"{k:34s} best {min(v):7.3f} s{rel}")


if __name__ == "__main__":
    main()
