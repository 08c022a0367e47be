"""Linear solve backends: one small object per backend behind one protocol, all usable
inside jit.

A matrix is given as values ``vals`` on a fixed sparsity pattern (unique rows/cols
computed once at set-up, passed in as *arguments* so that no large constant is baked
into the compiled program; the pattern from :meth:`jaxform.assembly.Model.with_pattern` is
sorted row-major).  Every backend implements :class:`LinearSolver`:

* :class:`DenseLU` (``dense``) scatters into an n x n array and calls LU;
* :class:`KLU` (``sparse``) calls klujax (SuiteSparse KLU as an XLA primitive), CPU only;
  the pattern's symbolic analysis is done once per pattern outside jit
  (:meth:`KLU.analyze`, carried in ``Indices.lu_symbolic``), so each solve factors
  numerically only; its handles and klujax's internals are in :mod:`jaxform.klu`;
* :class:`Pardiso` (``pardiso``) calls Intel MKL PARDISO (:mod:`jaxform.pardiso`; x86-64
  CPUs, where pypardiso and MKL are installed): a supernodal, multithreaded LU whose
  nested-dissection ordering suits 2-D meshes (a 200 x 200 seed Jacobian factors in
  about a twentieth of KLU's time); each factorization is a handle like KLU's;
* :class:`JaxSparse` (``jax-sparse``) calls ``jax.experimental.sparse.linalg.spsolve``:
  cuSolver's sparse QR on a CUDA GPU, SciPy's ``spsolve`` through a host callback on CPU
  (a reference there).  It has no batching rule, so under vmap it solves the batch one
  system after another.  It keeps no factorization.

:func:`choose_backend` maps ``solver.linear`` (``auto`` by size and platform: on CPU dense
below :data:`DENSE_LIMIT` unknowns, PARDISO from :data:`PARDISO_MIN_UNKNOWNS` where it is
installed, klujax between and otherwise) to one of them; on platforms other than CPU,
``sparse`` never imports klujax (that would move the process to CPU) and becomes
``jax-sparse`` on CUDA or ``dense`` elsewhere, and ``pardiso`` becomes ``dense``, with a
one-time :class:`LinearBackendWarning`.  The measurements behind the size thresholds are
in the benchmarks page of the documentation.

A factorization kept across solves (:class:`Factorization`, for modified Newton and the
reverse pass of gradient runs): ``refactor`` factors and frees the factorization it
replaces, ``solve_factored`` runs the triangular solves alone (``transpose`` for the
adjoint), ``release`` frees inside a program and ``release_now`` outside.  KLU's
factorizations are handles freed through an XLA FFI call (:mod:`jaxform.klu_free`; not a
host callback, which would keep the program out of the persistent compilation cache),
ordered before the next factorization by a data dependency; ``refactor`` makes a fresh
factorization (partial pivoting), never ``klu_refactor`` (the old pivot order raises on a
zero pivot: a contact multiplier row has one once its node touches).
"""

from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass
from typing import ClassVar, Protocol

import jax
import jax.numpy as jnp
import numpy as np

from jaxform import klu, pardiso

DENSE_LIMIT = 100  # unknowns; 'auto' picks dense below this on CPU
# unknowns from which 'auto' on CPU picks MKL PARDISO where it is installed (klujax below)
PARDISO_MIN_UNKNOWNS = 20_000
BACKENDS = ("auto", "dense", "sparse", "pardiso", "jax-sparse")
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


class LinearSolver(Protocol):
    """What a linear backend does.  ``symbolic`` is what :meth:`analyze` returned for the
    pattern (None for backends that need no analysis); ``transpose`` solves A^T y = b."""

    backend: ClassVar[str]  # its solver.linear name (for reports; never branched on)
    keeps_factorization: ClassVar[bool]  # refactor/solve_factored work (modified Newton)
    handles: ClassVar[bool]  # its factorizations are handles that must be freed
    modified_when_large: ClassVar[bool]  # solver.newton = 'auto' keeps its factorizations

    def analyze(self, rows, cols, n: int): ...

    def solve(self, rows, cols, vals, b, n: int, symbolic=None): ...

    def solve_transpose(self, rows, cols, vals, b, n: int, symbolic=None): ...

    def empty_factorization(self, n: int, dtype) -> Factorization: ...

    def refactor(self, rows, cols, vals, n: int, symbolic, old: Factorization) -> Factorization: ...

    def solve_factored(self, fac: Factorization, b, symbolic, transpose: bool = False): ...

    def factor_bytes(self, n: int, nnz: int, symbolic=None) -> float: ...

    def release(self, fac: Factorization): ...

    def release_now(self, fac: Factorization) -> None: ...


