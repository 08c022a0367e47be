"""Linear backends (jaxform.linear): selection by name, size and platform, and solves.

No GPU here: the platform is passed in, so the choice a GPU process would make is tested
on CPU; the chosen backend then solves a small non-symmetric sparse system on CPU
(jax-sparse through its CPU lowering, SciPy's spsolve), inside jit and under vmap.
"""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxform import pardiso
from jaxform.linear import (
    DENSE_LIMIT,
    GPU_DENSE_LIMIT,
    KLU,
    PARDISO_MIN_UNKNOWNS,
    DenseLU,
    JaxSparse,
    LinearBackendWarning,
    Pardiso,
    _warn_once,
    choose_backend,
)

BACKEND_TYPES = {"dense": DenseLU, "sparse": KLU, "pardiso": Pardiso, "jax-sparse": JaxSparse}
# MKL PARDISO is a dependency on x86-64 Linux and Windows (pyproject.toml) only
needs_pardiso = pytest.mark.skipif(
    not pardiso.available(), reason="MKL PARDISO is not installed on this platform"
)

# (name, unknowns, platform) -> backend chosen, whether a fallback message is given
CASES = [
    ("auto", DENSE_LIMIT - 1, "cpu", "dense", False),
    ("auto", DENSE_LIMIT, "cpu", "sparse", False),
    ("sparse", 10, "cpu", "sparse", False),
    ("dense", 10**5, "cpu", "dense", False),
    ("jax-sparse", 10, "cpu", "jax-sparse", False),
    ("auto", GPU_DENSE_LIMIT - 1, "cuda", "dense", False),
    ("auto", GPU_DENSE_LIMIT, "cuda", "jax-sparse", False),
    ("sparse", 500, "cuda", "jax-sparse", True),  # klujax is CPU-only: never silently
    ("jax-sparse", 500, "cuda", "jax-sparse", False),
    ("dense", 10**5, "cuda", "dense", False),
    ("sparse", 500, "rocm", "dense", True),  # spsolve does not lower on ROCm
    ("jax-sparse", 500, "tpu", "dense", True),
    ("auto", GPU_DENSE_LIMIT, "rocm", "dense", True),
    ("auto", 500, "tpu", "dense", False),
    ("pardiso", 500, "cuda", "dense", True),  # MKL is CPU-only
]
# where MKL PARDISO is installed: 'auto' takes it for large systems
PARDISO_CASES = [
    ("auto", PARDISO_MIN_UNKNOWNS - 1, "cpu", "sparse", False),
    ("auto", PARDISO_MIN_UNKNOWNS, "cpu", "pardiso", False),
    ("pardiso", 10, "cpu", "pardiso", False),
]


@pytest.mark.parametrize(
    "name,n,platform,expected,warns",
    CASES + [pytest.param(*c, marks=needs_pardiso) for c in PARDISO_CASES],
)
def test_backend_selection_by_size_and_platform(name, n, platform, expected, warns):
    _warn_once.cache_clear()  # the message is once per process
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        solver = choose_backend(name, n, platform=platform)
    assert solver.backend == expected
    assert type(solver) is BACKEND_TYPES[expected]
    msgs = [str(w.message) for w in caught if issubclass(w.category, LinearBackendWarning)]
    assert bool(msgs) == warns, msgs
    if warns:  # the message names the setting, the platform and the backend chosen
        assert f"'{name}'" in msgs[0] and platform in msgs[0] and expected in msgs[0]


def test_fallback_message_is_given_once():
    _warn_once.cache_clear()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for _ in range(3):
            choose_backend("sparse", 500, platform="cuda")
    assert sum(issubclass(w.category, LinearBackendWarning) for w in caught) == 1


def test_unknown_backend_names_the_field_and_the_choices():
    with pytest.raises(ValueError, match="solver.linear.*auto, dense, sparse, pardiso, jax-sparse"):
        choose_backend("umfpack", 10, platform="cpu")


