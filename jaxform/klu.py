"""klujax internals in one place: the pattern's symbolic analysis, KLU's fill estimate read
from the analysis handle, and freeing numeric factorizations from Python.

klujax hands out raw handles (pointers held in uint64 arrays).  Reading a field behind
one (``klu_symbolic``'s ``lnz``/``unz``) depends on the klujax build, so it is guarded
by :data:`RAW_READS_VERSION`: with another klujax, :func:`fill_estimate` returns None and
callers fall back to a conservative estimate.  Freeing a factorization from inside a
compiled program is :mod:`jaxform.klu_free` (an XLA FFI call).  klujax is imported
lazily: importing it switches JAX to CPU and float64 process-wide.
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


def free_now(handles, valid) -> None:
    """Free the valid numeric factorizations outside jit: ``handles`` (..., 1) uint64,
    ``valid`` (...) bool, as in :class:`jaxform.linear.Factorization`."""
    import klujax_cpp

    handles = np.asarray(handles)
    ok = np.broadcast_to(np.asarray(valid)[..., None], handles.shape).reshape(-1)
    for h in handles.reshape(-1)[ok]:
        klujax_cpp.KLUNumeric([int(h)]).close()
