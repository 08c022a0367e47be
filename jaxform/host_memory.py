"""The process's heap: large blocks handed back to the system when freed.

glibc's malloc serves a block from its heap below a threshold and maps it from the
system above; after a mapped block is freed the threshold rises to that block's size
(up to 32 MiB), so the blocks of a run (a chunk's per-step fields, XLA's buffers of a
few MiB each, KLU's work arrays) come from the heap from then on, where freed memory
stays resident between chunks.  :func:`map_large_blocks` fixes the threshold, so such
blocks are mapped and unmapped.  It changes the whole process: the command line calls
it (it owns the process); importing jaxform does not.  :func:`give_back` returns the
free pages inside the heap (what compiling a program leaves: ~0.8 GB after the 200 x 200
seed scene's chunk); it changes no setting, and the host loop calls it after a chunk
that took long enough for the trim's cost not to count (:func:`give_back_after`).
"""

from __future__ import annotations

import ctypes
from functools import cache

M_MMAP_THRESHOLD = -3  # malloc.h
LARGE_BLOCK_BYTES = 4 << 20


@cache
def _libc():
    """glibc (the symbols the process has loaded), or None (another C library)."""
    try:
        lib = ctypes.CDLL(None)
        lib.mallopt, lib.malloc_trim  # noqa: B018 (glibc's: both or neither)
    except (OSError, AttributeError):
        return None
    return lib


def give_back() -> None:
    """Hand the heap's free pages back to the system (glibc's ``malloc_trim(0)``; a
    no-op without glibc)."""
    lib = _libc()
    if lib is not None:
        lib.malloc_trim(0)


WORTH_S = 2.0  # the least work (s) after which a trim is worth its cost


def give_back_after(work_s: float) -> None:
    """:func:`give_back` after work of ``work_s`` seconds if that is at least
    :data:`WORTH_S`: a trim walks the heap (15 - 35 ms in a process that ran a few
    scenes, 57 trims = 1.0 s of an 8.4 s run of 1-step chunks), so short work keeps
    its free pages."""
    if work_s >= WORTH_S:
        give_back()


def map_large_blocks(threshold_bytes: int = LARGE_BLOCK_BYTES) -> bool:
    """Serve every allocation of ``threshold_bytes`` or more by its own mapping (glibc's
    ``mallopt(M_MMAP_THRESHOLD)``, which also stops the threshold from rising); returns
    whether it was set (False without glibc: another C library keeps its own policy)."""
    lib = _libc()
    if lib is None:
        return False
    lib.mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    return bool(lib.mallopt(M_MMAP_THRESHOLD, int(threshold_bytes)))