def _system(n=40, seed=0):
    """A non-symmetric sparse matrix (tridiagonal plus a few far entries), row-major pattern."""
    rng = np.random.default_rng(seed)
    a = (
        np.diag(4.0 + rng.random(n))
        + np.diag(rng.random(n - 1) - 0.5, 1)
        + np.diag(rng.random(n - 1) - 0.5, -1)
    )
    a[0, n - 1], a[n - 3, 2], a[5, 30] = 0.7, -0.4, 1.1
    rows, cols = np.nonzero(a)  # row-major order, as the assembly builds it
    return a, jnp.asarray(rows, jnp.int32), jnp.asarray(cols, jnp.int32), rng


@pytest.mark.parametrize(
    "name", ["dense", "sparse", pytest.param("pardiso", marks=needs_pardiso), "jax-sparse"]
)
def test_chosen_backend_solves_and_transposes_in_jit_and_vmap(name):
    a, rows, cols, rng = _system()
    n = a.shape[0]
    solver = choose_backend(name, n, platform="cpu")
    assert solver.backend == name
    vals = jnp.asarray(a[np.asarray(rows), np.asarray(cols)])
    b = jnp.asarray(rng.standard_normal(n))
    x = jax.jit(lambda v, b: solver.solve(rows, cols, v, b, n))(vals, b)
    y = jax.jit(lambda v, b: solver.solve_transpose(rows, cols, v, b, n))(vals, b)
    assert np.max(np.abs(a @ np.asarray(x) - np.asarray(b))) <= 1e-12
    assert np.max(np.abs(a.T @ np.asarray(y) - np.asarray(b))) <= 1e-12
    # a batch of matrices (the diagonal scaled) and right-hand sides, as vmap over designs
    scale = jnp.asarray([1.0, 2.0, 0.5])
    diag = jnp.asarray(np.asarray(rows) == np.asarray(cols))
    vb = jnp.where(diag[None, :], vals[None, :] * scale[:, None], vals[None, :])
    bb = jnp.asarray(rng.standard_normal((3, n)))
    xb = jax.jit(jax.vmap(lambda v, b: solver.solve(rows, cols, v, b, n)))(vb, bb)
    yb = jax.jit(jax.vmap(lambda v, b: solver.solve_transpose(rows, cols, v, b, n)))(vb, bb)
    for k in range(3):
        ak = a + (float(scale[k]) - 1.0) * np.diag(np.diag(a))
        assert np.max(np.abs(ak @ np.asarray(xb[k]) - np.asarray(bb[k]))) <= 1e-12
        assert np.max(np.abs(ak.T @ np.asarray(yb[k]) - np.asarray(bb[k]))) <= 1e-12


def test_klu_solve_with_the_analysis_equals_klujax_without_its_sort():
    """jaxform.klu.solve_with_symbol binds klujax's solve primitive to the pattern as it
    is (klujax's own function sorts it row-major first, inside the program, at every
    call): on a row-major pattern (the assembly's order) the same solution to the last
    bit, plain and transposed, under jit and vmap, with the same forward derivative (of
    the plain solve: klujax has none of the transposed one); and
    a pattern out of order still solves the system (KLU takes the columns in any order)."""
    import klujax

    from jaxform import klu

    a, rows, cols, rng = _system()
    n = a.shape[0]
    vals = jnp.asarray(a[np.asarray(rows), np.asarray(cols)])
    b = jnp.asarray(rng.standard_normal(n))
    sym = KLU().analyze(rows, cols, n)
    for transpose, theirs in ((False, klujax.solve_with_symbol), (True, klujax.tsolve_with_symbol)):
        ours = jax.jit(lambda v, b, t=transpose: klu.solve_with_symbol(rows, cols, v, b, sym, t))
        ref = jax.jit(lambda v, b, f=theirs: f(rows, cols, v, b, sym))
        assert np.array_equal(np.asarray(ours(vals, b)), np.asarray(ref(vals, b)))
        m = a.T if transpose else a
        assert np.max(np.abs(m @ np.asarray(ours(vals, b)) - np.asarray(b))) <= 1e-12
        vb = jnp.stack([vals, 2.0 * vals])
        bb = jnp.stack([b, -b])
        assert np.array_equal(np.asarray(jax.vmap(ours)(vb, bb)), np.asarray(jax.vmap(ref)(vb, bb)))
        if transpose:  # klujax defines no derivative of its transposed solve
            continue
        dv, db = jnp.asarray(rng.standard_normal(vals.shape)), jnp.asarray(rng.standard_normal(n))
        _, t_ours = jax.jvp(ours, (vals, b), (dv, db))
        _, t_ref = jax.jvp(ref, (vals, b), (dv, db))
        np.testing.assert_allclose(np.asarray(t_ours), np.asarray(t_ref), rtol=1e-12, atol=1e-14)
    order = np.asarray(rng.permutation(len(rows)))
    r2, c2, v2 = rows[order], cols[order], vals[order]
    x2 = klu.solve_with_symbol(r2, c2, v2, b, KLU().analyze(r2, c2, n))
    assert np.max(np.abs(a @ np.asarray(x2) - np.asarray(b))) <= 1e-12


