"""Process set-up for programs that render or refresh frames.

Two process-wide settings make frame loops on the project's 2-core machines run
at their measured speed; every command-line program that renders, refreshes or
serves frames calls :func:`setup_frame_process` once at start:

* :func:`service.base.heap.keep_freed_memory` - freed frame buffers stay in the heap, so
  the next frame's arrays do not fault their pages in again;
* :func:`service.blas.single_threaded_blas` - numpy's OpenBLAS runs on the calling
  thread, so its pool does not spin on the cores numba's kernels need next.
"""

from __future__ import annotations

from service.base.heap import keep_freed_memory
from service.blas import single_threaded_blas


def setup_frame_process() -> dict[str, bool]:
    """Apply the frame-loop process settings; say which took.

    Returns
    -------
    dict
        ``{"keep_freed_memory": bool, "single_threaded_blas": bool}``: False where
        the setting does not apply here (no glibc, no loaded OpenBLAS).
    """
    return {
        "keep_freed_memory": keep_freed_memory(),
        "single_threaded_blas": single_threaded_blas(),
    }
