"""Intel MKL PARDISO (supernodal, multithreaded sparse LU) inside compiled programs.

The solver is MKL's ``pardiso`` (from the ``mkl`` wheel that ``pypardiso`` brings, found
through pypardiso's own search for ``mkl_rt``), called by XLA FFI targets whose handlers
are ctypes functions (:mod:`jaxform.host_ffi`), so a program that solves with it is
cached and stored like any other.  A matrix is real and unsymmetric (PARDISO's matrix
type 11), given as values on a pattern whose compressed-row form (zero-based) is made
once per pattern on the host by :func:`analyze`; the program carries the pattern's id.

Factorizations are handles (uint64 ids into this process's table of PARDISO instances),
as klujax's are: :func:`factor` makes one (reusing the memory of the one it replaces),
:func:`solve_factored` solves with it (A or A^T), :func:`free` frees it inside a program
and :func:`free_now` outside.  Each factorization runs PARDISO's analysis (fill-reducing
nested dissection, weighted matching and scaling of the values) and its numeric
factorization (phase 12): the matching depends on the values, and a contact
multiplier's row changes from the identity to a constraint when its node touches, so no
analysis is reused across matrices.  PARDISO pivots within its supernodes and perturbs
a pivot that is still too small, which on a singular matrix gives a finite "solution" of
no meaning: where it perturbed one (``iparm(14)``), the matrix is factored again by
SciPy's SuperLU with partial pivoting (counted in :data:`STATS`), as klujax would, and a
factorization that fails (an exactly singular matrix) gives NaN solutions: the Newton
solve then reports a non-finite step, as with the other backends.  The factorization
keeps a copy of the values (PARDISO's iterative refinement reads them).

Reproducibility: the threaded factorization sums in an order that can change from run to
run, so two runs of a large scene agree to round-off (a 200 x 200 seed Jacobian's
solution differed in its last bits in two of five processes; the force histories to
1e-15, the Newton iterations by up to 1 %), not to the bit.  PARDISO's own reproducible
mode (``iparm(34)``) doubles the triangular solves there (39 -> 78 ms), and one thread
makes the factorization 1.5x slower; neither is the default.  ``solver.linear =
"sparse"`` (klujax) gives runs equal to the bit.

:func:`solve` (and its transpose) factors, solves and frees in one call, on an instance
kept per pattern, for a solve that keeps no factorization (full Newton).
"""

from __future__ import annotations

import ctypes as C
import functools
import hashlib
import itertools
import threading

import jax
import jax.numpy as jnp
import numpy as np

from jaxform.host_ffi import register, valid_handles

MTYPE = 11  # real unsymmetric
STATS = {"partial_pivoting": 0}  # factorizations redone with partial pivoting (SuperLU)
TARGETS = {
    "solve": "jaxform_pardiso_solve",
    "solve_t": "jaxform_pardiso_solve_t",
    "factor": "jaxform_pardiso_factor",
    "solve_factored": "jaxform_pardiso_solve_factored",
    "solve_factored_t": "jaxform_pardiso_solve_factored_t",
    "free": "jaxform_pardiso_free",
}

_LOCK = threading.Lock()
_PATTERNS: dict[int, tuple[int, np.ndarray, np.ndarray]] = {}  # id -> (n, ia, ja)
_PATTERN_IDS: dict[tuple, int] = {}
_FACTORS: dict[int, _Instance] = {}
_SCRATCH: dict[int, _Instance] = {}  # pattern id -> the instance of one-call solves
_IDS = itertools.count(1)  # 0: no factorization


@functools.cache
def _library():
    """MKL's ``pardiso`` and ``pardisoinit`` with their argument types (ImportError where
    pypardiso or MKL is missing)."""
    from pypardiso.pardiso_wrapper import PyPardisoSolver

    lib = PyPardisoSolver().libmkl  # pypardiso's search for mkl_rt
    i32p, vp = C.POINTER(C.c_int32), C.c_void_p
    lib.pardiso.argtypes = [vp, i32p, i32p, i32p, i32p, i32p, vp, vp, vp, vp, i32p, vp, i32p,
                            vp, vp, i32p]  # fmt: skip
    lib.pardiso.restype = None
    lib.pardisoinit.argtypes = [vp, i32p, vp]
    lib.pardisoinit.restype = None
    return lib


def available() -> bool:
    """Whether MKL PARDISO can be loaded here (pypardiso and MKL installed)."""
    try:
        _library()
    except (ImportError, OSError, AttributeError):
        return False
    return True