def test_scene_patterns_are_row_major():
    """The order klu.solve_with_symbol's shortcut keeps bit for bit: the assembled pattern
    of a scene with contact (the seed) is sorted row-major without repeats."""
    import jaxform
    from jaxform.config import load_config
    from jaxform.scenes import build_scene

    jaxform.enable_x64()
    scene = build_scene(load_config("configs/upsetting_seed.toml", ["mesh.nr=3", "mesh.nz=3"]))
    rows, cols = np.asarray(scene.idx.rows, np.int64), np.asarray(scene.idx.cols, np.int64)
    key = rows * (int(cols.max()) + 1) + cols
    assert np.all(np.diff(key) > 0)


def _saddle(n=30, m=6, seed=1):
    """A non-symmetric sparse saddle-point matrix like a contact step's: a stiffness block
    K (n x n) and m constraint rows B with zero diagonal (the multipliers' rows of nodes
    in contact), [[K, B^T], [B, 0]], row-major pattern."""
    rng = np.random.default_rng(seed)
    k = np.diag(4.0 + rng.random(n)) + np.diag(rng.random(n - 1) - 0.5, 1)
    k += np.diag(rng.random(n - 1) - 0.3, -1)
    b = np.zeros((m, n))
    b[np.arange(m), rng.choice(n, m, replace=False)] = 1.0 + rng.random(m)
    a = np.block([[k, b.T], [b, np.zeros((m, m))]])
    rows, cols = np.nonzero(a)
    return a, jnp.asarray(rows, jnp.int32), jnp.asarray(cols, jnp.int32), rng