def _no_token():
    return jnp.zeros((), jnp.int32)


@dataclass(frozen=True)
class DenseLU:
    """LU of the matrix scattered into an n x n array; factorizations are arrays."""

    backend: ClassVar[str] = "dense"
    keeps_factorization: ClassVar[bool] = True
    handles: ClassVar[bool] = False
    modified_when_large: ClassVar[bool] = False

    def analyze(self, rows, cols, n: int):
        return None

    def solve(self, rows, cols, vals, b, n: int, symbolic=None):
        return jnp.linalg.solve(_dense(rows, cols, vals, n), b)

    def solve_transpose(self, rows, cols, vals, b, n: int, symbolic=None):
        return self.solve(cols, rows, vals, b, n)

    def empty_factorization(self, n: int, dtype) -> Factorization:
        return _empty(jnp.zeros((n, n), dtype), jnp.zeros(n, jnp.int32))

    def refactor(self, rows, cols, vals, n: int, symbolic, old: Factorization) -> Factorization:
        lu, piv = jax.scipy.linalg.lu_factor(_dense(rows, cols, vals, n))
        return Factorization(
            lu=lu, piv=piv.astype(jnp.int32), valid=jnp.asarray(True), count=old.count + 1
        )

    def solve_factored(self, fac: Factorization, b, symbolic, transpose: bool = False):
        return jax.scipy.linalg.lu_solve((fac.lu, fac.piv), b, trans=1 if transpose else 0)

    def factor_bytes(self, n: int, nnz: int, symbolic=None) -> float:
        return 8.0 * n * n + 4.0 * n

    def release(self, fac: Factorization):
        return _no_token()

    def release_now(self, fac: Factorization) -> None:
        return None


