"""One refresh of propagation: the one-pass scatter of section 3.1.

The new map starts with every debris flag set and nothing else cleared.  One scan
of the old map runs, for each old pixel, the paper's parallel arms:

* the **debris arm** copies the old pixel's colour, depth and object to the same
  place in the new map if that place is still debris (no motion, flag kept);
* the **galpixel arm** (disabled when the old pixel is itself debris) advances the
  galpixel one refresh (:func:`service.galilean.fixed_point.advance`, z and colour
  likewise), and writes it where it lands if that pixel is debris or farther away
  (the z-test: nearest wins).  Galpixels that land outside the map are dropped.
* the **Poisson arm** (the old pixel's Poisson flag) is evaluated lazily by the
  second sweep, only for the origins it asks about (:mod:`.poisson`).

With the **obscuration cache** on, the loser of every clash goes to a cache map
(nearest loser kept), cached galpixels propagate like the others, and after the
scan a cached galpixel is promoted into the main map wherever the main map is
still debris.

Kernels take a map as the tuple of its arrays (:meth:`Galpixmap.arrays`):
``(colour, depth, frac, motion, zmotion, dcolour, debris, obj)``; the first sweep
takes them *flattened* (:func:`flat`: planes (k, N), scalars (N,), N = Z H W) and
addresses every galpixel by one flat index, which numba compiles to much cheaper
address arithmetic than four-dimensional indexing.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from service.galilean.fixed_point import advance
from service.galilean.poisson import expand_pixel

#: Index of each counter in the ``stats`` array the kernels fill.
STAT_NAMES = ("propagated", "clashes", "dropped", "cached", "promoted", "expanded", "debris")
STAT = {name: i for i, name in enumerate(STAT_NAMES)}


def flat(arrays: tuple) -> tuple:
    """A map's array tuple with every plane flattened: (k, Z, H, W) -> (k, N), (Z, H, W) -> (N,)."""
    n = arrays[1].size
    return tuple(a.reshape(a.shape[0], n) if a.ndim == 4 else a.reshape(n) for a in arrays)


@nb.njit(cache=True, inline="always")
def _copy(src: tuple, p: int, dst: tuple, q: int) -> None:
    """Copy one galpixel, every field, from flat index ``p`` of ``src`` to ``q`` of ``dst``."""
    for k in range(3):
        dst[0][k, q] = src[0][k, p]
    dst[1][q] = src[1][p]
    dst[2][0, q] = src[2][0, p]
    dst[2][1, q] = src[2][1, p]
    for k in range(src[3].shape[0]):
        dst[3][k, q] = src[3][k, p]
    for k in range(src[4].shape[0]):
        dst[4][k, q] = src[4][k, p]
    for k in range(src[5].shape[0]):
        dst[5][k, q] = src[5][k, p]
    dst[6][q] = src[6][p]
    dst[7][q] = src[7][p]


@nb.njit(cache=True, inline="always")
def _advance_into(
    src: tuple, p: int, dst: tuple, q: int, fx: int, fy: int, depth: float, mot: tuple,
    order: int,
) -> None:
    """Write galpixel ``p`` of ``src``, advanced one refresh, at ``q`` of ``dst``.

    ``mot`` is ``(vx, vy, ax, ay)`` after the step (from :func:`advance`), ``depth``
    the new depth, ``fx``, ``fy`` the new fraction.
    """
    s_col, s_mot, s_zm, s_dc = src[0], src[3], src[4], src[5]
    d_col, d_mot, d_zm, d_dc = dst[0], dst[3], dst[4], dst[5]
    d_col[0, q] = s_col[0, p]
    d_col[1, q] = s_col[1, p]
    d_col[2, q] = s_col[2, p]
    if s_dc.shape[0] == 4:
        da, db, dc, d2a = s_dc[0, p], s_dc[1, p], s_dc[2, p], s_dc[3, p]
        sa = da + 0.5 * d2a
        d_col[0, q] += sa + db
        d_col[1, q] += sa - dc
        d_col[2, q] += sa - db + dc
        d_dc[0, q] = da + d2a
        d_dc[1, q] = db
        d_dc[2, q] = dc
        d_dc[3, q] = d2a
    dst[1][q] = depth
    dst[2][0, q] = fx
    dst[2][1, q] = fy
    if order >= 1:
        d_mot[0, q] = mot[0]
        d_mot[1, q] = mot[1]
        d_zm[0, q] = s_zm[0, p]
    if order >= 2:
        d_mot[2, q] = mot[2]
        d_mot[3, q] = mot[3]
        d_zm[0, q] += s_zm[1, p]
        d_zm[1, q] = s_zm[1, p]
    if order >= 3:
        d_mot[4, q] = s_mot[4, p]
        d_mot[5, q] = s_mot[5, p]
        d_zm[0, q] += 0.5 * s_zm[2, p]
        d_zm[1, q] += s_zm[2, p]
        d_zm[2, q] = s_zm[2, p]
    dst[6][q] = 0
    dst[7][q] = src[7][p]


