"""Free a klujax numeric factorization from inside a compiled program, as an XLA FFI call.

klujax makes its numeric factorizations inside the program (a handle, a pointer held in a
uint64 array) but frees one only when Python wraps it (``klujax_cpp.KLUNumeric(...)
.close()``).  Modified Newton and the gradient run free the factorizations they replace
from inside the program.  Through ``io_callback`` that made the program uncacheable: JAX
does not write a program with a host callback to the persistent compilation cache (a
Python function cannot be serialized), so those programs compiled again on every run.

Here the free is an XLA FFI custom call instead: a target named :data:`TARGET` whose
handler is a C-callable function made with ctypes (the typed FFI calling convention of
``xla/ffi/api/c_api.h``, the structures it reads mirrored below), registered once per
process the first time a program uses it.  A program refers to the target by name only,
so a program loaded from the cache calls this process's handler.  The handler frees each
valid handle of the call (any batch shape) and writes zeros to its int32 result, the
token that orders later work after the free.
"""

from __future__ import annotations

import ctypes as C
import functools

import jax
import jax.numpy as jnp
import numpy as np

TARGET = "jaxform_klu_free_numeric"
_API_VERSION = (0, 1)  # the XLA FFI C API version the structures below follow
_STAGE_EXECUTE = 3
_EXTENSION_METADATA = 1


class _ExtensionBase(C.Structure):
    _fields_ = [("struct_size", C.c_size_t), ("type", C.c_int), ("next", C.c_void_p)]


class _ApiVersion(C.Structure):
    _fields_ = [
        ("struct_size", C.c_size_t),
        ("extension_start", C.c_void_p),
        ("major", C.c_int),
        ("minor", C.c_int),
    ]


class _Metadata(C.Structure):
    _fields_ = [
        ("struct_size", C.c_size_t),
        ("api_version", _ApiVersion),
        ("traits", C.c_uint32),
        ("state_type_id", C.c_int64),
    ]


class _MetadataExtension(C.Structure):
    _fields_ = [("base", _ExtensionBase), ("metadata", C.POINTER(_Metadata))]


class _Span(C.Structure):  # XLA_FFI_Args and XLA_FFI_Rets
    _fields_ = [
        ("struct_size", C.c_size_t),
        ("extension_start", C.c_void_p),
        ("size", C.c_int64),
        ("types", C.c_void_p),
        ("ptrs", C.POINTER(C.c_void_p)),
    ]


class _Attrs(C.Structure):
    _fields_ = [
        ("struct_size", C.c_size_t),
        ("extension_start", C.c_void_p),
        ("size", C.c_int64),
        ("types", C.c_void_p),
        ("names", C.c_void_p),
        ("attrs", C.c_void_p),
    ]


class _CallFrame(C.Structure):
    _fields_ = [
        ("struct_size", C.c_size_t),
        ("extension_start", C.c_void_p),
        ("api", C.c_void_p),
        ("ctx", C.c_void_p),
        ("stage", C.c_int),
        ("args", _Span),
        ("rets", _Span),
        ("attrs", _Attrs),
        ("future", C.c_void_p),
    ]


class _Buffer(C.Structure):
    _fields_ = [
        ("struct_size", C.c_size_t),
        ("extension_start", C.c_void_p),
        ("dtype", C.c_int),
        ("data", C.c_void_p),
        ("rank", C.c_int64),
        ("dims", C.POINTER(C.c_int64)),
    ]


def _array(buffer_address: int, ctype) -> np.ndarray:
    buf = _Buffer.from_address(buffer_address)
    size = int(np.prod([buf.dims[i] for i in range(buf.rank)], dtype=np.int64))
    return np.ctypeslib.as_array(C.cast(buf.data, C.POINTER(ctype)), (max(size, 1),))[:size]


def _handler(frame_address: int):
    """The FFI handler: NULL (success) for every stage; frees at the execute stage."""
    import klujax_cpp

    frame = _CallFrame.from_address(frame_address)
    if frame.extension_start:  # XLA asks which API version the handler speaks
        ext = _ExtensionBase.from_address(frame.extension_start)
        if ext.type == _EXTENSION_METADATA:
            meta = _MetadataExtension.from_address(frame.extension_start).metadata.contents
            meta.api_version.major, meta.api_version.minor = _API_VERSION
            meta.traits = 0
            return None
    if frame.stage != _STAGE_EXECUTE:
        return None
    handles = _array(frame.args.ptrs[0], C.c_uint64)
    valid = _array(frame.args.ptrs[1], C.c_bool)
    per_flag = handles.size // max(valid.size, 1)  # handles (..., 1), flags (...)
    for h in handles[np.repeat(valid, per_flag)]:
        klujax_cpp.KLUNumeric([int(h)]).close()
    _array(frame.rets.ptrs[0], C.c_int32)[:] = 0
    return None


_HANDLER_TYPE = C.CFUNCTYPE(C.c_void_p, C.c_void_p)


@functools.cache
def _registered():
    """Register :data:`TARGET` with XLA (once per process); the ctypes function is kept
    alive by this cache for the life of the process."""
    fn = _HANDLER_TYPE(_handler)
    new_capsule = C.pythonapi.PyCapsule_New
    new_capsule.restype = C.py_object
    new_capsule.argtypes = (C.c_void_p, C.c_char_p, C.c_void_p)
    jax.ffi.register_ffi_target(
        TARGET, new_capsule(C.cast(fn, C.c_void_p).value, None, None), platform="cpu"
    )
    return fn


def register_ffi_targets() -> None:
    """Register jaxform's FFI targets with XLA (once per process): a program loaded
    without being traced (:mod:`jaxform.program_store`) calls them too."""
    _registered()


def free_numeric(handle, valid):
    """Free the klujax numeric factorizations ``handle`` (uint64, (..., 1)) where ``valid``
    (bool, (...)) holds; an int32 zero of ``valid``'s shape, to order later work after it."""
    _registered()
    valid = jnp.asarray(valid, dtype=jnp.bool_)
    call = jax.ffi.ffi_call(
        TARGET,
        jax.ShapeDtypeStruct(valid.shape, jnp.int32),
        has_side_effect=True,
        vmap_method="broadcast_all",
    )
    return call(jnp.asarray(handle, dtype=jnp.uint64), valid)