@dataclass(frozen=True)
class KLU:
    """klujax (SuiteSparse KLU): a symbolic analysis per pattern, a numeric factorization
    per matrix, held as a handle (a uint64) that :meth:`release` frees."""

    backend: ClassVar[str] = "sparse"
    keeps_factorization: ClassVar[bool] = True
    handles: ClassVar[bool] = True
    modified_when_large: ClassVar[bool] = True

    def analyze(self, rows, cols, n: int):
        return klu.symbolic(rows, cols, n)

    def solve(self, rows, cols, vals, b, n: int, symbolic=None):
        import klujax  # lazy: see jaxform.klu

        rows, cols = rows.astype(jnp.int32), cols.astype(jnp.int32)
        if symbolic is None:
            return klujax.solve(rows, cols, vals, b)
        return klu.solve_with_symbol(rows, cols, vals, b, symbolic)

    def solve_transpose(self, rows, cols, vals, b, n: int, symbolic=None):
        if symbolic is None:
            return self.solve(cols, rows, vals, b, n)
        rows, cols = rows.astype(jnp.int32), cols.astype(jnp.int32)
        return klu.solve_with_symbol(rows, cols, vals, b, symbolic, transpose=True)

    def empty_factorization(self, n: int, dtype) -> Factorization:
        return _empty(jnp.zeros(1, jnp.uint64), jnp.zeros(0, jnp.int32))

    def refactor(self, rows, cols, vals, n: int, symbolic, old: Factorization) -> Factorization:
        """A new factorization of the matrix; the one it replaces is freed first."""
        import klujax

        if symbolic is None:
            raise ValueError(
                "a kept sparse factorization needs the pattern's KLU analysis "
                "(Indices.lu_symbolic = KLU().analyze(rows, cols, n); build_scene sets it)"
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
        import klujax

        solve = klujax.tsolve_with_numeric if transpose else klujax.solve_with_numeric
        return solve(fac.lu, b, symbolic).reshape(b.shape)

    def factor_bytes(self, n: int, nnz: int, symbolic=None) -> float:
        """Memory (bytes) of one factorization: from KLU's own fill estimate for its
        ordering, 12 bytes per entry of L and U (value and row index) and 48 per column,
        plus 15 % (the margin seen against resident memory on seed-scene Jacobians);
        without the estimate (another klujax, or no analysis), 16 log2(n) bytes per entry
        of A, about 3x those sizes."""
        fill = klu.fill_estimate(symbolic)
        if fill is None:
            return 16.0 * nnz * np.log2(max(n, 2))
        return 1.15 * (12.0 * sum(fill) + 48.0 * n)

    def release(self, fac: Factorization):
        """Free the factorization inside a program (a no-op for an invalid one); returns an
        int32 zero to make later work depend on the free."""
        from jaxform.klu_free import free_numeric

        return free_numeric(fac.lu, fac.valid)

    def release_now(self, fac: Factorization) -> None:
        """Free every valid factorization in ``fac`` (any leading axes), outside jit: the
        owner's last word on handles returned by a compiled program."""
        if fac is not None:
            klu.free_now(fac.lu, fac.valid)


@dataclass(frozen=True)
class Pardiso:
    """Intel MKL PARDISO (:mod:`jaxform.pardiso`): supernodal LU, multithreaded, each
    factorization with its own analysis; factorizations are handles that :meth:`release`
    frees.  Needs the pattern's id from :meth:`analyze` (``Indices.lu_symbolic``)."""

    backend: ClassVar[str] = "pardiso"
    keeps_factorization: ClassVar[bool] = True
    handles: ClassVar[bool] = True
    modified_when_large: ClassVar[bool] = True

    def analyze(self, rows, cols, n: int):
        return pardiso.analyze(rows, cols, n)

    @staticmethod
    def _pattern(symbolic, rows=None, cols=None, n=0):
        """The pattern's id: ``symbolic``, or made here from a concrete pattern."""
        if symbolic is None and not isinstance(rows, jax.core.Tracer | None):
            return pardiso.analyze(np.asarray(rows), np.asarray(cols), n)
        if symbolic is None:
            raise ValueError(
                "solver.linear = 'pardiso' needs the pattern's analysis "
                "(Indices.lu_symbolic = Pardiso().analyze(rows, cols, n); build_scene sets it)"
            )
        return symbolic

    def solve(self, rows, cols, vals, b, n: int, symbolic=None):
        return pardiso.solve(vals, b, self._pattern(symbolic, rows, cols, n))

    def solve_transpose(self, rows, cols, vals, b, n: int, symbolic=None):
        return pardiso.solve(vals, b, self._pattern(symbolic, rows, cols, n), transpose=True)

    def empty_factorization(self, n: int, dtype) -> Factorization:
        return _empty(jnp.zeros(1, jnp.uint64), jnp.zeros(0, jnp.int32))

    def refactor(self, rows, cols, vals, n: int, symbolic, old: Factorization) -> Factorization:
        """A new factorization of the matrix; the one it replaces is freed (its memory
        reused)."""
        handle = pardiso.factor(old.lu, old.valid, vals, self._pattern(symbolic))
        return Factorization(lu=handle, piv=old.piv, valid=jnp.asarray(True), count=old.count + 1)

    def solve_factored(self, fac: Factorization, b, symbolic, transpose: bool = False):
        return pardiso.solve_factored(fac.lu, b, transpose)

    def factor_bytes(self, n: int, nnz: int, symbolic=None) -> float:
        """Memory (bytes) of one factorization: 6 log2(n) bytes per entry of A (the
        nested-dissection fill of a 2-D mesh grows as n log n; PARDISO's own peak of its
        numeric factorization on seed-scene Jacobians: 4.2, 4.5 and 4.6 log2(n) bytes per
        entry at 30 x 30, 100 x 100 and 200 x 200, 249 MB there) and the copy of A's
        values the factorization keeps."""
        return 6.0 * nnz * np.log2(max(n, 2)) + 8.0 * nnz

    def release(self, fac: Factorization):
        """Free the factorization inside a program (a no-op for an invalid one); returns an
        int32 zero to make later work depend on the free."""
        return pardiso.free(fac.lu, fac.valid)

    def release_now(self, fac: Factorization) -> None:
        if fac is not None:
            pardiso.free_now(fac.lu, fac.valid)


@dataclass(frozen=True)
class JaxSparse:
    """``jax.experimental.sparse.linalg.spsolve`` on the CSR form of the pattern.

    ``solve`` needs the pattern sorted row-major (as built by the assembly); the CSR row
    pointer is found in jit by a search.  ``solve_transpose`` re-sorts (cols, rows)
    row-major first.  ``tol`` is cuSolver's singularity threshold on |R_ii| of the QR
    factor; ``reorder`` its fill-reducing ordering (0 none, 1 symrcm, 2 symamd, 3 METIS).
    On CPU both are ignored (SciPy's spsolve).  It keeps no factorization."""

    backend: ClassVar[str] = "jax-sparse"
    keeps_factorization: ClassVar[bool] = False
    handles: ClassVar[bool] = False
    modified_when_large: ClassVar[bool] = False
    tol: float = 1e-14
    reorder: int = 3

    def analyze(self, rows, cols, n: int):
        return None

    def solve(self, rows, cols, vals, b, n: int, symbolic=None):
        indptr = jnp.searchsorted(rows, jnp.arange(n + 1, dtype=rows.dtype), side="left")
        return _spsolve_sequential(
            vals, cols.astype(jnp.int32), indptr.astype(jnp.int32), b, self.tol, self.reorder
        )

    def solve_transpose(self, rows, cols, vals, b, n: int, symbolic=None):
        rows_t, cols_t, vals_t = jax.lax.sort((cols, rows, vals), num_keys=2)
        return self.solve(rows_t, cols_t, vals_t, b, n)

    def _refuse(self, *args, **kwargs):
        raise ValueError(
            "the 'jax-sparse' linear backend keeps no factorization: use "
            "solver.linear = 'dense' or 'sparse' for modified Newton"
        )

    empty_factorization = refactor = solve_factored = _refuse

    def factor_bytes(self, n: int, nnz: int, symbolic=None) -> float:
        return float("inf")

    def release(self, fac: Factorization):
        return _no_token()

    def release_now(self, fac: Factorization) -> None:
        return None


def _empty(lu, piv) -> Factorization:
    return Factorization(lu=lu, piv=piv, valid=jnp.asarray(False), count=jnp.asarray(0, jnp.int32))


def _dense(rows, cols, vals, n: int):
    return jnp.zeros((n, n), dtype=vals.dtype).at[rows, cols].set(vals)


def matvec(rows, cols, vals, y, n: int):
    """A y for A given by ``vals`` on the pattern (rows, cols); A^T y with the two swapped."""
    return jax.ops.segment_sum(vals * y[cols], rows, num_segments=n)


class LinearBackendWarning(UserWarning):
    """The linear backend asked for does not run on this platform; another was chosen."""


@functools.cache
def _warn_once(message: str) -> None:
    warnings.warn(message, LinearBackendWarning, stacklevel=3)


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
            if n_unknowns >= PARDISO_MIN_UNKNOWNS and pardiso.available():
                name = "pardiso"
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
    if name == "pardiso" and (where != "cpu" or not pardiso.available()):
        name = "sparse" if where == "cpu" else "dense"
        _warn_once(
            f"solver.linear = 'pardiso' on {where}: MKL PARDISO is not available here "
            f"(pypardiso and MKL, x86-64 CPU), using '{name}'"
        )
    return {"dense": DenseLU, "sparse": KLU, "pardiso": Pardiso, "jax-sparse": JaxSparse}[name]()


def register_ffi_targets() -> None:
    """Register jaxform's FFI targets with XLA (once per process): a program loaded
    without being traced (:mod:`jaxform.program_store`) calls them too."""
    from jaxform import klu_free

    klu_free.register_target()
    pardiso.register_targets()  # MKL itself is loaded by the first call, not here