@nb.njit(cache=True, inline="always")
def _target(src: tuple, p: int, r: int, c: int, order: int, fp: int, fm: int) -> tuple:
    """Where galpixel ``p`` (at row r, column c) lands: (qr, qc, fx, fy, depth, motion).

    ``motion`` is ``(vx, vy, ax, ay)`` after the step.
    """
    m, zm = src[3], src[4]
    x = (np.int64(c) << fp) + src[2][0, p]
    y = (np.int64(r) << fp) + src[2][1, p]
    d = src[1][p]
    sh = fm - fp
    vx = vy = ax = ay = np.int64(0)
    if order == 1:
        vx, vy = np.int64(m[0, p]), np.int64(m[1, p])
        x += (vx + (1 << (sh - 1))) >> sh
        y += (vy + (1 << (sh - 1))) >> sh
        d += zm[0, p]
    elif order == 2:
        vx, vy = np.int64(m[0, p]), np.int64(m[1, p])
        ax, ay = np.int64(m[2, p]), np.int64(m[3, p])
        x += (2 * vx + ax + (1 << sh)) >> (sh + 1)
        y += (2 * vy + ay + (1 << sh)) >> (sh + 1)
        vx += ax
        vy += ay
        d += zm[0, p] + 0.5 * zm[1, p]
    elif order == 3:
        x, vx, ax = advance(x, np.int64(m[0, p]), np.int64(m[2, p]), np.int64(m[4, p]), 3,
                            fp, fm)
        y, vy, ay = advance(y, np.int64(m[1, p]), np.int64(m[3, p]), np.int64(m[5, p]), 3,
                            fp, fm)
        d += zm[0, p] + 0.5 * zm[1, p] + zm[2, p] / 6.0
    qc = (x + (1 << (fp - 1))) >> fp
    qr = (y + (1 << (fp - 1))) >> fp
    return qr, qc, x - (qc << fp), y - (qr << fp), d, (vx, vy, ax, ay)


