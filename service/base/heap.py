"""Process heap: keep freed memory for the next frame instead of giving it back.

Renders, updates and refreshes allocate frame-sized arrays (a 640x480 update with
motion is tens of MB in a dozen arrays) and free them a moment later.  glibc
returns a freed block above its mmap threshold (128 KiB at start, raised as such
blocks are freed, at most 32 MiB) straight to the kernel, and trims the top of
the heap above its trim threshold, so the next frame's arrays fault their pages in
again, zero-filled by the kernel.  Measured on the 2-core development VM: a fresh
11 MB array cost 5-7 ms of page faults against 0.2 ms to fill a reused one, and
``render_with_motion`` at 640x480 spent about 8,000 faults, half its time, on them
(1.7x faster without them; a stage update with its graft 2.4x).

:func:`keep_freed_memory` raises both thresholds, so freed blocks stay in the
heap for reuse.  The cost is that the process's resident size stays at its
high-water mark (up to ``trim_threshold`` of it free) instead of shrinking
between frames.  The CLIs that render or refresh call it at start; it is a no-op
where the C library is not glibc.
"""

from __future__ import annotations

import ctypes
import ctypes.util

#: mallopt parameters (glibc's malloc.h).
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
#: glibc's ceiling for M_MMAP_THRESHOLD on 64-bit platforms: mallopt refuses more.
MMAP_THRESHOLD_MAX = 32 << 20


def keep_freed_memory(
    mmap_threshold: int = MMAP_THRESHOLD_MAX, trim_threshold: int = 1 << 30
) -> bool:
    """Keep freed blocks in the heap for reuse (glibc ``mallopt``).

    Blocks below ``mmap_threshold`` bytes come from, and go back to, the heap; up
    to ``trim_threshold`` free bytes at its top stay mapped.

    Parameters
    ----------
    mmap_threshold : int
        Blocks at least this large are mapped and unmapped on their own (at most
        :data:`MMAP_THRESHOLD_MAX`).
    trim_threshold : int
        Free bytes at the top of the heap kept rather than returned to the kernel.

    Returns
    -------
    bool
        True when both settings took (glibc); False where there is no glibc
        ``mallopt`` or it refused (nothing changes then).
    """
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError, TypeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    mmap = min(int(mmap_threshold), MMAP_THRESHOLD_MAX)
    trim = min(int(trim_threshold), 2**31 - 1)
    return bool(mallopt(M_MMAP_THRESHOLD, mmap)) and bool(mallopt(M_TRIM_THRESHOLD, trim))
