"""Linear solve backends behind one interface, all usable inside jit.

A matrix is given as values ``vals`` on a fixed sparsity pattern (unique rows/cols
computed once at set-up, passed in as *arguments* so that no large constant is baked
into the compiled program; the pattern from :func:`jaxform.assembly.build_indices` is
sorted row-major).  ``solve(rows, cols, vals, b, n)``:

* ``dense``  scatters into an n x n array and calls LU (jnp.linalg.solve);
* ``sparse`` calls klujax (SuiteSparse KLU as an XLA primitive).  klujax is imported
  lazily, only when this backend is used, because importing it switches JAX to CPU
  and float64 process-wide.  CPU only.
* ``jax-sparse`` (:class:`JaxSparseSolver`) calls ``jax.experimental.sparse.linalg.spsolve``:
  cuSolver's sparse QR (csrlsvqr) on a CUDA GPU, SciPy's ``spsolve`` (SuperLU) through a
  host callback on CPU.  The GPU sparse path; on CPU only a reference (2x slower than
  klujax, below).  It has no batching rule, so under vmap it solves the batch one
  system after another (``jax.custom_batching.sequential_vmap``).

``auto`` picks by size and platform (:func:`choose_backend`).  Measured on the seed scene
(2 cores, experiments/bench_seed.py, run time of the whole scene): 55 unknowns dense
0.11 s / sparse 0.12 s, 119 unknowns 0.24 / 0.22 s, 384 unknowns 1.29 / 0.84 s; one
solve at 384 unknowns 3.4 ms dense vs 0.8 ms sparse.  So on CPU dense only below 100
unknowns, klujax above.

Other CPU sparse solvers, measured on one real Jacobian of the 100x100 seed scene (31 005
unknowns, 817 821 nonzeros, pattern not symmetric, values far from symmetric;
``experiments/bench_linear.py``, analysis + factorization + solve per call, best of 3,
interleaved in one process, 2-core CPU shared with other jobs, load ~6): klujax 1.18-1.25 s
(residual 2e-14); SciPy SuperLU ``splu`` COLAMD 2.1 s (fill 15.2 M), MMD_AT_PLUS_A with
diag_pivot_thresh 0.01 2.8 s (with the default threshold > 300 s), NATURAL after a METIS
nested-dissection permutation (pymetis) 0.92-0.96 s, after reverse Cuthill-McKee 4.8 s;
Intel MKL PARDISO (pypardiso) 1.0 s; klujax after a METIS permutation 1.6 s (KLU orders by
AMD itself).  None is 1.5x faster than klujax, so none was added as a dependency: the
best (SuperLU + METIS, 1.3x) would bring pymetis and a host callback for a gain that the
shared machine's noise nearly covers.  scikit-umfpack has no wheel (it needs SuiteSparse
headers to build) and python-mumps' wheel is built against NumPy 1.

Platforms other than CPU (``jax.default_backend() != "cpu"``): ``sparse`` never imports
klujax there (that would move the process to CPU); it becomes ``jax-sparse`` on CUDA and
``dense`` elsewhere (no sparse direct solver lowers there), with a one-time
:class:`LinearBackendWarning` that names the backend chosen and why.  ``auto`` on a GPU
picks dense LU up to ``GPU_DENSE_LIMIT`` unknowns (an n x n float64 matrix of 3.2 GB at
20 000; a memory bound, not a measured crossover: no GPU was available when this was
written), ``jax-sparse`` above on CUDA.

``solve_transpose`` solves A^T y = b with the same pattern (for adjoints).
"""

from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass

import jax
import jax.numpy as jnp

DENSE_LIMIT = 100  # unknowns; 'auto' picks dense below this
BACKENDS = ("auto", "dense", "sparse", "jax-sparse")
GPU_DENSE_LIMIT = 20_000  # unknowns; 'auto' on a GPU picks dense LU below this
SPARSE_GPU_PLATFORMS = ("cuda",)  # where jax.experimental.sparse.linalg.spsolve lowers


@dataclass(frozen=True)
class LinearSolver:
    backend: str = "dense"  # 'dense' | 'sparse'

    def solve(self, rows, cols, vals, b, n: int):
        if self.backend == "dense":
            a = jnp.zeros((n, n), dtype=vals.dtype).at[rows, cols].set(vals)
            return jnp.linalg.solve(a, b)
        import klujax  # lazy: see module docstring

        return klujax.solve(rows.astype(jnp.int32), cols.astype(jnp.int32), vals, b)

    def solve_transpose(self, rows, cols, vals, b, n: int):
        return self.solve(cols, rows, vals, b, n)


