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

Symbolic analysis once per pattern: a scene on the sparse backend carries the pattern's
KLU analysis (:func:`klu_symbolic`, done outside jit, kept for the process) in
``Indices.lu_symbolic``; each solve then factors numerically only (``solve_with_symbol``,
the transposed solve of the reverse pass ``tsolve_with_symbol`` with the same analysis).

A factorization kept across solves (:class:`Factorization`, for modified Newton):
``refactor`` factors and frees the factorization it replaces, ``solve_factored`` runs the
triangular solves alone, ``release`` frees.  Dense: LU factors and pivots as arrays.
Sparse: klujax's numeric handle (a pointer held in a uint64 array), made inside the
compiled program; klujax frees a handle only when it wraps it in a Python object, so
:meth:`LinearSolver.release` frees it from inside the program through an XLA FFI call
into ``klujax_cpp.KLUNumeric(...).close()`` (:mod:`jaxform.klu_free`; not a host callback,
which would keep the program out of the persistent compilation cache), ordered before the
next factorization by a data dependency.  Measured (200 factorizations of a 20 000-unknown
banded matrix, 50 per program call): resident memory 309 -> 321 MB with the free,
+300 MB per 50 without.  ``refactor`` makes a fresh factorization (KLU's ``klu_factor``, partial
pivoting) and never ``klu_refactor`` (the old pivot order, which raises on a zero pivot:
a contact multiplier row has one once its node touches); ``refactor_and_solve`` measured
no faster than factor + solve at 100 x 100 anyway.