class _Instance:
    """One PARDISO instance: its internal handle ``pt``, its parameters ``iparm``, the
    values it factored (for iterative refinement) and whether that worked."""

    def __init__(self):
        self.pt = np.zeros(64, dtype=np.int64)
        self.iparm = np.zeros(64, dtype=np.int32)
        _library().pardisoinit(
            self.pt.ctypes.data, C.byref(C.c_int32(MTYPE)), self.iparm.ctypes.data
        )
        self.iparm[34] = 1  # zero-based ia, ja
        self.values = None
        self.pattern = None
        self.ok = False
        self.exact = None  # SuperLU's factors where PARDISO perturbed a pivot
        self.lock = threading.Lock()

    def _call(self, phase: int, b=None, x=None) -> int:
        n, ia, ja = _PATTERNS[self.pattern]
        err = C.c_int32(0)
        one = C.c_int32(1)
        _library().pardiso(
            self.pt.ctypes.data, C.byref(one), C.byref(one), C.byref(C.c_int32(MTYPE)),
            C.byref(C.c_int32(phase)), C.byref(C.c_int32(n)),
            None if self.values is None else self.values.ctypes.data,
            ia.ctypes.data, ja.ctypes.data, None, C.byref(one), self.iparm.ctypes.data,
            C.byref(C.c_int32(0)), None if b is None else b.ctypes.data,
            None if x is None else x.ctypes.data, C.byref(err),
        )  # fmt: skip
        return int(err.value)

    def factor(self, pattern: int, values: np.ndarray) -> None:
        self.release()
        self.pattern, self.values = pattern, np.array(values, dtype=np.float64)
        self.ok = self._call(12) == 0
        if self.ok and int(self.iparm[13]) > 0:  # pivots PARDISO perturbed (iparm(14))
            self._partial_pivoting()

    def _partial_pivoting(self) -> None:
        """The matrix factored again by SuperLU with partial pivoting (SciPy), which
        fails on an exactly singular matrix where PARDISO's perturbed pivots would give
        a finite answer of no meaning."""
        import scipy.sparse as sp
        import scipy.sparse.linalg as spl

        n, ia, ja = _PATTERNS[self.pattern]
        STATS["partial_pivoting"] += 1
        try:
            self.exact = spl.splu(sp.csr_matrix((self.values, ja, ia), shape=(n, n)).tocsc())
        except RuntimeError:  # "Factor is exactly singular"
            self.ok = False

    def solve(self, b: np.ndarray, x: np.ndarray, transpose: bool) -> None:
        if not self.ok:
            x[...] = np.nan
            return
        if self.exact is not None:
            x[...] = self.exact.solve(
                np.asarray(b, dtype=np.float64), trans="T" if transpose else "N"
            )
            return
        self.iparm[11] = 2 if transpose else 0
        rhs = np.array(b, dtype=np.float64)  # PARDISO may write to b while refining
        out = np.empty_like(rhs)
        if self._call(33, rhs, out) != 0:
            out[...] = np.nan
        x[...] = out

    def release(self) -> None:
        if self.pattern is not None:
            self._call(-1)
        self.ok, self.values, self.exact = False, None, None


def analyze(rows, cols, n: int):
    """The id (a (1,) uint64 device array) of the pattern (rows, cols), which must be in
    row-major order without repeats (as the assembly builds it), its compressed-row form
    kept for the process."""
    rows = np.asarray(rows, dtype=np.int64)
    cols = np.asarray(cols, dtype=np.int64)
    keys = rows * n + cols
    if keys.size and np.any(np.diff(keys) <= 0):
        raise ValueError("PARDISO: the pattern must be sorted row-major without repeats")
    key = (n, hashlib.sha1(keys.tobytes()).hexdigest())  # as klu.symbolic keys its analyses
    with _LOCK:
        if key not in _PATTERN_IDS:
            ia = np.searchsorted(rows, np.arange(n + 1)).astype(np.int32)
            pid = next(_IDS)
            _PATTERNS[pid] = (n, ia, cols.astype(np.int32))
            _PATTERN_IDS[key] = pid
        pid = _PATTERN_IDS[key]
    return jax.device_put(np.array([pid], dtype=np.uint64))


def _rows(buffer, ctype, width: int) -> np.ndarray:
    """A buffer as (batch, width)."""
    return buffer.view(ctype).reshape(-1, width)


def _solve_handler(transpose: bool):
    def handler(args, rets):
        sym = _rows(args[2], C.c_uint64, 1)[:, 0]
        n = _PATTERNS[int(sym[0])][0]
        b, x = _rows(args[1], C.c_double, n), _rows(rets[0], C.c_double, n)
        vals = _rows(args[0], C.c_double, args[0].shape[-1])
        for i in range(b.shape[0]):
            pid = int(sym[i])
            with _LOCK:
                inst = _SCRATCH.get(pid)
                if inst is None:
                    inst = _SCRATCH[pid] = _Instance()
            with inst.lock:  # one factor-and-solve at a time on the pattern's instance
                inst.factor(pid, vals[i])
                inst.solve(b[i], x[i], transpose)
                inst.release()  # its memory back: a remeshed run has a pattern per mesh

    return handler


