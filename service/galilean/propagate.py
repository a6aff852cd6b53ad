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
from service.galilean.poisson import expand_pixel

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


@nb.njit(cache=True, inline="always")
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
    old: tuple, new: tuple, cold: tuple, cnew: tuple, cache_on: bool, src_idx: np.ndarray,
    order: int, fp: int, fm: int, track: bool, stats: np.ndarray,
) -> None:
    """First sweep: debris arm and galpixel arm, then cache propagation and promotion.

    The per-pixel work is written out in this one loop (no helper calls on the hot
    path): numba compiles it about ten times faster that way.  The Poisson arm is
    evaluated lazily by the second sweep (:func:`second_sweep`),
    only for the few old pixels it asks about; the result is the same.

    Parameters
    ----------
    old, new : tuple of arrays
        Old and new main maps (shapes (Z, H, W) per plane); ``new``'s debris
        plane must be all 1 on entry.
    cold, cnew : tuple of arrays
        Old and new obscuration-cache maps (``cnew`` debris all 1); ignored unless
        ``cache_on``.
    src_idx : ndarray, shape (Z, H, W), int32
        Out (when ``track``): for each new pixel, ``r * W + c`` of the old galpixel
        that landed there, -1 for debris and promoted galpixels.
    order, fp, fm : int
    track : bool
        Record ``src_idx`` (needed by the expansion sweep).
    stats : ndarray, shape (7,), int64
        Counters, accumulated (see :data:`STAT_NAMES`).
    """
    o_col, o_dep, o_frac, o_mot, o_zm, o_dc, o_deb, o_obj = old
    n_col, n_dep, n_frac, n_mot, n_zm, n_dc, n_deb, n_obj = new
    nz, h, w = o_dep.shape
    sh = fm - fp
    ncol = o_dc.shape[0]
    n_prop = n_clash = n_drop = 0
    for z in range(nz):
        for r in range(h):
            for c in range(w):
                if o_deb[z, r, c] == 1:
                    if n_deb[z, r, c] == 1:
                        _debris_copy(old, new, z, r, c, src_idx, track)
                    continue
                n_prop += 1
                x = (np.int64(c) << fp) + o_frac[0, z, r, c]
                y = (np.int64(r) << fp) + o_frac[1, z, r, c]
                d = o_dep[z, r, c]
                vx = vy = ax = ay = np.int64(0)
                if order == 1:
                    vx, vy = np.int64(o_mot[0, z, r, c]), np.int64(o_mot[1, z, r, c])
                    x += (vx + (1 << (sh - 1))) >> sh
                    y += (vy + (1 << (sh - 1))) >> sh
                    d += o_zm[0, z, r, c]
                elif order == 2:
                    vx, vy = np.int64(o_mot[0, z, r, c]), np.int64(o_mot[1, z, r, c])
                    ax, ay = np.int64(o_mot[2, z, r, c]), np.int64(o_mot[3, z, r, c])
                    x += (2 * vx + ax + (1 << sh)) >> (sh + 1)
                    y += (2 * vy + ay + (1 << sh)) >> (sh + 1)
                    vx += ax
                    vy += ay
                    d += o_zm[0, z, r, c] + 0.5 * o_zm[1, z, r, c]
                elif order == 3:
                    x, vx, ax = advance(x, np.int64(o_mot[0, z, r, c]), np.int64(o_mot[2, z, r, c]),
                                        np.int64(o_mot[4, z, r, c]), 3, fp, fm)
                    y, vy, ay = advance(y, np.int64(o_mot[1, z, r, c]), np.int64(o_mot[3, z, r, c]),
                                        np.int64(o_mot[5, z, r, c]), 3, fp, fm)
                    d += o_zm[0, z, r, c] + 0.5 * o_zm[1, z, r, c] + o_zm[2, z, r, c] / 6.0
                qc = (x + (1 << (fp - 1))) >> fp
                qr = (y + (1 << (fp - 1))) >> fp
                if n_deb[z, r, c] == 1 and (qr != r or qc != c):
                    _debris_copy(old, new, z, r, c, src_idx, track)  # own place: overwritten
                if qr < 0 or qc < 0 or qr >= h or qc >= w:
                    n_drop += 1
                    continue
                if n_deb[z, qr, qc] == 0:
                    n_clash += 1
                    if d >= n_dep[z, qr, qc]:
                        if cache_on:
                            _spill_incoming(old, z, r, c, cnew, qr, qc, x - (qc << fp),
                                            y - (qr << fp), d, (vx, vy, ax, ay), order, stats)
                        continue
                    if cache_on:
                        _spill_resident(new, cnew, z, qr, qc, stats)
                n_col[0, z, qr, qc] = o_col[0, z, r, c]
                n_col[1, z, qr, qc] = o_col[1, z, r, c]
                n_col[2, z, qr, qc] = o_col[2, z, r, c]
                if ncol == 4:
                    da, d2a = o_dc[0, z, r, c], o_dc[3, z, r, c]
                    db, dc = o_dc[1, z, r, c], o_dc[2, z, r, c]
                    sa = da + 0.5 * d2a
                    n_col[0, z, qr, qc] += sa + db
                    n_col[1, z, qr, qc] += sa - dc
                    n_col[2, z, qr, qc] += sa - db + dc
                    n_dc[0, z, qr, qc] = da + d2a
                    n_dc[1, z, qr, qc] = db
                    n_dc[2, z, qr, qc] = dc
                    n_dc[3, z, qr, qc] = d2a
                n_dep[z, qr, qc] = d
                n_frac[0, z, qr, qc] = x - (qc << fp)
                n_frac[1, z, qr, qc] = y - (qr << fp)
                if order >= 1:
                    n_mot[0, z, qr, qc] = vx
                    n_mot[1, z, qr, qc] = vy
                    n_zm[0, z, qr, qc] = o_zm[0, z, r, c]
                if order >= 2:
                    n_mot[2, z, qr, qc] = ax
                    n_mot[3, z, qr, qc] = ay
                    n_zm[0, z, qr, qc] += o_zm[1, z, r, c]
                    n_zm[1, z, qr, qc] = o_zm[1, z, r, c]
                if order >= 3:
                    n_mot[4, z, qr, qc] = o_mot[4, z, r, c]
                    n_mot[5, z, qr, qc] = o_mot[5, z, r, c]
                    n_zm[0, z, qr, qc] += 0.5 * o_zm[2, z, r, c]
                    n_zm[1, z, qr, qc] += o_zm[2, z, r, c]
                    n_zm[2, z, qr, qc] = o_zm[2, z, r, c]
                n_deb[z, qr, qc] = 0
                n_obj[z, qr, qc] = o_obj[z, r, c]
                if track:
                    src_idx[z, qr, qc] = r * w + c
        if cache_on:
            _cache_pass(cold, new, cnew, z, order, fp, fm, stats, src_idx)
    stats[0] += n_prop
    stats[1] += n_clash
    stats[2] += n_drop


