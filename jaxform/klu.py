"""klujax internals in one place: the pattern's symbolic analysis, KLU's fill estimate read
from the analysis handle, the solve with the analysis of a pattern already in order, and
freeing numeric factorizations from Python.

klujax hands out raw handles (pointers held in uint64 arrays).  Reading a field behind
one (``klu_symbolic``'s ``lnz``/``unz``) depends on the klujax build, so it is guarded
by :data:`RAW_READS_VERSION`: with another klujax, :func:`fill_estimate` returns None and
callers fall back to a conservative estimate.  klujax's ``solve_with_symbol`` (and its
transpose) sorts the pattern row-major inside the program at every call (a lexsort of all
the entries, about as dear as KLU's factorization on small meshes: the benchmarks page,
"klujax's sort"); jaxform's
patterns are built sorted (:meth:`jaxform.assembly.Model.with_pattern`), so
:func:`solve_with_symbol` binds klujax's solve primitive to them as they are (the same
primitive, so the same derivative and batching rules), in that series only.  Freeing a
factorization from inside a compiled program is :mod:`jaxform.klu_free` (an XLA FFI
call).  klujax is imported lazily: importing it switches JAX to CPU and float64
process-wide.
"""

from __future__ import annotations

import ctypes
import hashlib

import jax
import numpy as np

RAW_READS_VERSION = "0.5."  # the klujax series whose analysis handle is a klu_symbolic*

_SYMBOLIC: dict = {}  # KLU symbolic analyses, kept alive for the process (one per pattern)


def symbolic(rows, cols, n: int):
    """KLU's symbolic analysis (fill-reducing ordering, block triangular form) of the
    pattern, done once per pattern outside jit and kept for the process; returned as the
    uint64 handle the sparse backend takes as ``symbolic``."""
    import klujax

    rows = np.asarray(rows, dtype=np.int32)
    cols = np.asarray(cols, dtype=np.int32)
    key = (n, hashlib.sha1(rows.tobytes() + cols.tobytes()).hexdigest())
    if key not in _SYMBOLIC:
        _SYMBOLIC[key] = klujax.analyze(rows, cols, n)
    return jax.device_put(np.asarray(_SYMBOLIC[key].raw, dtype=np.uint64))  # no program


def raw_reads_supported() -> bool:
    """Whether the installed klujax is the series whose handles :func:`fill_estimate`
    knows how to read."""
    import klujax

    return str(getattr(klujax, "__version__", "")).startswith(RAW_READS_VERSION)


def fill_estimate(symbolic_handle) -> tuple[float, float] | None:
    """(lnz, unz): KLU's estimates of the entries of L and U for its ordering, read from
    the public fields of ``klu_symbolic`` (klu.h: ``double symmetry, est_flops, lnz, unz``
    first), which klujax's analysis handle points to; None with another klujax."""
    if symbolic_handle is None or not raw_reads_supported():
        return None
    address = int(np.asarray(symbolic_handle).ravel()[0])
    lnz, unz = (ctypes.c_double.from_address(address + 8 * k).value for k in (2, 3))
    if not (np.isfinite(lnz) and np.isfinite(unz) and lnz > 0 and unz > 0):
        raise RuntimeError(
            f"KLU fill estimate unreadable (lnz = {lnz}, unz = {unz}): the "
            f"installed klujax lays out its analysis differently"
        )
    return lnz, unz


def solve_with_symbol(rows, cols, vals, b, symbolic, transpose: bool = False):
    """x with A x = b (A^T x = b for ``transpose``), A given by ``vals`` on the pattern
    (rows, cols), int32, factored with the pattern's analysis ``symbolic`` and freed
    within the call: klujax's ``(t)solve_with_symbol`` without its sort of the pattern
    (the klujax series of :data:`RAW_READS_VERSION`, float64), else that function
    itself.  KLU takes a pattern in any order; in row-major order (the assembly's) the
    solution is klujax's own to the last bit."""
    import jax.numpy as jnp
    import klujax

    if not raw_reads_supported() or vals.dtype != jnp.float64 or b.dtype != jnp.float64:
        solve = klujax.tsolve_with_symbol if transpose else klujax.solve_with_symbol
        return solve(rows, cols, vals, b, symbolic)
    prim = klujax.tsolve_with_symbol_f64 if transpose else klujax.solve_with_symbol_f64
    x = prim.bind(rows, cols, vals[None, :], b.reshape(1, b.shape[0], -1),
                  jnp.asarray(symbolic).astype(jnp.uint64))  # fmt: skip
    return x.reshape(b.shape)


def free_now(handles, valid) -> None:
    """Free the valid numeric factorizations outside jit: ``handles`` (..., 1) uint64,
    ``valid`` (...) bool, as in :class:`jaxform.linear.Factorization`."""
    import klujax_cpp

    from jaxform.host_ffi import valid_handles

    for h in valid_handles(handles, valid):
        klujax_cpp.KLUNumeric([h]).close()