def _factor_handler(args, rets):
    old = _rows(args[0], C.c_uint64, 1)[:, 0]
    valid = args[1].view(C.c_bool).reshape(-1)
    vals = _rows(args[2], C.c_double, args[2].shape[-1])
    sym = _rows(args[3], C.c_uint64, 1)[:, 0]
    out = _rows(rets[0], C.c_uint64, 1)[:, 0]
    for i in range(out.shape[0]):
        with _LOCK:
            inst = _FACTORS.pop(int(old[i]), None) if valid[i] else None
        inst = inst or _Instance()
        inst.factor(int(sym[i]), vals[i])
        new = next(_IDS)
        with _LOCK:
            _FACTORS[new] = inst
        out[i] = new


def _solve_factored_handler(transpose: bool):
    def handler(args, rets):
        handles = _rows(args[0], C.c_uint64, 1)[:, 0]
        n = args[1].shape[-1]
        b, x = _rows(args[1], C.c_double, n), _rows(rets[0], C.c_double, n)
        for i in range(b.shape[0]):
            inst = _FACTORS.get(int(handles[i]))
            if inst is None:
                x[i] = np.nan
                continue
            with inst.lock:  # XLA may run two solves of one factorization at once
                inst.solve(b[i], x[i], transpose)  # (iparm(12), the transpose flag, is shared)

    return handler


def _free_ids(handles, valid) -> None:
    for h in valid_handles(handles, valid):
        with _LOCK:
            inst = _FACTORS.pop(h, None)
        if inst is not None:
            with inst.lock:
                inst.release()


def _free_handler(args, rets):
    _free_ids(args[0].view(C.c_uint64), args[1].view(C.c_bool))
    rets[0].view(C.c_int32)[...] = 0


@functools.cache
def register_targets() -> None:
    """Register the PARDISO FFI targets with XLA (once per process)."""
    register(TARGETS["solve"], _solve_handler(False))
    register(TARGETS["solve_t"], _solve_handler(True))
    register(TARGETS["factor"], _factor_handler)
    register(TARGETS["solve_factored"], _solve_factored_handler(False))
    register(TARGETS["solve_factored_t"], _solve_factored_handler(True))
    register(TARGETS["free"], _free_handler)


def _call(name: str, out, *args, side_effect: bool = False):
    register_targets()
    return jax.ffi.ffi_call(
        TARGETS[name], out, has_side_effect=side_effect, vmap_method="broadcast_all"
    )(*args)


def solve(vals, b, symbolic, transpose: bool = False):
    """x with A x = b (A^T x = b), A = ``vals`` on the pattern ``symbolic``, factored
    within the call."""
    name = "solve_t" if transpose else "solve"
    out = jax.ShapeDtypeStruct(b.shape, jnp.float64)
    return _call(name, out, vals.astype(jnp.float64), b.astype(jnp.float64),
                 jnp.asarray(symbolic, jnp.uint64).reshape(-1)[:1])  # fmt: skip


def factor(old, old_valid, vals, symbolic):
    """A new factorization (a (1,) uint64 handle) of A = ``vals`` on the pattern; the
    valid factorization ``old`` it replaces is freed (its memory reused)."""
    out = jax.ShapeDtypeStruct((1,), jnp.uint64)
    return _call("factor", out, jnp.asarray(old, jnp.uint64).reshape(1),
                 jnp.asarray(old_valid, jnp.bool_), vals.astype(jnp.float64),
                 jnp.asarray(symbolic, jnp.uint64).reshape(-1)[:1], side_effect=True)  # fmt: skip


def solve_factored(handle, b, transpose: bool = False):
    """x with A x = b (A^T x = b) by the factorization ``handle``."""
    name = "solve_factored_t" if transpose else "solve_factored"
    out = jax.ShapeDtypeStruct(b.shape, jnp.float64)
    return _call(name, out, jnp.asarray(handle, jnp.uint64), b.astype(jnp.float64))


def free(handle, valid):
    """Free the factorizations ``handle`` ((..., 1)) where ``valid`` ((...)) holds; an
    int32 zero of ``valid``'s shape, to order later work after it."""
    valid = jnp.asarray(valid, dtype=jnp.bool_)
    out = jax.ShapeDtypeStruct(valid.shape, jnp.int32)
    return _call("free", out, jnp.asarray(handle, jnp.uint64), valid, side_effect=True)


def free_now(handles, valid) -> None:
    """Free the valid factorizations outside jit (handles (..., 1), flags (...))."""
    if handles is not None:
        _free_ids(np.asarray(handles, dtype=np.uint64), valid)


def live_factorizations() -> int:
    """How many factorizations this process holds, kept ones and one-call solves' (for
    tests)."""
    return len(_FACTORS) + sum(inst.values is not None for inst in _SCRATCH.values())
