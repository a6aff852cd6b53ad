"""One refresh of propagation: the one-pass scatter of section 3.1.

The new map starts with every debris flag set and nothing else cleared.  One scan
of the old map runs, for each old pixel, the paper's parallel arms:

* the **debris arm** copies the old pixel's colour, depth and object to the same
  place in the new map if that place is still debris (no motion, flag kept);
* the **galpixel arm** (disabled when the old pixel is itself debris) advances the
  galpixel one refresh (:func:`_step`, the one place every kernel takes the step
  from: :func:`service.galilean.fixed_point.advance` in x, y and z; colour
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

from service.galilean.fixed_point import Z_EMPTY, advance, pixel_of
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
    src: tuple,
    p: int,
    dst: tuple,
    q: int,
    fx: int,
    fy: int,
    depth: float,
    mot: tuple,
    order: int,
) -> None:
    """Write galpixel ``p`` of ``src``, advanced one refresh, at ``q`` of ``dst``.

    ``mot`` is ``(vx, vy, ax, ay, vz, az)`` after the step (from :func:`advance`),
    ``depth`` the new depth, ``fx``, ``fy`` the new fraction.
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
        d_zm[0, q] = mot[4]
    if order >= 2:
        d_mot[2, q] = mot[2]
        d_mot[3, q] = mot[3]
        d_zm[1, q] = mot[5]
    if order >= 3:
        d_mot[4, q] = s_mot[4, p]
        d_mot[5, q] = s_mot[5, p]
        d_zm[2, q] = s_zm[2, p]
    dst[6][q] = 0
    dst[7][q] = src[7][p]


@nb.njit(cache=True, inline="always", error_model="numpy")
def _step(
    r: int,
    c: int,
    fx: int,
    fy: int,
    d: int,
    vx: int,
    vy: int,
    ax: int,
    ay: int,
    jx: int,
    jy: int,
    vz: int,
    az: int,
    jz: int,
    order: int,
    fp: int,
    fm: int,
) -> tuple:
    """One refresh of one galpixel: the advance step, the only place it is written.

    Scalars in, scalars out (no arrays: a kernel's hot loop pays no reference
    counting for the call, and the compiler sees through it; no tuples either:
    numba's parallel array analysis trips over tuples of equal scalars).  The
    galpixel at row ``r``, column ``c`` with fraction ``(fx, fy)``, depth ``d``,
    motion ``(vx, vy, ax, ay, jx, jy)`` and z motion ``(vz, az, jz)`` (int64, 0
    beyond ``order``) moves by :func:`service.galilean.fixed_point.advance` in
    x, y and z.

    Returns
    -------
    tuple of int64
        ``(qr, qc, fx, fy, d, vx, vy, ax, ay, vz, az)``: the pixel it lands on, its
        new fraction, depth and motion (jerk is constant).
    """
    x, vx, ax = advance((np.int64(c) << fp) + fx, vx, ax, jx, order, fp, fm)
    y, vy, ay = advance((np.int64(r) << fp) + fy, vy, ay, jy, order, fp, fm)
    d, vz, az = advance(np.int64(d), vz, az, jz, order, fp, fm)
    qc, qr = pixel_of(x, fp), pixel_of(y, fp)
    return qr, qc, x - (qc << fp), y - (qr << fp), d, vx, vy, ax, ay, vz, az


@nb.njit(cache=True, inline="always")
def _zplanes(zm: tuple, p: int, order: int) -> tuple:
    """Galpixel ``p``'s z motion ``(vz, az, jz)`` as int64, 0 beyond ``order``."""
    z0 = np.int64(zm[0, p]) if order >= 1 else np.int64(0)
    z1 = np.int64(zm[1, p]) if order >= 2 else np.int64(0)
    z2 = np.int64(zm[2, p]) if order >= 3 else np.int64(0)
    return z0, z1, z2


@nb.njit(cache=True, inline="always")
def _motion_at(mot: np.ndarray, zm: np.ndarray, p: int, order: int) -> tuple:
    """Galpixel ``p``'s ``(vx, vy, ax, ay, jx, jy, vz, az, jz)`` as int64, 0 beyond ``order``.

    ``mot`` and ``zm`` are flat motion planes (2 order, N) and (order, N).
    """
    z = np.int64(0)
    vx = np.int64(mot[0, p]) if order >= 1 else z
    vy = np.int64(mot[1, p]) if order >= 1 else z
    ax = np.int64(mot[2, p]) if order >= 2 else z
    ay = np.int64(mot[3, p]) if order >= 2 else z
    jx = np.int64(mot[4, p]) if order >= 3 else z
    jy = np.int64(mot[5, p]) if order >= 3 else z
    vz = np.int64(zm[0, p]) if order >= 1 else z
    az = np.int64(zm[1, p]) if order >= 2 else z
    jz = np.int64(zm[2, p]) if order >= 3 else z
    return vx, vy, ax, ay, jx, jy, vz, az, jz


