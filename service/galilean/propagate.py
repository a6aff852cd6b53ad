"""One refresh of propagation: the one-pass scatter of section 3.1.

The new map starts with every debris flag set and nothing else cleared.  One scan
of the old map runs, for each old pixel, the paper's parallel arms:

* the **debris arm** copies the old pixel's colour, depth and object to the same
  place in the new map if that place is still debris (no motion, flag kept);
* the **galpixel arm** (disabled when the old pixel is itself debris) advances the
  galpixel one refresh (:func:`service.galilean.fixed_point.advance`, z and colour
  likewise), and writes it where it lands if that pixel is debris or farther away
  (the z-test: nearest wins).  Galpixels that land outside the map are dropped.
* the **Poisson arm** stores the old pixel's Poisson flag (:mod:`.poisson`).

With the **obscuration cache** on, the loser of every clash goes to a cache map
(nearest loser kept), cached galpixels propagate like the others, and after the
scan a cached galpixel is promoted into the main map wherever the main map is
still debris.

Kernels take a map as the tuple of its arrays (:meth:`Galpixmap.arrays`):
``(colour, depth, frac, motion, zmotion, dcolour, debris, obj)``.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from service.galilean.fixed_point import advance, pixel_of
from service.galilean.poisson import poisson_flag

#: Index of each counter in the ``stats`` array the kernels fill.
STAT_NAMES = ("propagated", "clashes", "dropped", "cached", "promoted", "expanded", "debris")
STAT = {name: i for i, name in enumerate(STAT_NAMES)}


@nb.njit(cache=True, inline="always")
def _zstep(d: float, zm: np.ndarray, z: int, r: int, c: int, order: int) -> float:
    """Depth after one refresh: d + vz + az/2 + jz/6 (orders present only)."""
    if order >= 1:
        d += zm[0, z, r, c]
    if order >= 2:
        d += 0.5 * zm[1, z, r, c]
    if order >= 3:
        d += zm[2, z, r, c] / 6.0
    return d


@nb.njit(cache=True, inline="always")
def _copy(src: tuple, z: int, r: int, c: int, dst: tuple, qr: int, qc: int) -> None:
    """Copy one galpixel, every field, from ``src[z, r, c]`` to ``dst[z, qr, qc]``."""
    for k in range(3):
        dst[0][k, z, qr, qc] = src[0][k, z, r, c]
    dst[1][z, qr, qc] = src[1][z, r, c]
    for k in range(2):
        dst[2][k, z, qr, qc] = src[2][k, z, r, c]
    for k in range(src[3].shape[0]):
        dst[3][k, z, qr, qc] = src[3][k, z, r, c]
    for k in range(src[4].shape[0]):
        dst[4][k, z, qr, qc] = src[4][k, z, r, c]
    for k in range(src[5].shape[0]):
        dst[5][k, z, qr, qc] = src[5][k, z, r, c]
    dst[6][z, qr, qc] = src[6][z, r, c]
    dst[7][z, qr, qc] = src[7][z, r, c]


@nb.njit(cache=True, inline="always")
def _advance_into(
    src: tuple, z: int, r: int, c: int, dst: tuple, qr: int, qc: int,
    fx: int, fy: int, depth: float, mot: tuple, order: int,
) -> None:
    """Write the galpixel ``src[z, r, c]`` advanced one refresh into ``dst[z, qr, qc]``.

    ``mot`` is ``(vx, vy, ax, ay)`` after the step (from :func:`advance`).
    """
    dc = src[5]
    if dc.shape[0] == 4:
        da, db, dcc, d2a = dc[0, z, r, c], dc[1, z, r, c], dc[2, z, r, c], dc[3, z, r, c]
        sa = da + 0.5 * d2a
        dst[0][0, z, qr, qc] = src[0][0, z, r, c] + sa + db
        dst[0][1, z, qr, qc] = src[0][1, z, r, c] + sa - dcc
        dst[0][2, z, qr, qc] = src[0][2, z, r, c] + sa - db + dcc
        dst[5][0, z, qr, qc] = da + d2a
        dst[5][1, z, qr, qc] = db
        dst[5][2, z, qr, qc] = dcc
        dst[5][3, z, qr, qc] = d2a
    else:
        for k in range(3):
            dst[0][k, z, qr, qc] = src[0][k, z, r, c]
    dst[1][z, qr, qc] = depth
    dst[2][0, z, qr, qc] = fx
    dst[2][1, z, qr, qc] = fy
    m, zm = src[3], src[4]
    if order >= 1:
        dst[3][0, z, qr, qc] = mot[0]
        dst[3][1, z, qr, qc] = mot[1]
        dst[4][0, z, qr, qc] = zm[0, z, r, c]
    if order >= 2:
        dst[3][2, z, qr, qc] = mot[2]
        dst[3][3, z, qr, qc] = mot[3]
        dst[4][0, z, qr, qc] += zm[1, z, r, c]
        dst[4][1, z, qr, qc] = zm[1, z, r, c]
    if order >= 3:
        dst[3][4, z, qr, qc] = m[4, z, r, c]
        dst[3][5, z, qr, qc] = m[5, z, r, c]
        dst[4][0, z, qr, qc] += 0.5 * zm[2, z, r, c]
        dst[4][1, z, qr, qc] += zm[2, z, r, c]
        dst[4][2, z, qr, qc] = zm[2, z, r, c]
    dst[6][z, qr, qc] = 0
    dst[7][z, qr, qc] = src[7][z, r, c]


@nb.njit(cache=True, inline="always")
def _target(src: tuple, z: int, r: int, c: int, order: int, fp: int, fm: int) -> tuple:
    """Where galpixel ``src[z, r, c]`` lands: (qr, qc, fx, fy, depth, (vx, vy, ax, ay))."""
    m = src[3]
    vx = vy = ax = ay = jx = jy = 0
    if order >= 1:
        vx, vy = np.int64(m[0, z, r, c]), np.int64(m[1, z, r, c])
    if order >= 2:
        ax, ay = np.int64(m[2, z, r, c]), np.int64(m[3, z, r, c])
    if order >= 3:
        jx, jy = np.int64(m[4, z, r, c]), np.int64(m[5, z, r, c])
    x = (np.int64(c) << fp) + src[2][0, z, r, c]
    y = (np.int64(r) << fp) + src[2][1, z, r, c]
    x, vx, ax = advance(x, vx, ax, jx, order, fp, fm)
    y, vy, ay = advance(y, vy, ay, jy, order, fp, fm)
    qc, qr = pixel_of(x, fp), pixel_of(y, fp)
    depth = _zstep(src[1][z, r, c], src[4], z, r, c, order)
    return qr, qc, x - (qc << fp), y - (qr << fp), depth, (vx, vy, ax, ay)


@nb.njit(cache=True)
def _place(
    src: tuple, z: int, r: int, c: int, dst: tuple, spill: tuple, cache_on: bool,
    order: int, fp: int, fm: int, stats: np.ndarray, src_idx: np.ndarray, width: int,
) -> None:
    """The galpixel arm for one galpixel: advance, z-test, write, spill the loser."""
    h, w = dst[1].shape[1], dst[1].shape[2]
    qr, qc, fx, fy, d, mot = _target(src, z, r, c, order, fp, fm)
    if qr < 0 or qc < 0 or qr >= h or qc >= w:
        stats[2] += 1
        return
    if dst[6][z, qr, qc] == 1 or d < dst[1][z, qr, qc]:
        if dst[6][z, qr, qc] == 0:
            stats[1] += 1
            if cache_on and (spill[6][z, qr, qc] == 1 or dst[1][z, qr, qc] < spill[1][z, qr, qc]):
                _copy(dst, z, qr, qc, spill, qr, qc)
                stats[3] += 1
        _advance_into(src, z, r, c, dst, qr, qc, fx, fy, d, mot, order)
        if width > 0:
            src_idx[z, qr, qc] = r * width + c
    else:
        stats[1] += 1
        if cache_on and (spill[6][z, qr, qc] == 1 or d < spill[1][z, qr, qc]):
            _advance_into(src, z, r, c, spill, qr, qc, fx, fy, d, mot, order)
            stats[3] += 1


@nb.njit(cache=True)
def sweep(
    old: tuple, new: tuple, cold: tuple, cnew: tuple, cache_on: bool, flags: np.ndarray,
    src_idx: np.ndarray, order: int, fp: int, fm: int, threshold: float, stats: np.ndarray,
) -> None:
    """First sweep: debris arm, galpixel arm, Poisson arm, then cache propagation and promotion.

    Parameters
    ----------
    old, new : tuple of arrays
        Old and new main maps (shapes (Z, H, W) per plane); ``new``'s debris
        plane must be all 1 on entry.
    cold, cnew : tuple of arrays
        Old and new obscuration-cache maps (``cnew`` debris all 1); ignored unless
        ``cache_on``.
    flags : ndarray, shape (Z, H, W), uint8
        Out: Poisson flag map of the old frame (1: source, edge or debris).
    src_idx : ndarray, shape (Z, H, W), int32
        Out: for each new pixel, ``r * W + c`` of the old galpixel that landed
        there, -1 for debris and promoted galpixels.
    order, fp, fm : int
    threshold : float
        Poisson threshold on ``|laplacian(depth)|``.
    stats : ndarray, shape (7,), int64
        Counters, accumulated (see :data:`STAT_NAMES`).
    """
    nz, h, w = old[1].shape
    for z in range(nz):
        for r in range(h):
            for c in range(w):
                if new[6][z, r, c] == 1:
                    for k in range(3):
                        new[0][k, z, r, c] = old[0][k, z, r, c]
                    new[1][z, r, c] = old[1][z, r, c]
                    new[7][z, r, c] = old[7][z, r, c]
                    src_idx[z, r, c] = -1
                flags[z, r, c] = poisson_flag(old[1], old[6], z, r, c, threshold)
                if old[6][z, r, c] == 0:
                    stats[0] += 1
                    _place(old, z, r, c, new, cnew, cache_on, order, fp, fm, stats, src_idx, w)
        if cache_on:
            _cache_pass(cold, new, cnew, z, order, fp, fm, stats, src_idx)


@nb.njit(cache=True)
def _cache_pass(
    cold: tuple, new: tuple, cnew: tuple, z: int, order: int, fp: int, fm: int,
    stats: np.ndarray, src_idx: np.ndarray,
) -> None:
    """Propagate the old cache into the new one, then promote into the main map's debris."""
    h, w = cold[1].shape[1], cold[1].shape[2]
    scratch = np.zeros(7, np.int64)
    for r in range(h):
        for c in range(w):
            if cold[6][z, r, c] == 0:
                _place(cold, z, r, c, cnew, cnew, False, order, fp, fm, scratch, src_idx, 0)
    for r in range(h):
        for c in range(w):
            if new[6][z, r, c] == 1 and cnew[6][z, r, c] == 0:
                _copy(cnew, z, r, c, new, r, c)
                cnew[6][z, r, c] = 1
                src_idx[z, r, c] = -1
                stats[4] += 1