@nb.njit(cache=True, error_model="numpy")
def sweep(
    old: tuple, new: tuple, cold: tuple, cnew: tuple, cache_on: bool, src_idx: np.ndarray,
    shape: tuple, order: int, fp: int, fm: int, track: bool, stats: np.ndarray,
) -> None:
    """First sweep: debris arm and galpixel arm, then cache propagation and promotion.

    Parameters
    ----------
    old, new : tuple of arrays
        Old and new main maps, flattened (:func:`flat`); ``new``'s debris must be
        all 1 on entry.
    cold, cnew : tuple of arrays
        Old and new obscuration-cache maps, flattened (``cnew`` debris all 1);
        ignored unless ``cache_on``.
    cache_on : bool
    src_idx : ndarray, shape (N,), int32
        Out (when ``track``): for each new pixel, ``r * W + c`` of the old
        galpixel that landed there, -1 for debris and promoted galpixels.
    shape : tuple
        (Z, H, W).
    order, fp, fm : int
    track : bool
        Record ``src_idx`` (needed by the expansion sweep).
    stats : ndarray, shape (7,), int64
        Counters, accumulated (see :data:`STAT_NAMES`).
    """
    nz, h, w = shape
    o_col, o_dep, o_frac, o_mot, o_zm, o_dc, o_deb, o_obj = old
    n_col, n_dep, n_frac, n_mot, n_zm, n_dc, n_deb, n_obj = new
    ncol = o_dc.shape[0]
    sh = fm - fp
    half = np.int64(1) << (fp - 1)
    n_prop = n_clash = n_drop = 0
    # The hot loop is written out by hand: passing arrays to helpers costs numba
    # reference-count traffic on every call, several times the work itself.
    for z in range(nz):
        for r in range(h):
            base = (z * h + r) * w
            for c in range(w):
                p = base + c
                galpixel = o_deb[p] == 0
                qr, qc = r, c
                if galpixel:
                    x = (np.int64(c) << fp) + o_frac[0, p]
                    y = (np.int64(r) << fp) + o_frac[1, p]
                    d = o_dep[p]
                    vx = vy = ax = ay = np.int64(0)
                    if order == 1:
                        vx, vy = np.int64(o_mot[0, p]), np.int64(o_mot[1, p])
                        x += (vx + (1 << (sh - 1))) >> sh
                        y += (vy + (1 << (sh - 1))) >> sh
                        d += o_zm[0, p]
                    elif order == 2:
                        vx, vy = np.int64(o_mot[0, p]), np.int64(o_mot[1, p])
                        ax, ay = np.int64(o_mot[2, p]), np.int64(o_mot[3, p])
                        x += (2 * vx + ax + (1 << sh)) >> (sh + 1)
                        y += (2 * vy + ay + (1 << sh)) >> (sh + 1)
                        vx += ax
                        vy += ay
                        d += o_zm[0, p] + 0.5 * o_zm[1, p]
                    elif order == 3:
                        x, vx, ax = advance(x, np.int64(o_mot[0, p]), np.int64(o_mot[2, p]),
                                            np.int64(o_mot[4, p]), 3, fp, fm)
                        y, vy, ay = advance(y, np.int64(o_mot[1, p]), np.int64(o_mot[3, p]),
                                            np.int64(o_mot[5, p]), 3, fp, fm)
                        d += o_zm[0, p] + 0.5 * o_zm[1, p] + o_zm[2, p] / 6.0
                    qc = (x + half) >> fp
                    qr = (y + half) >> fp
                if n_deb[p] == 1 and (qr != r or qc != c):  # debris arm (own place free)
                    n_col[0, p] = o_col[0, p]
                    n_col[1, p] = o_col[1, p]
                    n_col[2, p] = o_col[2, p]
                    n_dep[p] = o_dep[p]
                    n_obj[p] = o_obj[p]
                    if track:
                        src_idx[p] = -1
                if not galpixel:
                    continue
                n_prop += 1
                if qr < 0 or qc < 0 or qr >= h or qc >= w:
                    n_drop += 1
                    continue
                q = (z * h + qr) * w + qc
                fx, fy = x - (qc << fp), y - (qr << fp)
                if n_deb[q] == 0:
                    n_clash += 1
                    if d >= n_dep[q]:
                        if cache_on:
                            _spill_incoming(old, p, cnew, q, fx, fy, d, (vx, vy, ax, ay),
                                            order, stats)
                        continue
                    if cache_on:
                        _spill_resident(new, cnew, q, stats)
                n_col[0, q] = o_col[0, p]
                n_col[1, q] = o_col[1, p]
                n_col[2, q] = o_col[2, p]
                if ncol == 4:
                    da, db, dc, d2a = o_dc[0, p], o_dc[1, p], o_dc[2, p], o_dc[3, p]
                    sa = da + 0.5 * d2a
                    n_col[0, q] += sa + db
                    n_col[1, q] += sa - dc
                    n_col[2, q] += sa - db + dc
                    n_dc[0, q] = da + d2a
                    n_dc[1, q] = db
                    n_dc[2, q] = dc
                    n_dc[3, q] = d2a
                n_dep[q] = d
                n_frac[0, q] = fx
                n_frac[1, q] = fy
                if order >= 1:
                    n_mot[0, q] = vx
                    n_mot[1, q] = vy
                    n_zm[0, q] = o_zm[0, p]
                if order >= 2:
                    n_mot[2, q] = ax
                    n_mot[3, q] = ay
                    n_zm[0, q] += o_zm[1, p]
                    n_zm[1, q] = o_zm[1, p]
                if order >= 3:
                    n_mot[4, q] = o_mot[4, p]
                    n_mot[5, q] = o_mot[5, p]
                    n_zm[0, q] += 0.5 * o_zm[2, p]
                    n_zm[1, q] += o_zm[2, p]
                    n_zm[2, q] = o_zm[2, p]
                n_deb[q] = 0
                n_obj[q] = o_obj[p]
                if track:
                    src_idx[q] = r * w + c
        if cache_on:
            _cache_pass(cold, new, cnew, z, h, w, order, fp, fm, stats, src_idx)
    stats[0] += n_prop
    stats[1] += n_clash
    stats[2] += n_drop


