"""The reverse pass's transposed solve with a kept forward factorization
(jaxform.solver.adjoint_solve / refined_solve) and its memory budget.

References: the fresh transposed solve of the same matrix (NumPy's LU) and the
componentwise backward error max_i |b - A^T y|_i / (|A^T| |y| + |b|)_i of the result.
The factorization kept is of a nearby matrix, as in a converged Newton step: the
Jacobian of the iterate before the root.  The end-to-end check (every reverse step of a
frictional run refined, gradients against finite differences) is in test_gradients.py.
"""

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxform.config import load_config
from jaxform.gradients import kept_steps, trajectory
from jaxform.klu import symbolic as klu_symbolic
from jaxform.linear import KLU, DenseLU, LinearSolver, matvec
from jaxform.scenes import build_scene
from jaxform.solver import REFINE_TARGET, adjoint_solve, refined_solve

N = 60


def _matrix(seed=0):
    """A non-symmetric sparse matrix (tridiagonal, diagonally dominant, plus a few far
    entries), its pattern in row-major order."""
    rng = np.random.default_rng(seed)
    a = (
        np.diag(4.0 + rng.random(N))
        + np.diag(rng.random(N - 1) - 0.5, 1)
        + np.diag(rng.random(N - 1) - 0.5, -1)
    )
    a[0, N - 1], a[N - 3, 2], a[5, 30] = 0.7, -0.4, 1.1
    rows, cols = np.nonzero(a)
    return a, jnp.asarray(rows, jnp.int32), jnp.asarray(cols, jnp.int32), rng


@dataclass(frozen=True)
class Linear:
    """The step-linear contract of jaxform.solver.solve_implicit on a fixed pattern
    (jaxform.stepping.StepLinear reads the pattern from the step's arguments instead)."""

    solver: LinearSolver
    rows: jax.Array
    cols: jax.Array
    symbolic: jax.Array | None

    def __call__(self, vals, b, args, transpose):
        solve = self.solver.solve_transpose if transpose else self.solver.solve
        return solve(self.rows, self.cols, vals, b, N, self.symbolic)

    def solve_factored(self, fac, b, args, transpose=False):
        return self.solver.solve_factored(fac, b, self.symbolic, transpose)

    def matvec(self, vals, y, args, transpose):
        r, c = (self.cols, self.rows) if transpose else (self.rows, self.cols)
        return matvec(r, c, vals, y, N)


def _backward_error(a, y, b):
    """Componentwise (Oettli-Prager) backward error of y as a solution of A^T y = b."""
    return np.max(np.abs(b - a.T @ y) / (np.abs(a.T) @ np.abs(y) + np.abs(b)))


@pytest.mark.parametrize("backend", ["dense", "sparse"])
def test_refined_with_a_nearby_factorization_equals_the_fresh_transposed_solve(backend):
    a, rows, cols, rng = _matrix()
    r_, c_ = np.asarray(rows), np.asarray(cols)
    sym = klu_symbolic(rows, cols, N) if backend == "sparse" else None
    lin = Linear({"dense": DenseLU, "sparse": KLU}[backend](), rows, cols, sym)
    vals = jnp.asarray(a[r_, c_])
    near = vals * (1.0 + 1e-5 * rng.standard_normal(vals.shape))  # J one Newton step away
    far = jnp.asarray(np.where(r_ == c_, 12.0, -3.0) * a[r_, c_])  # not a nearby matrix
    b = jnp.asarray(rng.standard_normal(N))
    factor = jax.jit(
        lambda v: lin.solver.refactor(
            rows, cols, v, N, sym, lin.solver.empty_factorization(N, v.dtype)
        )
    )
    f_near, f_far = factor(near), factor(far)

    def refine(fac, v, b):
        return refined_solve(
            lambda r: lin.solve_factored(fac, r, None, True),
            lambda y: lin.matvec(v, y, None, True),
            lambda y: lin.matvec(jnp.abs(v), y, None, True),
            b,
        )

    y, steps, ok = jax.jit(refine)(f_near, vals, b)
    fresh = np.linalg.solve(a.T, np.asarray(b))
    assert bool(ok) and 2 <= int(steps) <= 4  # the error contracts ~1e-5 per step
    assert _backward_error(a, np.asarray(y), np.asarray(b)) <= REFINE_TARGET
    np.testing.assert_allclose(np.asarray(y), fresh, rtol=0, atol=1e-13 * np.abs(fresh).max())
    # a factorization of a matrix that is not nearby: refinement stalls and says so ...
    _, _, ok_far = jax.jit(refine)(f_far, vals, b)
    assert not bool(ok_far)
    # ... and adjoint_solve falls back to a fresh solve: the same answer every way
    solve = jax.jit(lambda fac, use: adjoint_solve(lin, vals, b, None, fac, use))
    for fac, use in ((f_near, True), (f_far, True), (f_far, False)):
        y = np.asarray(solve(fac, jnp.asarray(use)))
        np.testing.assert_allclose(y, fresh, rtol=0, atol=1e-13 * np.abs(fresh).max())
    # a zero right-hand side (a step no output depends on): y = 0 at once
    y0, steps0, ok0 = jax.jit(refine)(f_near, vals, jnp.zeros(N))
    assert bool(ok0) and int(steps0) == 0 and not np.any(np.asarray(y0))
    lin.solver.release_now(jax.tree_util.tree_map(lambda u, v: jnp.stack([u, v]), f_near, f_far))


def _scene(*over):
    return build_scene(
        load_config(
            "configs/upsetting_seed.toml", ["output.fields=false", "output.plots=false", *over]
        )
    )


def test_memory_budget_sets_the_kept_steps():
    sc = _scene("mesh.nr=12", "mesh.nz=12", "solver.linear=sparse")
    n, nnz = sc.model.layout.n_dofs, len(sc.idx.rows)
    size = sc.linear.factor_bytes(n, nnz, sc.idx.lu_symbolic)
    # KLU's fill estimate: between the matrix itself and a dense one
    assert 12.0 * nnz < size < 8.0 * n * n
    budget = 10.5 * size / 2**20
    sc = _scene(
        "mesh.nr=12", "mesh.nz=12", "solver.linear=sparse", f"solver.adjoint_memory_mb={budget}"
    )
    assert kept_steps(sc, 57) == 10 and kept_steps(sc, 4) == 4
    assert kept_steps(_scene("solver.adjoint_memory_mb=0"), 57) == 0
    dense = _scene("mesh.nr=2", "mesh.nz=2")
    m = dense.model.layout.n_dofs
    assert dense.linear.backend == "dense"
    assert dense.linear.factor_bytes(m, 0) == 8.0 * m * m + 4.0 * m


def test_kept_factorizations_are_refused_under_vmap():
    sc = _scene("mesh.nr=2", "mesh.nz=2", "solver.linear=sparse")

    def run(mu):
        inputs = sc.inputs.__class__(
            coords=sc.inputs.coords * mu,
            params=sc.inputs.params,
            die=sc.inputs.die,
            c_contact=sc.inputs.c_contact,
        )
        return trajectory(sc, inputs, reuse_factorizations=True).force_N

    with pytest.raises(ValueError, match="reuse_factorizations=True.*vmap"):
        jax.vmap(run)(jnp.asarray([1.0, 1.01]))