The reverse pass of a gradient run reuses such factorizations too (see
:mod:`jaxform.gradients`): ``solve_factored(..., transpose=True)`` (KLU's ``tsolve``,
or LU with ``trans=1``), :func:`matvec` on the pattern for the refinement,
:meth:`LinearSolver.factor_bytes` for the memory budget (KLU's own fill estimate),
:meth:`LinearSolver.release_now` for the owner to free the handles a compiled program
returned.
"""

from __future__ import annotations

import functools
import hashlib
import warnings
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

DENSE_LIMIT = 100  # unknowns; 'auto' picks dense below this
BACKENDS = ("auto", "dense", "sparse", "jax-sparse")
GPU_DENSE_LIMIT = 20_000  # unknowns; 'auto' on a GPU picks dense LU below this
SPARSE_GPU_PLATFORMS = ("cuda",)  # where jax.experimental.sparse.linalg.spsolve lowers


@jax.tree_util.register_dataclass
@dataclass(frozen=True)
class Factorization:
    """An LU factorization kept across Newton iterations and load steps (modified Newton).

    dense: ``lu`` (n, n) packed LU factors and ``piv`` (n,) pivots, as from
    ``jax.scipy.linalg.lu_factor``.  sparse: ``lu`` (1,) uint64, the handle of a KLU numeric
    factorization held by klujax (``piv`` unused), valid only inside the run that made it:
    :meth:`LinearSolver.refactor` frees the one it replaces, the run's owner frees the last
    (:meth:`LinearSolver.release`).  ``valid`` is False before the first factorization;
    ``count`` counts the factorizations made."""

    lu: jax.Array
    piv: jax.Array
    valid: jax.Array
    count: jax.Array


def _free_numeric(handle, valid):
    """Free one factorization from Python (:meth:`LinearSolver.release_now`)."""
    import klujax_cpp

    if bool(valid):
        klujax_cpp.KLUNumeric([int(v) for v in np.asarray(handle).ravel()]).close()
    return np.zeros((), np.int32)


_SYMBOLIC: dict = {}  # KLU symbolic analyses, kept alive for the process (one per pattern)


def klu_symbolic(rows, cols, n: int):
    """KLU's symbolic analysis (fill-reducing ordering, block triangular form) of the
    pattern, done once per pattern outside jit and kept for the process; returned as the
    uint64 handle that :meth:`LinearSolver.solve` and friends take as ``symbolic``."""
    import klujax

    rows = np.asarray(rows, dtype=np.int32)
    cols = np.asarray(cols, dtype=np.int32)
    key = (n, hashlib.sha1(rows.tobytes() + cols.tobytes()).hexdigest())
    if key not in _SYMBOLIC:
        _SYMBOLIC[key] = klujax.analyze(rows, cols, n)
    return jnp.asarray(_SYMBOLIC[key].raw, dtype=jnp.uint64)


@dataclass(frozen=True)
class LinearSolver:
    """``symbolic``: the pattern's KLU analysis (:func:`klu_symbolic`) or None; the sparse
    backend reuses it (factor + solve per call) instead of analysing per call."""

    backend: str = "dense"  # 'dense' | 'sparse'

    def solve(self, rows, cols, vals, b, n: int, symbolic=None):
        if self.backend == "dense":
            return jnp.linalg.solve(_dense(rows, cols, vals, n), b)
        import klujax  # lazy: see module docstring

        rows, cols = rows.astype(jnp.int32), cols.astype(jnp.int32)
        if symbolic is None:
            return klujax.solve(rows, cols, vals, b)
        return klujax.solve_with_symbol(rows, cols, vals, b, symbolic)

    def solve_transpose(self, rows, cols, vals, b, n: int, symbolic=None):
        if self.backend == "sparse" and symbolic is not None:
            import klujax

            return klujax.tsolve_with_symbol(
                rows.astype(jnp.int32), cols.astype(jnp.int32), vals, b, symbolic
            )
        return self.solve(cols, rows, vals, b, n)

    # -- a factorization kept across solves (modified Newton); dense and sparse only --

    def empty_factorization(self, n: int, dtype) -> Factorization:
        if self.backend == "dense":
            lu, piv = jnp.zeros((n, n), dtype), jnp.zeros(n, jnp.int32)
        else:
            lu, piv = jnp.zeros(1, jnp.uint64), jnp.zeros(0, jnp.int32)
        return Factorization(
            lu=lu, piv=piv, valid=jnp.asarray(False), count=jnp.asarray(0, jnp.int32)
        )

    def refactor(self, rows, cols, vals, n: int, symbolic, old: Factorization) -> Factorization:
        """A new factorization of the matrix; the sparse one replaced is freed."""
        if self.backend == "dense":
            lu, piv = jax.scipy.linalg.lu_factor(_dense(rows, cols, vals, n))
            return Factorization(
                lu=lu, piv=piv.astype(jnp.int32), valid=jnp.asarray(True), count=old.count + 1
            )
        import klujax

        if symbolic is None:
            raise ValueError(
                "a kept sparse factorization needs the pattern's KLU analysis "
                "(Indices.lu_symbolic = jaxform.linear.klu_symbolic(rows, cols, "
                "n); build_scene sets it for the sparse backend)"
            )
        token = self.release(old)
        handle = klujax.factor(
            rows.astype(jnp.int32),
            cols.astype(jnp.int32),
            vals,
            symbolic + token.astype(jnp.uint64),
        )  # after the free
        return Factorization(
            lu=handle.astype(jnp.uint64).reshape(1),
            piv=old.piv,
            valid=jnp.asarray(True),
            count=old.count + 1,
        )

    def solve_factored(self, fac: Factorization, b, symbolic, transpose: bool = False):
        """The triangular solves with a kept factorization of A: A y = b, or A^T y = b."""
        if self.backend == "dense":
            return jax.scipy.linalg.lu_solve((fac.lu, fac.piv), b, trans=1 if transpose else 0)
        import klujax

        solve = klujax.tsolve_with_numeric if transpose else klujax.solve_with_numeric
        return solve(fac.lu, b, symbolic).reshape(b.shape)

    def factor_bytes(self, n: int, nnz: int, symbolic=None) -> float:
        """Memory (bytes) of one kept factorization of an n x n matrix with nnz entries.

        dense: the LU factors and pivots.  sparse: from KLU's own fill estimate for its
        ordering (``lnz``, ``unz`` of the pattern's ``klu_symbolic``), 12 bytes per entry
        of L and U (value and row index) and 48 per column; measured on seed-scene
        Jacobians: 66.8 MB estimated / 68.9 MB resident at 100 x 100 (31 005 unknowns),
        7.9 / 8.8 MB at 40 x 40, hence the 15 % margin.  With a klujax other than the
        0.5 series (whose analysis handle is known to point at ``klu_symbolic``), or no
        analysis: 16 log2(n) bytes per entry of A, ~3x those measured sizes."""
        if self.backend == "dense":
            return 8.0 * n * n + 4.0 * n
        import klujax

        if symbolic is None or not str(getattr(klujax, "__version__", "")).startswith("0.5."):
            return 16.0 * nnz * np.log2(max(n, 2))
        lnz, unz = _klu_fill_estimate(int(np.asarray(symbolic).ravel()[0]))
        return 1.15 * (12.0 * (lnz + unz) + 48.0 * n)

    def release_now(self, fac: Factorization) -> None:
        """Free every valid sparse factorization in ``fac`` (any leading axes), outside jit:
        the owner's last word on handles returned by a compiled program."""
        if self.backend != "sparse" or fac is None:
            return
        handles = np.asarray(fac.lu).reshape(-1)
        valid = np.broadcast_to(np.asarray(fac.valid)[..., None], np.asarray(fac.lu).shape).reshape(
            -1
        )
        for h in handles[valid]:
            _free_numeric(h, True)

    def release(self, fac: Factorization):
        """Free a sparse factorization (a no-op for dense or an invalid one); returns an
        int32 zero to make later work depend on the free."""
        if self.backend == "dense":
            return jnp.zeros((), jnp.int32)
        from jaxform.klu_free import free_numeric

        return free_numeric(fac.lu, fac.valid)


def _dense(rows, cols, vals, n: int):
    return jnp.zeros((n, n), dtype=vals.dtype).at[rows, cols].set(vals)


def matvec(rows, cols, vals, y, n: int):
    """A y for A given by ``vals`` on the pattern (rows, cols); A^T y with the two swapped."""
    return jax.ops.segment_sum(vals * y[cols], rows, num_segments=n)


def _klu_fill_estimate(symbolic_address: int) -> tuple[float, float]:
    """(lnz, unz): KLU's estimates of the entries of L and U for its ordering, read from
    the public fields of ``klu_symbolic`` (klu.h: ``double symmetry, est_flops, lnz, unz``
    first), which klujax's analysis handle points to."""
    import ctypes

    lnz, unz = (ctypes.c_double.from_address(symbolic_address + 8 * k).value for k in (2, 3))
    if not (np.isfinite(lnz) and np.isfinite(unz) and lnz > 0 and unz > 0):
        raise RuntimeError(
            f"KLU fill estimate unreadable (lnz = {lnz}, unz = {unz}): the "
            f"installed klujax lays out its analysis differently"
        )
    return lnz, unz


class LinearBackendWarning(UserWarning):
    """The linear backend asked for does not run on this platform; another was chosen."""


@functools.cache
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

    def solve(self, rows, cols, vals, b, n: int, symbolic=None):
        indptr = jnp.searchsorted(rows, jnp.arange(n + 1, dtype=rows.dtype), side="left")
        return _spsolve_sequential(
            vals, cols.astype(jnp.int32), indptr.astype(jnp.int32), b, self.tol, self.reorder
        )

    def solve_transpose(self, rows, cols, vals, b, n: int, symbolic=None):
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
    where = platform_kind(platform)
    sparse_gpu = where in SPARSE_GPU_PLATFORMS
    if where == "cpu":
        if name == "auto":
            name = "dense" if n_unknowns < DENSE_LIMIT else "sparse"
    elif name == "auto":
        name = "dense" if n_unknowns < GPU_DENSE_LIMIT or not sparse_gpu else "jax-sparse"
        if name == "dense" and n_unknowns >= GPU_DENSE_LIMIT:
            _warn_once(
                f"solver.linear = 'auto' on {where}: dense LU for {n_unknowns} unknowns "
                f"(no sparse direct solver lowers on {where})"
            )
    elif name == "sparse":
        name = "jax-sparse" if sparse_gpu else "dense"
        why = (
            "cuSolver sparse QR via jax.experimental.sparse.linalg.spsolve"
            if sparse_gpu
            else f"dense LU: no sparse direct solver lowers on {where}"
        )
        _warn_once(
            f"solver.linear = 'sparse' on {where}: klujax is CPU-only (importing it "
            f"would move JAX to the CPU), using '{name}' ({why})"
        )
    elif name == "jax-sparse" and not sparse_gpu:
        name = "dense"
        _warn_once(
            f"solver.linear = 'jax-sparse' on {where}: spsolve lowers only on CPU and "
            f"CUDA, using 'dense' (dense LU)"
        )
    if name == "jax-sparse":
        return JaxSparseSolver()
    return LinearSolver(name)
