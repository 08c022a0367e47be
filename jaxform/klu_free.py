"""Free a klujax numeric factorization from inside a compiled program, as an XLA FFI call.

klujax makes its numeric factorizations inside the program (a handle, a pointer held in a
uint64 array) but frees one only when Python wraps it (``klujax_cpp.KLUNumeric(...)
.close()``).  Modified Newton and the gradient run free the factorizations they replace
from inside the program.  Through ``io_callback`` that made the program uncacheable: JAX
does not write a program with a host callback to the persistent compilation cache (a
Python function cannot be serialized), so those programs compiled again on every run.

Here the free is an XLA FFI custom call instead: a target named :data:`TARGET` whose
handler is a C-callable function made with ctypes (:mod:`jaxform.host_ffi`), registered
once per process the first time a program uses it.  A program refers to the target by
name only, so a program loaded from the cache calls this process's handler.  The handler frees each
valid handle of the call (any batch shape) and writes zeros to its int32 result, the
token that orders later work after the free.
"""

from __future__ import annotations

import ctypes as C

import jax
import jax.numpy as jnp

from jaxform.host_ffi import register, valid_handles

TARGET = "jaxform_klu_free_numeric"


def _free(args, rets):
    """Free each valid handle of the call (handles (..., 1), flags (...)); zeros out."""
    import klujax_cpp

    for h in valid_handles(args[0].view(C.c_uint64), args[1].view(C.c_bool)):
        klujax_cpp.KLUNumeric([h]).close()
    rets[0].view(C.c_int32)[...] = 0


def register_target() -> None:
    """Register :data:`TARGET` with XLA (once per process)."""
    register(TARGET, _free)


def free_numeric(handle, valid):
    """Free the klujax numeric factorizations ``handle`` (uint64, (..., 1)) where ``valid``
    (bool, (...)) holds; an int32 zero of ``valid``'s shape, to order later work after it."""
    register_target()
    valid = jnp.asarray(valid, dtype=jnp.bool_)
    call = jax.ffi.ffi_call(
        TARGET,
        jax.ShapeDtypeStruct(valid.shape, jnp.int32),
        has_side_effect=True,
        vmap_method="broadcast_all",
    )
    return call(jnp.asarray(handle, dtype=jnp.uint64), valid)
