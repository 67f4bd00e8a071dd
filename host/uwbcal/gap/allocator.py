"""The C allocator's setting for the diagnosis: keep freed array memory for reuse.

The diagnosis makes many short-lived arrays of a few hundred kB to a few MB (a fit's NLL table
of 122 grid values x 540 features, a localisation pool of 50 000 values, a feature pass over
100 000 records). glibc serves each such block by mmap and returns it by munmap, so every new
array faults its pages in afresh: on the asil run that was a quarter of the wall time, most of
it system time (an NLL table: 1.6 ms fresh, 0.27 ms from reused memory). Raising glibc's mmap
and trim thresholds keeps the blocks in the heap for reuse. Arithmetic is unchanged; the process
keeps up to ``TRIM_BYTES`` of freed memory. Elsewhere than glibc this does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
from typing import Final

#: Blocks up to this size come from the heap, not from mmap (glibc M_MMAP_THRESHOLD), bytes.
MMAP_BYTES: Final = 64 << 20
#: Free heap memory kept before it is returned to the system (glibc M_TRIM_THRESHOLD), bytes.
TRIM_BYTES: Final = 256 << 20
_M_TRIM_THRESHOLD: Final = -1  # glibc malloc.h
_M_MMAP_THRESHOLD: Final = -3

_done: list[bool] = []


def reuse_freed_memory() -> bool:
    """Set the thresholds once per process (forked workers inherit them); True if they were set."""
    if _done:
        return _done[0]
    ok = False
    try:
        name = ctypes.util.find_library("c")
        libc = ctypes.CDLL(name) if name else None
        mallopt = getattr(libc, "mallopt", None)
        if mallopt is not None:
            ok = bool(mallopt(_M_MMAP_THRESHOLD, MMAP_BYTES)) and bool(mallopt(_M_TRIM_THRESHOLD, TRIM_BYTES))
    except OSError:
        ok = False
    _done.append(ok)
    return ok
