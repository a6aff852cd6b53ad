"""The Poisson table: every pixel's Poisson flag of a map, found once per refresh.

When much of the map is debris after the scatter (at least :data:`TABLE_FROM` of
it), :func:`service.galilean.finish.finish` reads the expansion's Poisson tests
(:mod:`.poisson`, equation 34) from :func:`poisson_interiors`' table instead of
testing origins one by one; :func:`interior_at` is the one-pixel test both use.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from service.galilean.fixed_point import Z_EMPTY
from service.galilean.propagate import u64
from service.numba_subroutine import subroutine

#: Debris pixels after the scatter, as a fraction of the map, from which the
#: expansion reads its Poisson tests from a :func:`poisson_interiors` table
#: (0.15-0.2 ms at 640x480 on two threads) instead of testing origins one by one.
TABLE_FROM = 1 / 128


@nb.njit(cache=True, inline="always")
def interior_at(
    dep: np.ndarray, deb: np.ndarray, zb: int, sq: int, h: int, w: int, threshold: float
) -> bool:
    """The Poisson test of old galpixel ``sq`` of the zone at ``zb`` (:func:`poisson_interiors`)."""
    sr, sc = sq // w, sq % w
    if sr == 0 or sc == 0 or sr == h - 1 or sc == w - 1:
        return False
    return _interior_inside(dep, deb, zb + sq, w, threshold)


@nb.njit(cache=True, inline="always")
def _interior_inside(dep: np.ndarray, deb: np.ndarray, p: int, w: int, threshold: float) -> bool:
    """The Poisson test of flat pixel ``p``, not on the border (no branch: SIMD-friendly)."""
    pc, pl, pr, pu, pd = u64(p), u64(p - 1), u64(p + 1), u64(p - w), u64(p + w)
    clean = (deb[pc] | deb[pl] | deb[pr] | deb[pu] | deb[pd]) == 0
    e0, e1, e2 = np.int64(dep[pc]), np.int64(dep[pr]), np.int64(dep[pl])
    e3, e4 = np.int64(dep[pd]), np.int64(dep[pu])
    full = ((e0 != Z_EMPTY) & (e1 != Z_EMPTY) & (e2 != Z_EMPTY)
            & (e3 != Z_EMPTY) & (e4 != Z_EMPTY))
    return clean & full & (abs(e1 + e2 + e3 + e4 - 4 * e0) <= threshold)


@nb.njit(cache=True, nogil=True, parallel=True)
def poisson_interiors(
    dep: np.ndarray, deb: np.ndarray, shape: tuple, threshold: float, out: np.ndarray
) -> None:
    """Which galpixels of a map pass the Poisson test (equation 34), rows in parallel.

    ``out[p]`` is 1 where :func:`service.galilean.poisson.poisson_flag` is 0 (a
    surface interior: not on the border, no debris among the pixel and its four
    neighbours, no empty depth, ``|laplacian| <= threshold``), with its arithmetic.

    Parameters
    ----------
    dep : ndarray, shape (N,), int32
        Fixed-point depth plane (``Z_EMPTY`` empty).
    deb : ndarray, shape (N,), uint8
        Debris plane.
    shape : tuple
        (Z, H, W), N = Z H W.
    threshold : float
        In fixed-point depth units.
    out : ndarray, shape (N,), uint8
    """
    nz, h, w = shape
    for k in nb.prange(nz * h):
        interior_row(dep, deb, np.int64(k * w), np.int64(k % h), h, w, threshold, out)


@subroutine()
def interior_row(
    dep: np.ndarray,
    deb: np.ndarray,
    base: int,
    r: int,
    h: int,
    w: int,
    threshold: float,
    out: np.ndarray,
) -> None:
    """One row of :func:`poisson_interiors`: row ``r`` of a zone, from flat pixel ``base``.

    Also run by :func:`service.galilean.scatter_bands.scatter_bands` on the old
    rows each band owns, while they are in cache.  A call, not inlined: it is
    compiled once for all three kernels, outside their parallel passes (inlined
    into both scatter kernels it cost about 5 s more cold compile), and as a
    :func:`~service.numba_subroutine.subroutine` optimised only inside them.
    Callers pass int64 indices (a ``prange`` index would compile it twice).
    """
    if r == 0 or r == h - 1:
        for c in range(w):
            out[u64(base + c)] = 0
        return
    out[u64(base)] = 0
    out[u64(base + w - 1)] = 0
    for c in range(1, w - 1):
        out[u64(base + c)] = _interior_inside(dep, deb, base + c, w, threshold)


