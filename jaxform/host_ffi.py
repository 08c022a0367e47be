"""XLA FFI targets whose handlers are Python functions made C-callable with ctypes.

A compiled program calls an FFI target by name, so a program loaded from the persistent
compilation cache (or :mod:`jaxform.program_store`) calls the handler this process
registered; a host callback (``pure_callback``, ``io_callback``) instead keeps the
program out of the cache, because a Python function cannot be serialized.  The handler
speaks the typed FFI calling convention of ``xla/ffi/api/c_api.h``; the structures it
reads are mirrored below.  Users: :mod:`jaxform.klu_free` (freeing klujax
factorizations) and :mod:`jaxform.pardiso` (MKL PARDISO).

:func:`register` makes a target of ``fn(args, rets)``, where ``args`` and ``rets`` are
lists of :class:`Buffer` views (NumPy arrays over XLA's memory, no copy), called at the
execute stage only.
"""

from __future__ import annotations

import ctypes as C
from dataclasses import dataclass

import jax
import numpy as np

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


@dataclass(frozen=True)
class Buffer:
    """One argument or result of an FFI call: its shape and its data's address."""

    address: int
    shape: tuple[int, ...]

    def view(self, ctype) -> np.ndarray:
        """The buffer as a NumPy array of ``ctype`` (no copy; writable for a result)."""
        size = int(np.prod(self.shape, dtype=np.int64))
        flat = np.ctypeslib.as_array(C.cast(self.address, C.POINTER(ctype)), (max(size, 1),))
        return flat[:size].reshape(self.shape)


def valid_handles(handles, valid) -> list[int]:
    """The handles (..., 1) whose flag (...) holds, as ints: the factorizations a free
    call (inside a program or outside) lets go."""
    handles = np.asarray(handles)
    ok = np.broadcast_to(np.asarray(valid, dtype=bool)[..., None], handles.shape)
    return [int(h) for h in handles[ok]]


def _buffers(span: _Span) -> list[Buffer]:
    out = []
    for i in range(span.size):
        buf = _Buffer.from_address(span.ptrs[i])
        out.append(Buffer(buf.data or 0, tuple(int(buf.dims[k]) for k in range(buf.rank))))
    return out


_HANDLER_TYPE = C.CFUNCTYPE(C.c_void_p, C.c_void_p)
_REGISTERED: dict[str, object] = {}  # target -> its ctypes function, alive for the process


def register(target: str, fn) -> None:
    """Register ``fn(args, rets)`` as the CPU FFI target ``target`` (once per process)."""
    if target in _REGISTERED:
        return

    def handler(frame_address: int):
        frame = _CallFrame.from_address(frame_address)
        if frame.extension_start:  # XLA asks which API version the handler speaks
            ext = _ExtensionBase.from_address(frame.extension_start)
            if ext.type == _EXTENSION_METADATA:
                meta = _MetadataExtension.from_address(frame.extension_start).metadata.contents
                meta.api_version.major, meta.api_version.minor = _API_VERSION
                meta.traits = 0
                return None
        if frame.stage == _STAGE_EXECUTE:
            fn(_buffers(frame.args), _buffers(frame.rets))
        return None

    c_fn = _HANDLER_TYPE(handler)
    new_capsule = C.pythonapi.PyCapsule_New
    new_capsule.restype = C.py_object
    new_capsule.argtypes = (C.c_void_p, C.c_char_p, C.c_void_p)
    jax.ffi.register_ffi_target(
        target, new_capsule(C.cast(c_fn, C.c_void_p).value, None, None), platform="cpu"
    )
    _REGISTERED[target] = c_fn