@needs_pardiso
def test_pardiso_kept_factorizations_solve_free_and_store():
    """Reference: NumPy's dense solve.  PARDISO's kept factorizations (refactor,
    solve_factored plain and transposed) on a saddle-point matrix with zero-diagonal
    constraint rows (the pivots PARDISO perturbs and refines) solve to 1e-12; a refactor
    frees the one it replaces and release frees exactly the valid ones (the process's
    table of factorizations back to where it was), also batched under vmap; a singular
    matrix gives NaN (the Newton solve's non-finite step), not an exception; a one-call
    solve holds no factorization after it; and a
    program that factors and solves is exportable (the persistent cache and the program
    store keep it: FFI targets, no host callback)."""
    a, rows, cols, rng = _saddle()
    n = a.shape[0]
    lin = Pardiso()
    sym = lin.analyze(rows, cols, n)
    vals = jnp.asarray(a[np.asarray(rows), np.asarray(cols)])
    b = jnp.asarray(rng.standard_normal(n))
    live = pardiso.live_factorizations()

    def two(vals, b):
        empty = lin.empty_factorization(n, vals.dtype)
        f1 = lin.refactor(rows, cols, vals, n, sym, empty)
        x1 = lin.solve_factored(f1, b, sym)
        f2 = lin.refactor(rows, cols, 2.0 * vals, n, sym, f1)  # replaces (frees) f1
        y2 = lin.solve_factored(f2, b, sym, transpose=True)
        return x1, y2, f2

    x1, y2, f2 = jax.jit(two)(vals, b)
    assert np.max(np.abs(a @ np.asarray(x1) - np.asarray(b))) <= 1e-12
    assert np.max(np.abs(2.0 * a.T @ np.asarray(y2) - np.asarray(b))) <= 1e-12
    assert pardiso.live_factorizations() == live + 1  # f1 freed by the refactor
    token = jax.jit(lin.release)(f2)
    assert int(token) == 0 and pardiso.live_factorizations() == live
    # batched: three matrices, the second factorization released outside jit as invalid
    scale = jnp.asarray([1.0, 2.0, 0.5])
    empty = lin.empty_factorization(n, vals.dtype)
    facs = jax.jit(jax.vmap(lambda s: lin.refactor(rows, cols, s * vals, n, sym, empty)))(scale)
    xs = jax.jit(jax.vmap(lambda f, bb: lin.solve_factored(f, bb, sym)))(facs, jnp.stack([b] * 3))
    for k in range(3):
        assert np.max(np.abs(float(scale[k]) * a @ np.asarray(xs[k]) - np.asarray(b))) <= 1e-12
    assert pardiso.live_factorizations() == live + 3
    lin.release_now(facs.__class__(lu=facs.lu, piv=facs.piv, valid=jnp.asarray([True, False, True]),
                                   count=facs.count))  # fmt: skip
    assert pardiso.live_factorizations() == live + 1
    lin.release_now(facs)  # the one left; the freed ones are not freed twice
    assert pardiso.live_factorizations() == live
    # singular: a zero row (PARDISO perturbs the pivot; SuperLU, partial pivoting, refuses)
    redone = pardiso.STATS["partial_pivoting"]
    sing = np.where(np.asarray(rows) == 3, 0.0, np.asarray(vals))
    x = jax.jit(lambda v, b: lin.solve(rows, cols, v, b, n, sym))(jnp.asarray(sing), b)
    assert np.isnan(np.asarray(x)).all()
    assert pardiso.STATS["partial_pivoting"] == redone + 1
    # a one-call solve (full Newton's) keeps nothing after it (a pattern per mesh)
    x = jax.jit(lambda v, b: lin.solve_transpose(rows, cols, v, b, n, sym))(vals, b)
    assert np.max(np.abs(a.T @ np.asarray(x) - np.asarray(b))) <= 1e-12
    assert pardiso.live_factorizations() == live
    # the program store's export (the targets known by name), serialized and called again
    from jaxform import program_store

    leaves, tree = jax.tree_util.tree_flatten((vals, b))
    exported, out_tree = program_store._export(two, leaves, tree)
    again = jax.export.deserialize(exported.serialize()).call(*leaves)
    x1_again, _, f2_again = jax.tree_util.tree_unflatten(out_tree, again)
    assert np.array_equal(np.asarray(x1_again), np.asarray(x1))
    lin.release_now(f2_again)
    assert pardiso.live_factorizations() == live


@needs_pardiso
def test_pardiso_runs_a_scene_as_klujax_does():
    """Reference: the same scene solved by klujax.  The seed scene (4 x 4, modified Newton
    as 'auto' gives it, its first 6 steps) with solver.linear = 'pardiso': the force
    history equal to 1e-9 of the force (both converge to rtol 1e-10 of it)."""
    import jaxform
    from jaxform.driver import run

    jaxform.enable_x64()
    forces = {}
    for lin in ("sparse", "pardiso"):
        res = run("configs/upsetting_seed.toml", ["mesh.nr=4", "mesh.nz=4", f"solver.linear={lin}",
                  "die.reduction=0.1", "output.plots=false", "output.fields=false"])  # fmt: skip
        forces[lin] = np.asarray(res.history["force_N"])
        assert res.scene.linear.backend == lin
    assert len(forces["sparse"]) == len(forces["pardiso"]) > 3
    scale = np.max(np.abs(forces["sparse"]))
    assert np.max(np.abs(forces["pardiso"] - forces["sparse"])) <= 1e-9 * scale