class LinearBackendWarning(UserWarning):
    """The linear backend asked for does not run on this platform; another was chosen."""


@functools.lru_cache(maxsize=None)
def _warn_once(message: str) -> None:
    warnings.warn(message, LinearBackendWarning, stacklevel=3)


@dataclass(frozen=True)
class JaxSparseSolver:
    """``jax.experimental.sparse.linalg.spsolve`` on the CSR form of the pattern.

    ``solve`` needs the pattern sorted row-major (as built by the assembly); the CSR row
    pointer is found in jit by a search.  ``solve_transpose`` re-sorts (cols, rows) row-major
    first.  ``tol`` is cuSolver's singularity threshold on |R_ii| of the QR factor; ``reorder``
    its fill-reducing ordering (0 none, 1 symrcm, 2 symamd, 3 METIS nested dissection).  On
    CPU both are ignored (SciPy's spsolve)."""

    backend: str = "jax-sparse"
    tol: float = 1e-14
    reorder: int = 3

    def solve(self, rows, cols, vals, b, n: int):
        indptr = jnp.searchsorted(rows, jnp.arange(n + 1, dtype=rows.dtype), side="left")
        return _spsolve_sequential(vals, cols.astype(jnp.int32), indptr.astype(jnp.int32), b,
                                   self.tol, self.reorder)

    def solve_transpose(self, rows, cols, vals, b, n: int):
        rows_t, cols_t, vals_t = jax.lax.sort((cols, rows, vals), num_keys=2)
        return self.solve(rows_t, cols_t, vals_t, b, n)


def _spsolve_sequential(data, indices, indptr, b, tol, reorder):
    from jax.experimental.sparse.linalg import spsolve

    @jax.custom_batching.sequential_vmap
    def one(data, indices, indptr, b):
        return spsolve(data, indices, indptr, b, tol=tol, reorder=reorder)

    return one(data, indices, indptr, b)


def platform_kind(platform: str | None = None) -> str:
    """'cpu', 'cuda', 'rocm', 'tpu', ... for the given or the default JAX backend."""
    if platform is not None:
        return platform
    backend = jax.default_backend()
    if backend != "gpu":
        return backend
    version = str(getattr(jax.devices()[0].client, "platform_version", "")).lower()
    return "rocm" if "rocm" in version else "cuda"


def choose_backend(name: str, n_unknowns: int, platform: str | None = None):
    """The linear solver for ``solver.linear = name`` and n unknowns on ``platform``
    ('cpu', 'cuda', 'rocm', 'tpu'; default: where JAX runs).  See the module docstring."""
    if name not in BACKENDS:
        raise ValueError(f"solver.linear = {name!r}: must be one of {', '.join(BACKENDS)}")
    kind = platform_kind(platform)
    sparse_gpu = kind in SPARSE_GPU_PLATFORMS
    if kind == "cpu":
        if name == "auto":
            name = "dense" if n_unknowns < DENSE_LIMIT else "sparse"
    elif name == "auto":
        name = "dense" if n_unknowns < GPU_DENSE_LIMIT or not sparse_gpu else "jax-sparse"
        if name == "dense" and n_unknowns >= GPU_DENSE_LIMIT:
            _warn_once(f"solver.linear = 'auto' on {kind}: dense LU for {n_unknowns} unknowns "
                       f"(no sparse direct solver lowers on {kind})")
    elif name == "sparse":
        name = "jax-sparse" if sparse_gpu else "dense"
        why = ("cuSolver sparse QR via jax.experimental.sparse.linalg.spsolve" if sparse_gpu
               else f"dense LU: no sparse direct solver lowers on {kind}")
        _warn_once(f"solver.linear = 'sparse' on {kind}: klujax is CPU-only (importing it "
                   f"would move JAX to the CPU), using '{name}' ({why})")
    elif name == "jax-sparse" and not sparse_gpu:
        name = "dense"
        _warn_once(f"solver.linear = 'jax-sparse' on {kind}: spsolve lowers only on CPU and "
                   f"CUDA, using 'dense' (dense LU)")
    if name == "jax-sparse":
        return JaxSparseSolver()
    return LinearSolver(name)
