"""BLAS threads: numpy's OpenBLAS kept to the calling thread.

numpy's bundled OpenBLAS runs a large matrix product on a thread pool of its own,
one thread per core, whose threads then spin for up to 2^28 cycles (about 0.1 s)
waiting for more work before they sleep.  On the 2-core machine the project runs
on, those spinning threads take the cores numba's kernels need next: measured
beside a 1M-triangle ``Renderer.render`` (whose culling multiplies the polygon
normals by the view vectors), 25 ms of CPU spent spinning in the 50 ms after it,
the G(2) refresh that followed took 19 ms CPU against 11 ms after a pause, and
the render itself took 160 ms CPU (87 ms wall) against 98 ms (80 ms wall) with
one BLAS thread.  The project's matrix products are thin (N x 3 by 3 x Z), memory
bound, and gain nothing from the pool.

:func:`single_threaded_blas` sets OpenBLAS's thread count to one at run time
(``OPENBLAS_NUM_THREADS`` only counts before numpy loads it, and the CLIs import
numpy before their ``main`` runs).  The CLIs that render or refresh call it at
start, beside :func:`service.base.heap.keep_freed_memory`.
"""

from __future__ import annotations

import ctypes
from pathlib import Path

import numpy  # noqa: F401  (loads the BLAS library whose threads are set here)

#: Names OpenBLAS builds export its thread-count setter under (numpy's bundled
#: scipy-openblas adds a prefix and a suffix; a system OpenBLAS has the plain name).
SETTERS = (
    "scipy_openblas_set_num_threads64_",
    "scipy_openblas_set_num_threads",
    "openblas_set_num_threads64_",
    "openblas_set_num_threads",
)


def _loaded_openblas() -> list[str]:
    """Paths of the OpenBLAS libraries mapped into this process (Linux; else none)."""
    try:
        maps = Path("/proc/self/maps").read_text()
    except OSError:
        return []
    found = {line.split()[-1] for line in maps.splitlines() if "openblas" in line.lower()}
    return sorted(p for p in found if p.startswith("/"))


def single_threaded_blas() -> bool:
    """Run numpy's BLAS on the calling thread only; True if an OpenBLAS took the setting.

    A no-op (False) where numpy's BLAS is not a loaded OpenBLAS with a known setter.
    """
    done = False
    for path in _loaded_openblas():
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for name in SETTERS:
            setter = getattr(lib, name, None)
            if setter is not None:
                setter.argtypes = [ctypes.c_int]
                setter.restype = None
                setter(1)
                done = True
                break
    return done