@nb.njit(cache=True)
def _spill_incoming(
    old: tuple, p: int, cnew: tuple, q: int, fx: int, fy: int, d: float, mot: tuple,
    order: int, stats: np.ndarray,
) -> None:
    """A clash loser on its way in goes to the cache if nearer than the cache's entry."""
    if cnew[6][q] == 1 or d < cnew[1][q]:
        _advance_into(old, p, cnew, q, fx, fy, d, mot, order)
        stats[3] += 1


@nb.njit(cache=True)
def _spill_resident(new: tuple, cnew: tuple, q: int, stats: np.ndarray) -> None:
    """The galpixel about to be overwritten goes to the cache if nearer than the cache's entry."""
    if cnew[6][q] == 1 or new[1][q] < cnew[1][q]:
        _copy(new, q, cnew, q)
        stats[3] += 1


@nb.njit(cache=True)
def _cache_pass(
    cold: tuple, new: tuple, cnew: tuple, z: int, h: int, w: int, order: int, fp: int,
    fm: int, stats: np.ndarray, src_idx: np.ndarray,
) -> None:
    """Propagate zone ``z`` of the old cache into the new one, then promote.

    Cached galpixels take the z-test among themselves; afterwards each one sitting
    where the main map is still debris moves into the main map.
    """
    for r in range(h):
        for c in range(w):
            p = (z * h + r) * w + c
            if cold[6][p] == 1:
                continue
            qr, qc, fx, fy, d, mot = _target(cold, p, r, c, order, fp, fm)
            if qr < 0 or qc < 0 or qr >= h or qc >= w:
                continue
            q = (z * h + qr) * w + qc
            if cnew[6][q] == 1 or d < cnew[1][q]:
                _advance_into(cold, p, cnew, q, fx, fy, d, mot, order)
    for p in range(z * h * w, (z + 1) * h * w):
        if new[6][p] == 1 and cnew[6][p] == 0:
            _copy(cnew, p, new, p)
            cnew[6][p] = 1
            src_idx[p] = -1
            stats[4] += 1


@nb.njit(cache=True)
def second_sweep(
    new: tuple, src_idx: np.ndarray, old_depth: np.ndarray, old_debris: np.ndarray,
    threshold: float, n_neighbours: int, mode: int, margin: int,
    out_colour: np.ndarray, out_depth: np.ndarray, out_debris: np.ndarray, stats: np.ndarray,
) -> None:
    """Second sweep: expansion of debris (when ``threshold`` >= 0), then the display copy.

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
                if deb[z, r, c] == 0:
                    continue
                # cheap pre-check: only debris next to a galpixel can be expanded
                near = (c > 0 and deb[z, r, c - 1] == 0) or (c < w - 1 and deb[z, r, c + 1] == 0) \
                    or (r > 0 and deb[z, r - 1, c] == 0) or (r < h - 1 and deb[z, r + 1, c] == 0)
                if threshold >= 0 and near and expand_pixel(
                        new, src_idx, old_depth, old_debris, threshold, z, r, c, n_neighbours,
                        mode):
                    expanded += 1
                else:
                    left += 1
    for z in range(nz):
        for rr in range(h - 2 * margin):
            for cc in range(w - 2 * margin):
                r, c = rr + margin, cc + margin
                out_colour[z, rr, cc, 0] = np.uint8(min(max(col[0, z, r, c] + 0.5, 0.0), 255.0))
                out_colour[z, rr, cc, 1] = np.uint8(min(max(col[1, z, r, c] + 0.5, 0.0), 255.0))
                out_colour[z, rr, cc, 2] = np.uint8(min(max(col[2, z, r, c] + 0.5, 0.0), 255.0))
                out_depth[z, rr, cc] = dep[z, r, c]
                out_debris[z, rr, cc] = deb[z, r, c] == 1
    stats[5] += expanded
    stats[6] += left