@nb.njit(cache=True, inline="always")
def _debris_copy(old: tuple, new: tuple, z: int, r: int, c: int, src_idx: np.ndarray,
                 track: bool) -> None:
    """The debris arm: the old pixel's colour, depth and object, in place, as debris."""
    for k in range(3):
        new[0][k, z, r, c] = old[0][k, z, r, c]
    new[1][z, r, c] = old[1][z, r, c]
    new[7][z, r, c] = old[7][z, r, c]
    if track:
        src_idx[z, r, c] = -1


@nb.njit(cache=True)
def _spill_incoming(
    old: tuple, z: int, r: int, c: int, cnew: tuple, qr: int, qc: int, fx: int, fy: int,
    d: float, mot: tuple, order: int, stats: np.ndarray,
) -> None:
    """A clash loser on its way in goes to the cache if nearer than the cache's entry."""
    if cnew[6][z, qr, qc] == 1 or d < cnew[1][z, qr, qc]:
        _advance_into(old, z, r, c, cnew, qr, qc, fx, fy, d, mot, order)
        stats[3] += 1


@nb.njit(cache=True)
def _spill_resident(new: tuple, cnew: tuple, z: int, qr: int, qc: int, stats: np.ndarray) -> None:
    """The galpixel about to be overwritten goes to the cache if nearer than the cache's entry."""
    if cnew[6][z, qr, qc] == 1 or new[1][z, qr, qc] < cnew[1][z, qr, qc]:
        _copy(new, z, qr, qc, cnew, qr, qc)
        stats[3] += 1


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


@nb.njit(cache=True)
def second_sweep(
    new: tuple, src_idx: np.ndarray, old_depth: np.ndarray, old_debris: np.ndarray,
    threshold: float, n_neighbours: int, mode: int, margin: int,
    out_colour: np.ndarray, out_depth: np.ndarray, out_debris: np.ndarray, stats: np.ndarray,
) -> None:
    """Second sweep: expansion of debris (when ``threshold`` >= 0) fused with the display copy.

    Parameters
    ----------
    new : tuple of arrays
        The new main map, changed in place by expansions.
    src_idx : ndarray, shape (Z, H, W), int32
        Origins recorded by :func:`sweep`.
    old_depth, old_debris : ndarray, shape (Z, H, W)
        The old map, for the Poisson test of origins.
    threshold : float
        Poisson threshold; < 0 switches expansion off.
    n_neighbours, mode : int
        See :func:`service.galilean.poisson.expand_pixel`.
    margin : int
    out_colour : ndarray, shape (Z, H - 2 margin, W - 2 margin, 3), uint8
        Out: displayed colour, rounded and clipped.
    out_depth : ndarray, shape (Z, H - 2 margin, W - 2 margin), float32
    out_debris : ndarray, shape (Z, H - 2 margin, W - 2 margin), bool
    stats : ndarray, shape (7,), int64
        ``stats[5]`` expanded, ``stats[6]`` debris left (whole map).
    """
    col, dep, deb = new[0], new[1], new[6]
    nz, h, w = dep.shape
    expanded = left = 0
    for z in range(nz):
        for r in range(h):
            for c in range(w):
                if deb[z, r, c] == 1:
                    if threshold >= 0 and expand_pixel(new, src_idx, old_depth, old_debris,
                                                       threshold, z, r, c, n_neighbours, mode):
                        expanded += 1
                    else:
                        left += 1
                rr, cc = r - margin, c - margin
                if rr < 0 or cc < 0 or rr >= h - 2 * margin or cc >= w - 2 * margin:
                    continue
                for k in range(3):
                    v = col[k, z, r, c] + 0.5
                    out_colour[z, rr, cc, k] = 0 if v < 0.0 else (255 if v >= 255.0 else np.uint8(v))
                out_depth[z, rr, cc] = dep[z, r, c]
                out_debris[z, rr, cc] = deb[z, r, c] == 1
    stats[5] += expanded
    stats[6] += left