@nb.njit(cache=True, error_model="numpy")
def sweep(
    old: tuple,
    new: tuple,
    cold: tuple,
    cnew: tuple,
    cache_on: bool,
    src_idx: np.ndarray,
    shape: tuple,
    order: int,
    fp: int,
    fm: int,
    track: bool,
    stats: np.ndarray,
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
    n_prop = n_clash = n_drop = 0
    # The advance step is _step (scalars only, inlined): passing arrays to helpers
    # costs numba reference-count traffic on every call, several times the work.
    for z in range(nz):
        for r in range(h):
            base = (z * h + r) * w
            for c in range(w):
                p = base + c
                galpixel = o_deb[p] == 0
                qr, qc = r, c
                if galpixel:
                    vx, vy, ax, ay, jx, jy, vz, az, jz = _motion_at(o_mot, o_zm, p, order)
                    qr, qc, fx, fy, d, vx, vy, ax, ay, vz, az = _step(
                        r, c, o_frac[0, p], o_frac[1, p], o_dep[p],
                        vx, vy, ax, ay, jx, jy, vz, az, jz, order, fp, fm,
                    )  # fmt: skip
                # debris arm (own place free): for an old galpixel that moved away,
                # and for old debris, which keeps the colour it last showed
                if n_deb[p] == 1 and (not galpixel or qr != r or qc != c):
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
                if n_deb[q] == 0:
                    n_clash += 1
                    if d >= n_dep[q]:
                        if cache_on:
                            mot = (vx, vy, ax, ay, vz, az)
                            _spill_incoming(old, p, cnew, q, fx, fy, d, mot, order, stats)
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
                    n_zm[0, q] = vz
                if order >= 2:
                    n_mot[2, q] = ax
                    n_mot[3, q] = ay
                    n_zm[1, q] = az
                if order >= 3:
                    n_mot[4, q] = o_mot[4, p]
                    n_mot[5, q] = o_mot[5, p]
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
    old: tuple,
    p: int,
    cnew: tuple,
    q: int,
    fx: int,
    fy: int,
    d: float,
    mot: tuple,
    order: int,
    stats: np.ndarray,
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
    cold: tuple,
    new: tuple,
    cnew: tuple,
    z: int,
    h: int,
    w: int,
    order: int,
    fp: int,
    fm: int,
    stats: np.ndarray,
    src_idx: np.ndarray,
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
            vx, vy, ax, ay, jx, jy, vz, az, jz = _motion_at(cold[3], cold[4], p, order)
            qr, qc, fx, fy, d, vx, vy, ax, ay, vz, az = _step(
                r, c, cold[2][0, p], cold[2][1, p], cold[1][p],
                vx, vy, ax, ay, jx, jy, vz, az, jz, order, fp, fm,
            )  # fmt: skip
            mot = (vx, vy, ax, ay, vz, az)
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
    new: tuple,
    src_idx: np.ndarray,
    old_depth: np.ndarray,
    old_debris: np.ndarray,
    threshold: float,
    n_neighbours: int,
    mode: int,
    margin: int,
    out_colour: np.ndarray,
    out_depth: np.ndarray,
    out_debris: np.ndarray,
    stats: np.ndarray,
    zs: float = 1.0,
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
                near = (
                    (c > 0 and deb[z, r, c - 1] == 0)
                    or (c < w - 1 and deb[z, r, c + 1] == 0)
                    or (r > 0 and deb[z, r - 1, c] == 0)
                    or (r < h - 1 and deb[z, r + 1, c] == 0)
                )
                if (
                    threshold >= 0
                    and near
                    and expand_pixel(
                        new, src_idx, old_depth, old_debris, threshold, z, r, c, n_neighbours, mode
                    )
                ):
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
                d = dep[z, r, c]
                out_depth[z, rr, cc] = np.inf if d == Z_EMPTY else d * zs
                out_debris[z, rr, cc] = deb[z, r, c] == 1
    stats[5] += expanded
    stats[6] += left


# ------------------------------------------------------------------ fast path
# The stage runs ``scatter_bands`` (or ``scatter`` when the obscuration cache is on)
# and then ``finish``; together they do what ``sweep`` + ``second_sweep`` do, bit
# for bit (tests/galilean/test_gal_speed_equivalence.py).  ``sweep`` and
# ``second_sweep`` stay as the straightforward reference.  The debris arm is
# deferred to ``finish`` (its result only survives where no galpixel landed, and,
# as in ``sweep``, only for old galpixels), which also does the expansion and the
# display copy of each row in one go.  Fast-path indices are unsigned (see ``_u``).


@nb.njit(cache=True, error_model="numpy")
def scatter(
    old: tuple,
    new: tuple,
    cold: tuple,
    cnew: tuple,
    cache_on: bool,
    src_idx: np.ndarray,
    shape: tuple,
    order: int,
    fp: int,
    fm: int,
    track: bool,
    stats: np.ndarray,
) -> None:
    """First sweep without its debris arm (:func:`finish` does it); see :func:`sweep`.

    Same parameters and the same arithmetic, operation for operation.  Afterwards
    a new pixel whose debris flag is still set holds stale fields until
    :func:`finish` runs the debris arm there.

    Written for the machine: flat indices are unsigned (numba cannot prove a signed
    one non-negative and adds a negative-index wraparound to every access), and
    each galpixel is read whole into registers before anything is stored (stores
    to the new map would otherwise force reloads, and page-aligned planes alias
    the loads that follow them in the store buffer).


    The one kernel that still writes the advance step out rather than calling
    :func:`_step`: through :func:`_step` (order a run-time value, so every
    component's order test stays in the loop) it took 5-8 % more CPU time for
    G(1)-G(3) at 640x480, side by side.
    """
    nz, h, w = shape
    o_col, o_dep, o_frac, o_mot, o_zm, o_dc, o_deb, o_obj = old
    n_col, n_dep, n_frac, n_mot, n_zm, n_dc, n_deb, n_obj = new
    ncol = o_dc.shape[0]
    sh = fm - fp
    half = np.int64(1) << (fp - 1)
    n_prop = n_clash = n_drop = 0
    for z in range(nz):
        for r in range(h):
            base = (z * h + r) * w
            y0 = np.int64(r) << fp
            for c in range(w):
                p = np.uint64(base + c)
                if o_deb[p] != 0:
                    continue
                x = (np.int64(c) << fp) + o_frac[0, p]
                y = y0 + o_frac[1, p]
                d = np.int64(o_dep[p])
                vx = vy = ax = ay = jx = jy = np.int64(0)
                if order == 1:
                    vx, vy = np.int64(o_mot[0, p]), np.int64(o_mot[1, p])
                    x += (vx + (1 << (sh - 1))) >> sh
                    y += (vy + (1 << (sh - 1))) >> sh
                elif order == 2:
                    vx, vy = np.int64(o_mot[0, p]), np.int64(o_mot[1, p])
                    ax, ay = np.int64(o_mot[2, p]), np.int64(o_mot[3, p])
                    x += (2 * vx + ax + (1 << sh)) >> (sh + 1)
                    y += (2 * vy + ay + (1 << sh)) >> (sh + 1)
                    vx += ax
                    vy += ay
                elif order == 3:
                    jx, jy = np.int64(o_mot[4, p]), np.int64(o_mot[5, p])
                    x, vx, ax = advance(
                        x, np.int64(o_mot[0, p]), np.int64(o_mot[2, p]), jx, 3, fp, fm
                    )
                    y, vy, ay = advance(
                        y, np.int64(o_mot[1, p]), np.int64(o_mot[3, p]), jy, 3, fp, fm
                    )
                z0, z1, z2 = _zplanes(o_zm, p, order)
                d, vz, az = advance(d, z0, z1, z2, order, fp, fm)
                qc = (x + half) >> fp
                qr = (y + half) >> fp
                n_prop += 1
                if qr < 0 or qc < 0 or qr >= h or qc >= w:
                    n_drop += 1
                    continue
                q = np.uint64((z * h + qr) * w + qc)
                fx, fy = x - (qc << fp), y - (qr << fp)
                if n_deb[q] == 0:
                    n_clash += 1
                    if d >= n_dep[q]:
                        if cache_on:
                            _spill_incoming(
                                old,
                                np.int64(p),
                                cnew,
                                np.int64(q),
                                fx,
                                fy,
                                d,
                                (vx, vy, ax, ay, vz, az),
                                order,
                                stats,
                            )
                        continue
                    if cache_on:
                        _spill_resident(new, cnew, np.int64(q), stats)
                c0, c1, c2 = o_col[0, p], o_col[1, p], o_col[2, p]
                ob = o_obj[p]
                if ncol == 4:
                    da, db, dc, d2a = o_dc[0, p], o_dc[1, p], o_dc[2, p], o_dc[3, p]
                    sa = da + 0.5 * d2a
                    n_col[0, q] = c0 + (sa + db)
                    n_col[1, q] = c1 + (sa - dc)
                    n_col[2, q] = c2 + (sa - db + dc)
                    n_dc[0, q] = da + d2a
                    n_dc[1, q] = db
                    n_dc[2, q] = dc
                    n_dc[3, q] = d2a
                else:
                    n_col[0, q] = c0
                    n_col[1, q] = c1
                    n_col[2, q] = c2
                n_dep[q] = d
                n_frac[0, q] = fx
                n_frac[1, q] = fy
                if order == 1:
                    n_mot[0, q] = vx
                    n_mot[1, q] = vy
                    n_zm[0, q] = vz
                elif order == 2:
                    n_mot[0, q] = vx
                    n_mot[1, q] = vy
                    n_mot[2, q] = ax
                    n_mot[3, q] = ay
                    n_zm[0, q] = vz
                    n_zm[1, q] = az
                elif order == 3:
                    n_mot[0, q] = vx
                    n_mot[1, q] = vy
                    n_mot[2, q] = ax
                    n_mot[3, q] = ay
                    n_mot[4, q] = jx
                    n_mot[5, q] = jy
                    n_zm[0, q] = vz
                    n_zm[1, q] = az
                    n_zm[2, q] = z2
                n_deb[q] = 0
                n_obj[q] = ob
                if track:
                    src_idx[q] = r * w + c
        if cache_on:
            _cache_pass(cold, new, cnew, z, h, w, order, fp, fm, stats, src_idx)
    stats[0] += n_prop
    stats[1] += n_clash
    stats[2] += n_drop


def planes(arrays: tuple) -> tuple:
    """A map's array tuple as flat planes, the form the fast kernels take.

    ``(colour, depth, frac, motion, zmotion, dcolour, debris, obj)`` with every
    multi-plane field a tuple of fixed length (3, 2, 6, 3, 4) of 1-D C-contiguous
    (N,) planes, planes a map lacks filled in by empty arrays (never touched: the
    kernels know the order and the colour planes).  Fixed lengths give one compiled
    kernel for all orders; 1-D contiguous planes give numba unit-stride addressing.
    """
    n = arrays[1].size

    def group(a: np.ndarray, k: int) -> tuple:
        return tuple(a[i].reshape(n) if i < a.shape[0] else np.empty(0, a.dtype) for i in range(k))

    col, dep, frac, mot, zm, dc, deb, obj = arrays
    return (
        group(col, 3),
        dep.reshape(n),
        group(frac, 2),
        group(mot, 6),
        group(zm, 3),
        group(dc, 4),
        deb.reshape(n),
        obj.reshape(n),
    )


@nb.njit(cache=True, inline="always")
def _u(i: int) -> np.uint64:
    """An index as unsigned: numba then skips its negative-index wraparound code."""
    return np.uint64(i)


@nb.njit(cache=True, inline="always")
def _landing(qr: int, qc: int, debris: int, z: int, h: int, w: int) -> int:
    """Flat landing pixel of a galpixel landing at row ``qr``, column ``qc`` of zone ``z``.

    -1 for debris, -2 off the map.
    """
    inside = (qr >= 0) & (qc >= 0) & (qr < h) & (qc < w)
    return -1 if debris != 0 else ((z * h + qr) * w + qc if inside else -2)


@nb.njit(cache=True, inline="always")
def _no_colour_motion(dc: tuple, ncol: int, p: np.uint64) -> bool:
    """Whether galpixel ``p``'s colour derivatives (``ncol`` planes of ``dc``) are all zero."""
    return ncol == 0 or (dc[0][p] == 0 and dc[1][p] == 0 and dc[2][p] == 0 and dc[3][p] == 0)


@nb.njit(cache=True, inline="always")
def _unmoved(
    p: np.uint64,
    i: np.uint64,
    frac: tuple,
    fxb: np.ndarray,
    fyb: np.ndarray,
    vxb: np.ndarray,
    vyb: np.ndarray,
    axb: np.ndarray,
    ayb: np.ndarray,
) -> None:
    """Batch entry ``i`` for the copy of static galpixel ``p`` (its fraction, no motion)."""
    fxb[i] = frac[0][p]
    fyb[i] = frac[1][p]
    vxb[i] = vyb[i] = axb[i] = ayb[i] = 0


@nb.njit(cache=True, inline="always")
def _all_set(flags: np.ndarray, a: int, b: int) -> bool:
    """Whether ``flags[a:b]`` (uint8) are all non-zero."""
    every = np.uint8(1)
    for k in range(a, b):
        every &= flags[_u(k)]
    return every != 0


#: Pixels :func:`scatter_bands` checks at once for galpixels known static.
CHUNK = 32


#: Pixels per batch of rows :func:`scatter_bands` advances before it copies.
BATCH = 4096


@nb.njit(cache=True, inline="always", error_model="numpy")
def _scatter_bands_body(
    old: tuple,
    new: tuple,
    src_idx: np.ndarray,
    shape: tuple,
    order: int,
    fp: int,
    fm: int,
    ncol: int,
    track: bool,
    reach: int,
    bands: int,
    stats: np.ndarray,
    reach_out: np.ndarray,
    same_in: np.ndarray,
    same_out: np.ndarray,
    use_same: bool,
    record: bool,
    bookkeeping: bool,
) -> None:
    """The body of :func:`scatter_bands` and :func:`scatter_bands_plain`.

    ``bookkeeping`` is a constant where the two kernels inline this body, so numba
    prunes the still-galpixel branches and stores from :func:`scatter_bands_plain`
    (with them, the first refresh after every change was 15-20 % slower).  Two
    module-level kernels, not one built by a factory: each has its own entry in
    numba's cache (``holo-warmup`` compiles both; a second process loads both).
    """
    nz, h, w = shape
    o_col, o_dep, o_frac, o_mot, o_zm, o_dc, o_deb, o_obj = old
    n_col, n_dep, n_frac, n_mot, n_zm, n_dc, n_deb, n_obj = new
    k0 = np.int64(0)
    rows = max(1, min(h, BATCH // w))
    size = rows * w
    # batch buffers, one row per band (allocated outside the parallel loop)
    qb_all = np.empty((bands, size), np.int64)  # landing pixel; -1 debris, -2 off the map
    db_all = np.empty((bands, size), np.int64)  # new depth
    fxb_all = np.empty((bands, size), np.int16)
    fyb_all = np.empty((bands, size), np.int16)
    vxb_all = np.empty((bands, size), np.int32)
    vyb_all = np.empty((bands, size), np.int32)
    axb_all = np.empty((bands, size), np.int32)
    ayb_all = np.empty((bands, size), np.int32)
    run_i_all = np.empty((bands, size), np.int64)  # first batch index of a run
    run_q_all = np.empty((bands, size), np.int64)  # its landing pixel
    run_n_all = np.empty((bands, size), np.int64)  # its length
    sb_all = np.zeros((bands, size), np.uint8)  # 1: no motion, lands on its own pixel
    for band in nb.prange(bands):
        lo, hi = band * h // bands, (band + 1) * h // bands
        r_lo, r_hi = max(0, lo - reach), min(h, hi + reach)
        qb = qb_all[band]
        db = db_all[band]
        fxb = fxb_all[band]
        fyb = fyb_all[band]
        vxb = vxb_all[band]
        vyb = vyb_all[band]
        axb = axb_all[band]
        ayb = ayb_all[band]
        run_i = run_i_all[band]
        run_q = run_q_all[band]
        run_n = run_n_all[band]
        sb = sb_all[band]
        n_prop = n_clash = n_drop = np.int64(0)
        mvy = may = mjy = np.int64(0)
        for z in range(nz):
            zb = z * h * w
            q_lo, q_hi = zb + lo * w, zb + hi * w  # this band's new pixels
            for r0 in range(r_lo, r_hi, rows):
                nr = min(rows, r_hi - r0)
                b0 = zb + r0 * w  # flat index of the batch's first pixel
                own_lo, own_hi = (lo - r0) * w, (hi - r0) * w  # batch indices of own rows
                # 1. advance (one loop per order: a loop-invariant branch inside
                #    would keep LLVM from vectorising it)
                for rr in range(nr):
                    r = r0 + rr
                    p0 = zb + r * w
                    i0 = rr * w
                    # stretches of whole chunks known static (left to step 2) and
                    # the stretches between them (long loops: each loop entry
                    # checks aliasing)
                    ce = 0
                    while ce < w:
                        ca = cb = ce
                        if not (bookkeeping and use_same):
                            cb = ce = w
                        while cb < w and not _all_set(same_in, p0 + cb,
                                                      p0 + min(w, cb + CHUNK)):
                            cb = min(w, cb + CHUNK)
                        ce = max(ce, cb)
                        while ce < w and _all_set(same_in, p0 + ce, p0 + min(w, ce + CHUNK)):
                            ce = min(w, ce + CHUNK)
                        if order == 0:
                            for c in range(ca, cb):
                                p, i = _u(p0 + c), _u(i0 + c)
                                deb = o_deb[p]  # every load before the first store
                                qr, qc, fx, fy, d = _step(
                                    r, c, o_frac[0][p], o_frac[1][p], o_dep[p],
                                    k0, k0, k0, k0, k0, k0, k0, k0, k0, 0, fp, fm,
                                )[:5]  # fmt: skip
                                qb[i] = _landing(qr, qc, deb, z, h, w)
                                fxb[i], fyb[i], db[i] = fx, fy, d
                                if bookkeeping:
                                    sb[i] = qb[i] == p0 + c
                        elif order == 1:
                            for c in range(ca, cb):
                                p, i = _u(p0 + c), _u(i0 + c)
                                vx, vy = np.int64(o_mot[0][p]), np.int64(o_mot[1][p])
                                vz, deb = np.int64(o_zm[0][p]), o_deb[p]
                                qr, qc, fx, fy, d, vx1, vy1 = _step(
                                    r, c, o_frac[0][p], o_frac[1][p], o_dep[p],
                                    vx, vy, k0, k0, k0, k0, vz, k0, k0, 1, fp, fm,
                                )[:7]  # fmt: skip
                                qb[i] = _landing(qr, qc, deb, z, h, w)
                                fxb[i], fyb[i], db[i], vxb[i], vyb[i] = fx, fy, d, vx1, vy1
                                if bookkeeping:
                                    sb[i] = (qb[i] == p0 + c) & ((vx | vy | vz) == 0)
                        elif order == 2:
                            for c in range(ca, cb):
                                p, i = _u(p0 + c), _u(i0 + c)
                                vx, vy = np.int64(o_mot[0][p]), np.int64(o_mot[1][p])
                                ax, ay = np.int64(o_mot[2][p]), np.int64(o_mot[3][p])
                                vz, az = np.int64(o_zm[0][p]), np.int64(o_zm[1][p])
                                deb = o_deb[p]
                                qr, qc, fx, fy, d, vx1, vy1, ax1, ay1 = _step(
                                    r, c, o_frac[0][p], o_frac[1][p], o_dep[p],
                                    vx, vy, ax, ay, k0, k0, vz, az, k0, 2, fp, fm,
                                )[:9]  # fmt: skip
                                qb[i] = _landing(qr, qc, deb, z, h, w)
                                fxb[i], fyb[i], db[i] = fx, fy, d
                                vxb[i], vyb[i], axb[i], ayb[i] = vx1, vy1, ax1, ay1
                                if bookkeeping:
                                    still = (vx | vy | ax | ay | vz | az) == 0
                                    sb[i] = (qb[i] == p0 + c) & still
                        else:
                            for c in range(ca, cb):
                                p, i = _u(p0 + c), _u(i0 + c)
                                vx, vy = np.int64(o_mot[0][p]), np.int64(o_mot[1][p])
                                ax, ay = np.int64(o_mot[2][p]), np.int64(o_mot[3][p])
                                jx, jy = np.int64(o_mot[4][p]), np.int64(o_mot[5][p])
                                vz, az = np.int64(o_zm[0][p]), np.int64(o_zm[1][p])
                                jz = np.int64(o_zm[2][p])
                                deb = o_deb[p]
                                qr, qc, fx, fy, d, vx1, vy1, ax1, ay1 = _step(
                                    r, c, o_frac[0][p], o_frac[1][p], o_dep[p],
                                    vx, vy, ax, ay, jx, jy, vz, az, jz, 3, fp, fm,
                                )[:9]  # fmt: skip
                                qb[i] = _landing(qr, qc, deb, z, h, w)
                                fxb[i], fyb[i], db[i] = fx, fy, d
                                vxb[i], vyb[i], axb[i], ayb[i] = vx1, vy1, ax1, ay1
                                if bookkeeping:
                                    still = (vx | vy | ax | ay | jx | jy | vz | az | jz) == 0
                                    sb[i] = (qb[i] == p0 + c) & still
                # 2. z-test in scan order; the open run is kept in registers
                runs = 0
                ri = rq = rn = np.int64(0)
                for i in range(nr * w):
                    p = _u(b0 + i)
                    known = bookkeeping and use_same and same_in[p] != 0  # still, new holds it
                    q = b0 + i if known else qb[i]
                    own = own_lo <= i < own_hi
                    if q < 0 or q < q_lo or q >= q_hi:
                        if q != -1 and own:
                            n_prop += 1
                            n_drop += q == -2
                        if rn:
                            run_i[runs], run_q[runs], run_n[runs] = ri, rq, rn
                            runs += 1
                            rn = 0
                        continue
                    n_prop += own
                    fresh = n_deb[_u(q)] != 0
                    if known and fresh:
                        # the first to land on its own pixel, which holds it already
                        n_deb[_u(q)] = 0
                        if bookkeeping and record:
                            same_out[_u(q)] = 1
                        if rn:
                            run_i[runs], run_q[runs], run_n[runs] = ri, rq, rn
                            runs += 1
                            rn = 0
                        continue
                    d = np.int64(o_dep[p]) if known else db[i]
                    if not fresh:
                        n_clash += 1
                        if d >= n_dep[_u(q)]:
                            if rn:
                                run_i[runs], run_q[runs], run_n[runs] = ri, rq, rn
                                runs += 1
                                rn = 0
                            continue
                    n_dep[_u(q)] = d
                    n_deb[_u(q)] = 0
                    if known:  # step 1 skipped it: its batch entries for the copy
                        _unmoved(p, _u(i), o_frac, fxb, fyb, vxb, vyb, axb, ayb)
                    if bookkeeping and record:
                        still = known or (sb[i] != 0 and _no_colour_motion(o_dc, ncol, p))
                        same_out[_u(q)] = still
                    if rn and q == rq + rn:
                        rn += 1
                    else:
                        if rn:
                            run_i[runs], run_q[runs], run_n[runs] = ri, rq, rn
                            runs += 1
                        ri, rq, rn = i, q, 1
                if rn:
                    run_i[runs], run_q[runs], run_n[runs] = ri, rq, rn
                    runs += 1
                # 3. copy, plane by plane, run by run
                for k in range(runs):
                    i0, q0, m = run_i[k], run_q[k], run_n[k]
                    s0 = b0 + i0
                    if ncol == 4:
                        for j in range(m):
                            p, q = _u(s0 + j), _u(q0 + j)
                            da, dbb, dcc, d2a = o_dc[0][p], o_dc[1][p], o_dc[2][p], o_dc[3][p]
                            sa = da + 0.5 * d2a
                            n_col[0][q] = o_col[0][p] + (sa + dbb)
                            n_col[1][q] = o_col[1][p] + (sa - dcc)
                            n_col[2][q] = o_col[2][p] + (sa - dbb + dcc)
                            n_dc[0][q] = da + d2a
                            n_dc[1][q] = dbb
                            n_dc[2][q] = dcc
                            n_dc[3][q] = d2a
                    else:
                        for j in range(m):
                            p, q = _u(s0 + j), _u(q0 + j)
                            n_col[0][q] = o_col[0][p]
                            n_col[1][q] = o_col[1][p]
                            n_col[2][q] = o_col[2][p]
                    for j in range(m):
                        b, q = _u(i0 + j), _u(q0 + j)
                        n_frac[0][q] = fxb[b]
                        n_frac[1][q] = fyb[b]
                    for j in range(m):
                        n_obj[_u(q0 + j)] = o_obj[_u(s0 + j)]
                    if track:
                        for j in range(m):
                            src_idx[_u(q0 + j)] = s0 - zb + j
                    if order >= 1:
                        for j in range(m):
                            b, q = _u(i0 + j), _u(q0 + j)
                            n_mot[0][q] = vxb[b]
                            n_mot[1][q] = vyb[b]
                            mvy = max(mvy, abs(np.int64(vyb[b])))
                    if order >= 2:
                        for j in range(m):
                            b, q = _u(i0 + j), _u(q0 + j)
                            n_mot[2][q] = axb[b]
                            n_mot[3][q] = ayb[b]
                            may = max(may, abs(np.int64(ayb[b])))
                    if order == 3:
                        for j in range(m):
                            p, q = _u(s0 + j), _u(q0 + j)
                            n_mot[4][q] = o_mot[4][p]
                            n_mot[5][q] = o_mot[5][p]
                            mjy = max(mjy, abs(np.int64(o_mot[5][p])))
                    if order == 1:
                        for j in range(m):
                            n_zm[0][_u(q0 + j)] = o_zm[0][_u(s0 + j)]
                    elif order == 2:
                        for j in range(m):
                            p, q = _u(s0 + j), _u(q0 + j)
                            n_zm[0][q] = o_zm[0][p] + o_zm[1][p]
                            n_zm[1][q] = o_zm[1][p]
                    elif order == 3:
                        for j in range(m):
                            p, q = _u(s0 + j), _u(q0 + j)
                            z0, z1, z2 = o_zm[0][p], o_zm[1][p], o_zm[2][p]
                            n_zm[0][q] = z0 + z1 + ((np.int64(z2) + 1) >> 1)
                            n_zm[1][q] = z1 + z2
                            n_zm[2][q] = z2
        stats[band, 0] += n_prop
        stats[band, 1] += n_clash
        stats[band, 2] += n_drop
        reach_out[band, 0] = mvy
        reach_out[band, 1] = may
        reach_out[band, 2] = mjy


@nb.njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def scatter_bands(
    old: tuple,
    new: tuple,
    src_idx: np.ndarray,
    shape: tuple,
    order: int,
    fp: int,
    fm: int,
    ncol: int,
    track: bool,
    reach: int,
    bands: int,
    stats: np.ndarray,
    reach_out: np.ndarray,
    same_in: np.ndarray,
    same_out: np.ndarray,
    use_same: bool,
    record: bool,
) -> None:
    """First sweep without its debris arm or cache, the new rows in parallel bands.

    Bit for bit the result of :func:`sweep` without cache, the debris arm left to
    :func:`finish`.  Maps are :func:`planes`; ``new``'s debris all 1 on entry.

    Each batch of old rows (about :data:`BATCH` pixels) is done in three steps:

    1. *advance* (plain element-wise loops, SIMD): every galpixel's landing pixel,
       new fraction, motion and depth into batch buffers;
    2. *z-test* (the only sequential part, in scan order like the paper's scan):
       each landing galpixel against the new map's debris flag and depth, which it
       writes when it wins; winners from consecutive old pixels that land on
       consecutive new pixels are gathered into runs;
    3. *copy*: each field, plane by plane, run by run (contiguous, SIMD).

    Within every plane the writes keep scan order, so a pixel that two winners
    land on ends up with the later one, as in the one-pass scan; the z-test only
    reads the flags and depths that step 2 keeps current.

    Band ``b`` owns the new rows
    ``[b H / bands, (b + 1) H / bands)`` of every zone: it advances, in scan order,
    the old rows a galpixel landing there can come from (its own rows and
    ``reach`` rows either side) and runs the z-test and the copy only for the
    galpixels that land in its rows.  Each new pixel thus sees its candidates in
    the one-pass scan's order, from one thread; no two bands write one pixel.

    Parameters
    ----------
    old, new : tuple
        The old and new maps as :func:`planes`.
    src_idx : ndarray, shape (N,), int32
        Out (when ``track``): for each new pixel, ``r * W + c`` of the old galpixel
        that landed there (pixels nothing lands on are left as they were).
    shape : tuple
        (Z, H, W).
    order, fp, fm : int
        Galpixel order; fractional bits of position and of motion.
    ncol : int
        Colour-derivative planes the map holds (:attr:`Galpixmap.colour_planes`: 4 or 0).
    track : bool
        Record ``src_idx`` (needed by the expansion sweep).
    reach : int
        A bound on the rows any galpixel of ``old`` moves this refresh
        (:func:`map_reach`, or :func:`reach_of` of the previous call's
        ``reach_out``).  A galpixel moving farther could be missed: callers must
        pass a true bound (``H`` is always one).
    bands : int
        Number of bands (any count gives the same result).
    stats : ndarray, shape (bands, 3), int64
        Accumulated per band: propagated, clashes, dropped (of its own old rows).
    reach_out : ndarray, shape (bands, 3), int64
        Out: per band the largest ``|vy|``, ``|ay|``, ``|jy|`` it wrote.
    same_in : ndarray, shape (N,), uint8
        1 where ``new`` already holds, bit for bit, the galpixel ``old`` holds and
        that galpixel is static (see below); read only when ``use_same``.
    same_out : ndarray, shape (N,), uint8
        Out, when ``record``: ``same_in`` for the next refresh, at every pixel a
        galpixel lands on (:func:`finish` writes the others).
    use_same : bool
        Whether ``same_in`` holds what the last refresh recorded (False after any
        other change to either map: a graft, a head-motion update).
    record : bool
        Whether to record ``same_out`` (it costs about a fifth of a refresh that
        cannot use it; the caller turns it off when the maps keep changing).

    Notes
    -----
    *Static galpixels are not rewritten.*  A galpixel with no motion, z motion or
    colour motion that lands on its own pixel (its fraction then unchanged) is a
    copy of itself.  ``same_in`` marks those that won their own pixel in the
    previous refresh too (when the maps were the other way round), so that the
    new map holds them already.  Step 1 skips whole chunks of such pixels
    (:data:`CHUNK`) and step 2, for one that is the first to land on its pixel,
    only clears the pixel's debris flag: its planes are neither read nor copied.
    A later galpixel that wins the pixel overwrites it as usual; one that landed
    first makes it a normal clash (its depth read, and copied if it wins).
    ``same_out`` records for the next refresh 1 where a pixel's winner is its own
    static galpixel, 0 where another galpixel won (pixels nothing lands on are
    left to :func:`finish`, which clears them).  The origin (``src_idx``) of a
    pixel left in place is not rewritten either: the previous refresh wrote the
    same.  The one difference from the one-pass scan is the sign of a zero: a
    static galpixel's colour of -0.0 stays -0.0 where the scan's ``colour + 0.0``
    writes +0.0.
    """
    _scatter_bands_body(
        old, new, src_idx, shape, order, fp, fm, ncol, track, reach, bands, stats, reach_out,
        same_in, same_out, use_same, record, True
    )


@nb.njit(cache=True, nogil=True, parallel=True, error_model="numpy")
def scatter_bands_plain(
    old: tuple,
    new: tuple,
    src_idx: np.ndarray,
    shape: tuple,
    order: int,
    fp: int,
    fm: int,
    ncol: int,
    track: bool,
    reach: int,
    bands: int,
    stats: np.ndarray,
    reach_out: np.ndarray,
    same_in: np.ndarray,
    same_out: np.ndarray,
    use_same: bool,
    record: bool,
) -> None:
    """:func:`scatter_bands` without its still-galpixel bookkeeping (compiled out).

    What a refresh runs when it neither uses nor records ``same``: ``use_same`` and
    ``record`` are ignored (taken as False).
    """
    _scatter_bands_body(
        old, new, src_idx, shape, order, fp, fm, ncol, track, reach, bands, stats, reach_out,
        same_in, same_out, use_same, record, False
    )


@nb.njit(cache=True, inline="always")
def _show_row(
    c0: np.ndarray,
    c1: np.ndarray,
    c2: np.ndarray,
    dep: np.ndarray,
    deb: np.ndarray,
    p0: int,
    n: int,
    out_colour: np.ndarray,
    out_depth: np.ndarray,
    out_debris: np.ndarray,
    o0: int,
    zs: float,
) -> None:
    """Display copy of ``n`` pixels from flat index ``p0`` to output pixel ``o0``.

    Depth goes out as float32 depth units (``zs`` = 2^-fz per fixed-point unit).
    """
    for i in range(n):
        p, o, o3 = _u(p0 + i), _u(o0 + i), _u(3 * (o0 + i))
        out_colour[o3] = np.uint8(min(max(c0[p] + 0.5, 0.0), 255.0))
        out_colour[o3 + np.uint64(1)] = np.uint8(min(max(c1[p] + 0.5, 0.0), 255.0))
        out_colour[o3 + np.uint64(2)] = np.uint8(min(max(c2[p] + 0.5, 0.0), 255.0))
        out_depth[o] = np.inf if dep[p] == Z_EMPTY else dep[p] * zs
        out_debris[o] = deb[p] == 1


@nb.njit(cache=True)
def show(
    m: tuple,
    shape: tuple,
    margin: int,
    out_colour: np.ndarray,
    out_depth: np.ndarray,
    out_debris: np.ndarray,
    zs: float,
) -> None:
    """Display copy of a map (:func:`planes`, no expansion); outputs flattened too.

    ``zs`` is the depth unit (2^-fz) the displayed float32 depth is scaled by.
    """
    nz, h, w = shape
    ww = w - 2 * margin
    (c0, c1, c2), dep, deb = m[0], m[1], m[6]
    for z in range(nz):
        for r in range(margin, h - margin):
            o0 = (z * (h - 2 * margin) + r - margin) * ww
            _show_row(
                c0,
                c1,
                c2,
                dep,
                deb,
                (z * h + r) * w + margin,
                ww,
                out_colour,
                out_depth,
                out_debris,
                o0,
                zs,
            )


def debris_words(debris: np.ndarray) -> np.ndarray:
    """A (Z, H, W) uint8 debris plane's first ``8 (N // 8)`` bytes as uint64 words (a view)."""
    flat_ = debris.reshape(-1)
    return flat_[: flat_.size // 8 * 8].view(np.uint64)


@nb.njit(cache=True, nogil=True, parallel=True)
def show_bands(
    m: tuple,
    shape: tuple,
    margin: int,
    out_colour: np.ndarray,
    out_depth: np.ndarray,
    out_debris: np.ndarray,
    zs: float,
) -> None:
    """:func:`show` with the displayed rows split between threads (``nb.prange``)."""
    nz, h, w = shape
    hh, ww = h - 2 * margin, w - 2 * margin
    (c0, c1, c2), dep, deb = m[0], m[1], m[6]
    for k in nb.prange(nz * hh):
        z, rr = k // hh, k % hh
        _show_row(
            c0,
            c1,
            c2,
            dep,
            deb,
            (z * h + rr + margin) * w + margin,
            ww,
            out_colour,
            out_depth,
            out_debris,
            k * ww,
            zs,
        )


#: Debris pixels after the scatter, as a fraction of the map, from which the
#: expansion reads its Poisson tests from a :func:`poisson_interiors` table
#: (0.15-0.2 ms at 640x480 on two threads) instead of testing origins one by one.
TABLE_FROM = 1 / 128


@nb.njit(cache=True, inline="always")
def _interior_at(
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
    pc, pl, pr, pu, pd = _u(p), _u(p - 1), _u(p + 1), _u(p - w), _u(p + w)
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
        r = k % h
        base = k * w
        if r == 0 or r == h - 1:
            for c in range(w):
                out[_u(base + c)] = 0
            continue
        out[_u(base)] = 0
        out[_u(base + w - 1)] = 0
        for c in range(1, w - 1):
            out[_u(base + c)] = _interior_inside(dep, deb, base + c, w, threshold)


@nb.njit(cache=True, nogil=True)
def _finish_rows(
    new: tuple,
    old: tuple,
    src_idx: np.ndarray,
    deb64: np.ndarray,
    snap: np.ndarray,
    shape: tuple,
    k0: int,
    k1: int,
    n_mot: int,
    n_zm: int,
    ncol: int,
    threshold: float,
    n_neighbours: int,
    mode: int,
    track: bool,
    same_out: np.ndarray,
    interior: np.ndarray,
    table: bool,
    counts: np.ndarray,
    margin: int,
    out_colour: np.ndarray,
    out_depth: np.ndarray,
    out_debris: np.ndarray,
    write_out: bool,
    zs: float,
) -> None:
    """:func:`finish`'s scan of the map rows ``[k0, k1)`` (row ``k`` = ``z H + r``).

    ``new`` is the new map as :func:`planes`, ``old`` the old map's colour planes,
    depth, debris and object planes.  Every debris pixel in scan order; each
    row's debris flags are first copied to ``snap`` when it is not empty (for
    :func:`_fix_rows`).  ``counts`` (4,) accumulates expanded and debris left.
    """
    nz, h, w = shape
    # every plane in a local of its own, once: taking arrays out of tuples inside
    # the loop costs a reference-count pair each time (~1 us per expansion)
    (c0, c1, c2), dep, (f0, f1), mot, zm, dc, deb, obj = new
    m0, m1, m2, m3, m4, m5 = mot
    z0, z1, z2 = zm
    d0, d1, d2, d3 = dc
    o0, o1, o2, o_dep, o_deb, o_obj = old
    ww = w - 2 * margin
    keep = snap.size > 0
    expanded = left = 0
    n8 = 8 * deb64.size
    for k in range(k0, k1):
        z = k // h
        r = k - z * h
        zb = z * h * w
        base = k * w
        if keep:
            for c in range(w):
                snap[_u(base + c)] = deb[_u(base + c)]
        c = np.int64(-1)
        while c < w - 1:
            c += 1
            p = _u(base + c)
            if (p & 7) == 0 and c + 8 <= w and p + 8 <= n8 and deb64[p >> 3] == 0:
                c += 7  # eight galpixels: nothing to do
                continue
            if deb[p] == 0:
                continue
            same_out[p] = 0
            near = (
                (c > 0 and deb[_u(base + c - 1)] == 0)
                or (c < w - 1 and deb[_u(base + c + 1)] == 0)
                or (r > 0 and deb[_u(base + c - w)] == 0)
                or (r < h - 1 and deb[_u(base + c + w)] == 0)
            )
            if threshold >= 0 and near:
                # expansion (poisson.expand_pixel, same arithmetic)
                first = np.int64(-1)
                n = 0
                acc0 = acc1 = acc2 = accd = 0.0
                for k in range(n_neighbours):
                    if k == 0:
                        ok, qi = c > 0, base + c - 1
                    elif k == 1:
                        ok, qi = r > 0, base + c - w
                    elif k == 2:
                        ok, qi = c < w - 1, base + c + 1
                    else:
                        ok, qi = r < h - 1, base + c + w
                    if not ok or deb[_u(qi)] == 1:
                        continue
                    sq = np.int64(src_idx[_u(qi)])
                    if sq < 0:
                        continue
                    # Poisson test of the origin: from the table, or on the spot
                    if table:
                        if interior[_u(zb + sq)] == 0:
                            continue
                    elif not _interior_at(o_dep, o_deb, zb, sq, h, w, threshold):
                        continue
                    if first < 0:
                        first = qi
                    n += 1
                    acc0 += c0[_u(qi)]
                    acc1 += c1[_u(qi)]
                    acc2 += c2[_u(qi)]
                    accd += np.float64(dep[_u(qi)])
                if first >= 0:
                    q = _u(first)
                    c0[p] = c0[q]
                    c1[p] = c1[q]
                    c2[p] = c2[q]
                    dep[p] = dep[q]
                    if n_mot >= 2:
                        m0[p] = m0[q]
                        m1[p] = m1[q]
                    if n_mot >= 4:
                        m2[p] = m2[q]
                        m3[p] = m3[q]
                    if n_mot >= 6:
                        m4[p] = m4[q]
                        m5[p] = m5[q]
                    if n_zm >= 1:
                        z0[p] = z0[q]
                    if n_zm >= 2:
                        z1[p] = z1[q]
                    if n_zm >= 3:
                        z2[p] = z2[q]
                    if ncol == 4:
                        d0[p] = d0[q]
                        d1[p] = d1[q]
                        d2[p] = d2[q]
                        d3[p] = d3[q]
                    deb[p] = 0
                    obj[p] = obj[q]
                    if mode == 1:
                        c0[p] = acc0 / n
                        c1[p] = acc1 / n
                        c2[p] = acc2 / n
                        dep[p] = np.floor(accd / n + 0.5)
                    f0[p] = 0
                    f1[p] = 0
                    src_idx[p] = src_idx[q]
                    expanded += 1
                    continue
            left += 1
            # debris arm (also for old debris: it keeps the colour it last showed)
            c0[p] = o0[p]
            c1[p] = o1[p]
            c2[p] = o2[p]
            dep[p] = o_dep[p]
            obj[p] = o_obj[p]
            if track:
                src_idx[p] = -1
        if write_out and margin <= r < h - margin:
            _show_row(
                c0,
                c1,
                c2,
                dep,
                deb,
                base + margin,
                ww,
                out_colour,
                out_depth,
                out_debris,
                (z * (h - 2 * margin) + r - margin) * ww,
                zs,
            )
    counts[0] += expanded
    counts[1] += left


@nb.njit(cache=True, nogil=True)
def _fix_rows(
    new: tuple,
    old: tuple,
    src_idx: np.ndarray,
    snap: np.ndarray,
    shape: tuple,
    k0: int,
    k1: int,
    n_mot: int,
    n_zm: int,
    ncol: int,
    threshold: float,
    n_neighbours: int,
    mode: int,
    track: bool,
    same_out: np.ndarray,
    interior: np.ndarray,
    table: bool,
    counts: np.ndarray,
    margin: int,
    out_colour: np.ndarray,
    out_depth: np.ndarray,
    out_debris: np.ndarray,
    write_out: bool,
    zs: float,
) -> None:
    """A band's fix-up (see :func:`finish`): its top row ``k0``, then what that changes.

    Row ``k0`` (untouched by the band's scan) is scanned in full; in the rows
    below, up to ``k1``, only the debris pixels (as the scatter left them,
    ``snap``) whose left or upper neighbour this fix-up expanded are scanned
    again, until a row in which it expands nothing.  Right and lower neighbours'
    debris flags are read from ``snap``, as the one-band scan sees them.  The
    expansion and debris arm are :func:`_finish_rows`'s, arithmetic for
    arithmetic.  ``counts`` (4,): expanded and debris left are corrected for the
    pixels the band had done; rows fixed and pixels redone are added.
    """
    nz, h, w = shape
    (c0, c1, c2), dep, (f0, f1), mot, zm, dc, deb, obj = new
    m0, m1, m2, m3, m4, m5 = mot
    z0, z1, z2 = zm
    d0, d1, d2, d3 = dc
    o0, o1, o2, o_dep, o_deb, o_obj = old
    ww = w - 2 * margin
    # columns the fix-up expanded in the row above (ascending), and in this row
    prev, cur = np.empty(w, np.int64), np.empty(w, np.int64)
    n_prev = 0
    for k in range(k0, k1):
        z = k // h
        r = k - z * h
        zb = z * h * w
        base = k * w
        n_cur = i = 0
        c = np.int64(-1)
        chain = False  # the pixel just done was expanded: its right neighbour is due
        while True:
            # the next pixel due: every one in the top row; below it, one whose
            # upper neighbour (``prev``) or left neighbour (``chain``) was expanded
            if k == k0:
                c += 1
                if c >= w:
                    break
            else:
                while i < n_prev and prev[i] <= c:
                    i += 1
                if chain and c + 1 < w:
                    c += 1
                elif i < n_prev:
                    c = prev[i]
                else:
                    break
            chain = False
            p = _u(base + c)
            if snap[p] == 0:
                continue
            # what the band's scan did here: 0 nothing (top row), 1 expanded, 2 debris arm
            spec = 0 if k == k0 else (1 if deb[p] == 0 else 2)
            counts[3] += 1
            same_out[p] = 0
            near = (
                (c > 0 and deb[_u(base + c - 1)] == 0)
                or (c < w - 1 and snap[_u(base + c + 1)] == 0)
                or (r > 0 and deb[_u(base + c - w)] == 0)
                or (r < h - 1 and snap[_u(base + c + w)] == 0)
            )
            first = np.int64(-1)
            n = 0
            acc0 = acc1 = acc2 = accd = 0.0
            for kk in range(n_neighbours if threshold >= 0 and near else 0):
                if kk == 0:
                    ok, qi = c > 0, base + c - 1
                elif kk == 1:
                    ok, qi = r > 0, base + c - w
                elif kk == 2:
                    ok, qi = c < w - 1, base + c + 1
                else:
                    ok, qi = r < h - 1, base + c + w
                if not ok or (deb[_u(qi)] if kk < 2 else snap[_u(qi)]) == 1:
                    continue
                sq = np.int64(src_idx[_u(qi)])
                if sq < 0:
                    continue
                if table:
                    if interior[_u(zb + sq)] == 0:
                        continue
                elif not _interior_at(o_dep, o_deb, zb, sq, h, w, threshold):
                    continue
                if first < 0:
                    first = qi
                n += 1
                acc0 += c0[_u(qi)]
                acc1 += c1[_u(qi)]
                acc2 += c2[_u(qi)]
                accd += np.float64(dep[_u(qi)])
            if first < 0:
                # debris arm; a pixel the band expanded stays expanded (the fix-up
                # only adds galpixels), one it left as debris holds the same
                counts[1] += spec == 0
                if spec == 0:
                    c0[p] = o0[p]
                    c1[p] = o1[p]
                    c2[p] = o2[p]
                    dep[p] = o_dep[p]
                    obj[p] = o_obj[p]
                    if track:
                        src_idx[p] = -1
                continue
            q = _u(first)
            c0[p] = c0[q]
            c1[p] = c1[q]
            c2[p] = c2[q]
            dep[p] = dep[q]
            if n_mot >= 2:
                m0[p] = m0[q]
                m1[p] = m1[q]
            if n_mot >= 4:
                m2[p] = m2[q]
                m3[p] = m3[q]
            if n_mot >= 6:
                m4[p] = m4[q]
                m5[p] = m5[q]
            if n_zm >= 1:
                z0[p] = z0[q]
            if n_zm >= 2:
                z1[p] = z1[q]
            if n_zm >= 3:
                z2[p] = z2[q]
            if ncol == 4:
                d0[p] = d0[q]
                d1[p] = d1[q]
                d2[p] = d2[q]
                d3[p] = d3[q]
            deb[p] = 0
            obj[p] = obj[q]
            if mode == 1:
                c0[p] = acc0 / n
                c1[p] = acc1 / n
                c2[p] = acc2 / n
                dep[p] = np.floor(accd / n + 0.5)
            f0[p] = 0
            f1[p] = 0
            src_idx[p] = src_idx[q]
            # taken as changed for the pixels right of and below it (not compared)
            cur[n_cur] = c
            n_cur += 1
            chain = True
            counts[0] += spec != 1
            counts[1] -= spec == 2
        counts[2] += 1
        if write_out and margin <= r < h - margin:
            _show_row(
                c0,
                c1,
                c2,
                dep,
                deb,
                base + margin,
                ww,
                out_colour,
                out_depth,
                out_debris,
                (z * (h - 2 * margin) + r - margin) * ww,
                zs,
            )
        if n_cur == 0:
            break  # the rows below saw this row as it is now
        prev, cur, n_prev = cur, prev, n_cur


@nb.njit(cache=True, nogil=True, parallel=True)
def finish(
    new: tuple,
    old: tuple,
    src_idx: np.ndarray,
    deb64: np.ndarray,
    shape: tuple,
    n_mot: int,
    n_zm: int,
    ncol: int,
    threshold: float,
    n_neighbours: int,
    mode: int,
    margin: int,
    out_colour: np.ndarray,
    out_depth: np.ndarray,
    out_debris: np.ndarray,
    write_out: bool,
    track: bool,
    stats: np.ndarray,
    same_out: np.ndarray,
    interior: np.ndarray,
    table: bool,
    bands: int,
    snap: np.ndarray,
    band_stats: np.ndarray,
    zs: float = 1.0,
) -> None:
    """Second pass after :func:`scatter_bands`: debris arm, expansion and display copy.

    A pixel is only written when this scan reaches it (the debris arm, or an
    expansion that reads neighbours but writes the pixel itself), so each row is
    final once scanned (and copied to the display then, while cached, when
    ``write_out``).

    **Bands.**  The scan is sequential in principle: an expansion can qualify the
    debris pixel right of it and the one below, through the rows of the whole
    map.  The map's rows (``z H + r``) are split into ``bands`` bands that are
    scanned in parallel, each but the first leaving its top row alone and taking
    that row as the scatter left it (its pixels debris where they were).  Then,
    band by band, the top row is scanned with the true row above it, and the
    band's rows below are scanned again only where that changes something: a
    debris pixel whose left or upper neighbour was expanded by the fix-up (or,
    in the top row, by the scan), reading its right and lower neighbours' debris
    flags as the scatter left them (``snap``), as the sequential scan does.  The
    fix-up stops at the first row it changes nothing in.  Expansions only add
    galpixels, so a pixel the band expanded is expanded by the fix-up too and
    every field it wrote is written again; a debris-arm pixel that stays one
    holds the same.  Any band count gives the one-band result bit for bit.

    Parameters
    ----------
    new, old : tuple
        New map (changed in place) and old map, as :func:`planes`.
    src_idx : ndarray, shape (N,), int32
        Origins recorded by the first sweep.
    deb64 : ndarray, shape (N // 8,), uint64
        The new map's debris plane seen as words (:func:`debris_words`): eight
        galpixels in a row are skipped with one test.
    shape : tuple
        (Z, H, W).
    n_mot, n_zm, ncol : int
        The map's motion, z-motion and colour-derivative planes (an expansion
        replicates them all).
    threshold, n_neighbours, mode, margin
        As :func:`second_sweep`.
    out_colour, out_depth, out_debris : ndarray
        Flattened outputs, (Z R C 3,), (Z R C,), (Z R C,); written when ``write_out``.
    track : bool
        Whether the first sweep recorded origins (the debris arm then stores -1).
    stats : ndarray, shape (7,), int64
    same_out : ndarray, shape (N,), uint8
        :func:`scatter_bands`'s record of pixels the two maps will agree on;
        cleared at every pixel this pass writes (nothing landed there).
    interior : ndarray, shape (N,), uint8
        :func:`poisson_interiors` of ``old``, read when ``table`` (and ``threshold >= 0``).
    table : bool
        Read the origins' Poisson tests from ``interior`` rather than testing each
        origin on the spot (same result; the table pays off from about one debris
        pixel in a hundred and twenty-eight, see :data:`TABLE_FROM`).
    bands : int
        Number of bands, 1 to ``Z H``.
    snap : ndarray, shape (N,), uint8
        Scratch for the scatter's debris flags (unused, may be empty, with one band).
    band_stats : ndarray, shape (bands, 4), int64
        Out: per band expanded, debris left, rows fixed up and pixels scanned again.
    zs : float
        Depth unit of the display copy (2^-fz).
    """
    nz, h, w = shape
    rows = nz * h
    band_stats[:] = 0
    # a parallel loop takes arrays, not tuples of them: unpacked here, packed in it
    (c0, c1, c2), dep, (f0, f1), mot, zm, dc, deb, obj = new
    m0, m1, m2, m3, m4, m5 = mot
    z0, z1, z2 = zm
    d0, d1, d2, d3 = dc
    (o0, o1, o2), o_dep, o_deb, o_obj = old[0], old[1], old[6], old[7]
    for b in nb.prange(bands):
        lo, hi = b * rows // bands, (b + 1) * rows // bands
        if b > 0:  # the top row is left to the fix-up, as the scatter left it
            for c in range(w):
                snap[lo * w + c] = deb[lo * w + c]
            lo += 1
        _finish_rows(
            ((c0, c1, c2), dep, (f0, f1), (m0, m1, m2, m3, m4, m5), (z0, z1, z2),
             (d0, d1, d2, d3), deb, obj),
            (o0, o1, o2, o_dep, o_deb, o_obj), src_idx, deb64, snap if b > 0 else snap[:0],
            shape, lo, hi, n_mot, n_zm, ncol, threshold, n_neighbours, mode, track, same_out,
            interior, table, band_stats[b], margin, out_colour, out_depth, out_debris,
            write_out, zs,
        )
    for b in range(1, bands):  # in order: a fix-up reads the row above it as final
        _fix_rows(
            new, (o0, o1, o2, o_dep, o_deb, o_obj), src_idx, snap, shape, b * rows // bands,
            (b + 1) * rows // bands, n_mot, n_zm, ncol, threshold, n_neighbours, mode, track,
            same_out, interior, table, band_stats[b], margin, out_colour, out_depth,
            out_debris, write_out, zs,
        )
    for b in range(bands):
        stats[5] += band_stats[b, 0]
        stats[6] += band_stats[b, 1]


def reach_of(vy: int, ay: int, jy: int, fm: int) -> int:
    """Bound on the rows a galpixel with ``|vy|``, ``|ay|``, ``|jy|`` moves in a refresh.

    Motion in units of 2^-fm px/refresh^n.

    One refresh moves ``v + a/2 (+ j/6)`` rounded, at most ``|v| + |a| + |j|``;
    the fraction and both roundings add under two rows.
    """
    return int((int(vy) + int(ay) + int(jy)) >> fm) + 2


def map_reach(motion: np.ndarray, fm: int) -> int:
    """:func:`reach_of` of a whole map's motion planes ``(2n, Z, H, W)`` int32."""
    if motion.shape[0] == 0:
        return 2
    m = [max(int(motion[k].max()), -int(motion[k].min())) for k in range(1, motion.shape[0], 2)]
    m += [0] * (3 - len(m))
    return reach_of(m[0], m[1], m[2], fm)
