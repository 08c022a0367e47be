"""The process's heap: large blocks handed back to the system when freed.

glibc's malloc serves a block from its heap below a threshold and maps it from the
system above; after a mapped block is freed the threshold rises to that block's size
(up to 32 MiB), so the blocks of a run (a chunk's per-step fields, XLA's buffers of a
few MiB each, KLU's work arrays) come from the heap from then on, where freed memory
stays resident between chunks.  :func:`map_large_blocks` fixes the threshold, so such
blocks are mapped and unmapped.  It changes the whole process: the command line calls
it (it owns the process); importing jaxform does not.
"""

from __future__ import annotations

import ctypes
import ctypes.util

M_MMAP_THRESHOLD = -3  # malloc.h
LARGE_BLOCK_BYTES = 1 << 20


def map_large_blocks(threshold_bytes: int = LARGE_BLOCK_BYTES) -> bool:
    """Serve every allocation of ``threshold_bytes`` or more by its own mapping (glibc's
    ``mallopt(M_MMAP_THRESHOLD)``, which also stops the threshold from rising); returns
    whether it was set (False without glibc: another C library keeps its own policy)."""
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        mallopt = ctypes.CDLL(name).mallopt
    except (OSError, AttributeError):  # not glibc
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    return bool(mallopt(M_MMAP_THRESHOLD, int(threshold_bytes)))
