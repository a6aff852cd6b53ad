"""One refresh of propagation: the one-pass scatter of section 3.1.

The new map starts with every debris flag set and nothing else cleared.  One scan
of the old map runs, for each old pixel, the paper's parallel arms:

* the **debris arm** copies the old pixel's colour, depth and object to the same
  place in the new map if that place is still debris (no motion, flag kept);
* the **galpixel arm** (disabled when the old pixel is itself debris) advances the
  galpixel one refresh (:func:`step`, the one place every kernel takes the step
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
takes them as :func:`planes` (each field's planes flat, (N,), N = Z H W, in tuples
of fixed length) and addresses every galpixel by one flat index, which numba
compiles to much cheaper address arithmetic than four-dimensional indexing.

This module keeps the straightforward reference (:func:`sweep`,
:func:`second_sweep`), :func:`scatter` (the stage's scatter when the cache is on)
and what every refresh kernel shares: :func:`step`, :func:`planes`, :func:`u64`.
The stage's fast path lives beside it, one module per pass:
:mod:`.scatter_bands` (the galpixel arm on all threads), :mod:`.finish` (debris
arm, expansion, display copy), :mod:`.show` (the display window) and
:mod:`.poisson_table` (every pixel's Poisson flag at once).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from service.galilean.fixed_point import Z_EMPTY, advance, pixel_of
from service.galilean.poisson import expand_pixel
from service.numba_subroutine import subroutine

#: Index of each counter in the ``stats`` array the kernels fill.
STAT_NAMES = ("propagated", "clashes", "dropped", "cached", "promoted", "expanded", "debris")
STAT = {name: i for i, name in enumerate(STAT_NAMES)}


@nb.njit(cache=True, inline="always", error_model="numpy")
def step(
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


@nb.njit(cache=True, error_model="numpy")
def sweep(old: tuple, new: tuple, cold: tuple, cnew: tuple, cache_on: bool, src_idx: np.ndarray,
          shape: tuple, order: int, fp: int, fm: int, track: bool, stats: np.ndarray) -> None:
    """First sweep: debris arm and galpixel arm, then cache propagation and promotion.

    Parameters
    ----------
    old, new : tuple of arrays
        Old and new main maps as :func:`planes`; ``new``'s debris must be all 1
        on entry.
    cold, cnew : tuple of arrays
        Old and new obscuration-cache maps as :func:`planes` (``cnew`` debris all
        1); ignored unless ``cache_on``.
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

    The maps are :func:`planes`, as the stage's kernels take them, so the cache's
    kernels (:func:`_cache_pass` and the spills) are the ones :func:`scatter`
    calls, compiled once for both.
    """
    nz, h, w = shape
    o_col, o_dep, o_frac, o_mot, o_zm, o_dc, o_deb, o_obj = old
    n_col, n_dep, n_frac, n_mot, n_zm, n_dc, n_deb, n_obj = new
    # The advance step is step (scalars only, inlined): passing arrays to helpers
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
                    qr, qc, fx, fy, d, vx, vy, ax, ay, vz, az = step(
                        r, c, o_frac[0][p], o_frac[1][p], o_dep[p],
                        vx, vy, ax, ay, jx, jy, vz, az, jz, order, fp, fm,
                    )  # fmt: skip
                # debris arm (own place free): for an old galpixel that moved away,
                # and for old debris, which keeps the colour it last showed
                if n_deb[p] == 1 and (not galpixel or qr != r or qc != c):
                    n_col[0][p] = o_col[0][p]
                    n_col[1][p] = o_col[1][p]
                    n_col[2][p] = o_col[2][p]
                    n_dep[p] = o_dep[p]
                    n_obj[p] = o_obj[p]
                    if track:
                        src_idx[p] = -1
                if not galpixel:
                    continue
                stats[0] += 1
                if qr < 0 or qc < 0 or qr >= h or qc >= w:
                    stats[2] += 1
                    continue
                q = (z * h + qr) * w + qc
                mot = (vx, vy, ax, ay, vz, az)
                if n_deb[q] == 0:
                    stats[1] += 1
                    if d >= n_dep[q]:
                        if cache_on:
                            _spill_incoming(old, p, cnew, q, fx, fy, d, mot, order, stats)
                        continue
                    if cache_on:
                        _spill_resident(new, cnew, q, stats)
                _advance_into(old, p, new, q, fx, fy, d, mot, order)
                if track:
                    src_idx[q] = r * w + c
        if cache_on:
            _cache_pass(cold, new, cnew, z, h, w, order, fp, fm, stats, src_idx)


@nb.njit(cache=True)
def second_sweep(new: tuple, src_idx: np.ndarray, old_depth: np.ndarray, old_debris: np.ndarray,
                 threshold: float, n_neighbours: int, mode: int, margin: int,
                 out_colour: np.ndarray, out_depth: np.ndarray, out_debris: np.ndarray,
                 stats: np.ndarray, zs: float = 1.0) -> None:
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
# The stage runs ``scatter_bands`` (:mod:`.scatter_bands`; ``scatter`` below when
# the obscuration cache is on) and then ``finish`` (:mod:`.finish`); together they
# do what ``sweep`` + ``second_sweep`` do, bit for bit
# (tests/galilean/test_gal_speed_equivalence.py).  ``sweep`` and
# ``second_sweep`` stay as the straightforward reference.  The debris arm is
# deferred to ``finish`` (its result only survives where no galpixel landed, and,
# as in ``sweep``, only for old galpixels), which also does the expansion and the
# display copy of each row in one go.  Fast-path indices are unsigned (see ``u64``).


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

    Same parameters (the maps as :func:`planes`) and the same arithmetic,
    operation for operation.  Afterwards a new pixel whose debris flag is still
    set holds stale fields until :func:`finish` runs the debris arm there.  The
    stage's scatter when the obscuration cache is on.

    The maps as :func:`planes`: whole flat fields typed 'C' with 0-1 planes and
    'A' (staggered) or 'C' (a copied map) with more, and numba compiled the
    kernel, :func:`_cache_pass` and the spills once per combination (two in the
    warm-up, three more in the tests, 5-19 s of CPU each); 1-D planes in tuples
    of fixed length are one type for every order.

    Written for the machine: flat indices are unsigned (numba cannot prove a signed
    one non-negative and adds a negative-index wraparound to every access), and
    each galpixel is read whole into registers before anything is stored (stores
    to the new map would otherwise force reloads, and page-aligned planes alias
    the loads that follow them in the store buffer).


    The one kernel that still writes the advance step out rather than calling
    :func:`step`: through :func:`step` (order a run-time value, so every
    component's order test stays in the loop) it took 5-8 % more CPU time for
    G(1)-G(3) at 640x480, side by side.
    """
    nz, h, w = shape
    o_col, o_dep, o_frac, o_mot, o_zm, o_dc, o_deb, o_obj = old
    n_col, n_dep, n_frac, n_mot, n_zm, n_dc, n_deb, n_obj = new
    ncol = 4 if o_dc[0].shape[0] > 0 else 0
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
                x = (np.int64(c) << fp) + o_frac[0][p]
                y = y0 + o_frac[1][p]
                d = np.int64(o_dep[p])
                vx = vy = ax = ay = jx = jy = np.int64(0)
                if order == 1:
                    vx, vy = np.int64(o_mot[0][p]), np.int64(o_mot[1][p])
                    x += (vx + (1 << (sh - 1))) >> sh
                    y += (vy + (1 << (sh - 1))) >> sh
                elif order == 2:
                    vx, vy = np.int64(o_mot[0][p]), np.int64(o_mot[1][p])
                    ax, ay = np.int64(o_mot[2][p]), np.int64(o_mot[3][p])
                    x += (2 * vx + ax + (1 << sh)) >> (sh + 1)
                    y += (2 * vy + ay + (1 << sh)) >> (sh + 1)
                    vx += ax
                    vy += ay
                elif order == 3:
                    jx, jy = np.int64(o_mot[4][p]), np.int64(o_mot[5][p])
                    x, vx, ax = advance(
                        x, np.int64(o_mot[0][p]), np.int64(o_mot[2][p]), jx, 3, fp, fm
                    )
                    y, vy, ay = advance(
                        y, np.int64(o_mot[1][p]), np.int64(o_mot[3][p]), jy, 3, fp, fm
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
                c0, c1, c2 = o_col[0][p], o_col[1][p], o_col[2][p]
                ob = o_obj[p]
                if ncol == 4:
                    da, db, dc, d2a = o_dc[0][p], o_dc[1][p], o_dc[2][p], o_dc[3][p]
                    sa = da + 0.5 * d2a
                    n_col[0][q] = c0 + (sa + db)
                    n_col[1][q] = c1 + (sa - dc)
                    n_col[2][q] = c2 + (sa - db + dc)
                    n_dc[0][q] = da + d2a
                    n_dc[1][q] = db
                    n_dc[2][q] = dc
                    n_dc[3][q] = d2a
                else:
                    n_col[0][q] = c0
                    n_col[1][q] = c1
                    n_col[2][q] = c2
                n_dep[q] = d
                n_frac[0][q] = fx
                n_frac[1][q] = fy
                if order >= 1:
                    n_mot[0][q] = vx
                    n_mot[1][q] = vy
                    n_zm[0][q] = vz
                if order >= 2:
                    n_mot[2][q] = ax
                    n_mot[3][q] = ay
                    n_zm[1][q] = az
                if order >= 3:
                    n_mot[4][q] = jx
                    n_mot[5][q] = jy
                    n_zm[2][q] = z2
                n_deb[q] = 0
                n_obj[q] = ob
                if track:
                    src_idx[q] = r * w + c
        if cache_on:
            _cache_pass(cold, new, cnew, z, h, w, order, fp, fm, stats, src_idx)
    stats[0] += n_prop
    stats[1] += n_clash
    stats[2] += n_drop


# ------------------------------------------------ the sweeps' plane helpers
# For maps as :func:`planes` (``field[k][p]``; an absent plane is empty and never
# read), shared by the reference :func:`sweep` and the stage's :func:`scatter`:
# one compile of the cache's kernels serves both.


@nb.njit(cache=True, inline="always")
def _copy(src: tuple, p: int, dst: tuple, q: int) -> None:
    """Copy one galpixel, every field, from flat index ``p`` of ``src`` to ``q`` of ``dst``."""
    for k in range(3):
        dst[0][k][q] = src[0][k][p]
    dst[1][q] = src[1][p]
    dst[2][0][q] = src[2][0][p]
    dst[2][1][q] = src[2][1][p]
    for k in range(6):
        if src[3][k].shape[0] > 0:
            dst[3][k][q] = src[3][k][p]
    for k in range(3):
        if src[4][k].shape[0] > 0:
            dst[4][k][q] = src[4][k][p]
    for k in range(4):
        if src[5][k].shape[0] > 0:
            dst[5][k][q] = src[5][k][p]
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

    ``mot`` is ``(vx, vy, ax, ay, vz, az)`` after the step (from :func:`step`),
    ``depth`` the new depth, ``fx``, ``fy`` the new fraction.
    """
    s_col, s_mot, s_zm, s_dc = src[0], src[3], src[4], src[5]
    d_col, d_mot, d_zm, d_dc = dst[0], dst[3], dst[4], dst[5]
    d_col[0][q] = s_col[0][p]
    d_col[1][q] = s_col[1][p]
    d_col[2][q] = s_col[2][p]
    if s_dc[0].shape[0] > 0:
        da, db, dc, d2a = s_dc[0][p], s_dc[1][p], s_dc[2][p], s_dc[3][p]
        sa = da + 0.5 * d2a
        d_col[0][q] += sa + db
        d_col[1][q] += sa - dc
        d_col[2][q] += sa - db + dc
        d_dc[0][q] = da + d2a
        d_dc[1][q] = db
        d_dc[2][q] = dc
        d_dc[3][q] = d2a
    dst[1][q] = depth
    dst[2][0][q] = fx
    dst[2][1][q] = fy
    if order >= 1:
        d_mot[0][q] = mot[0]
        d_mot[1][q] = mot[1]
        d_zm[0][q] = mot[4]
    if order >= 2:
        d_mot[2][q] = mot[2]
        d_mot[3][q] = mot[3]
        d_zm[1][q] = mot[5]
    if order >= 3:
        d_mot[4][q] = s_mot[4][p]
        d_mot[5][q] = s_mot[5][p]
        d_zm[2][q] = s_zm[2][p]
    dst[6][q] = 0
    dst[7][q] = src[7][p]


@nb.njit(cache=True, inline="always")
def _zplanes(zm: tuple, p: int, order: int) -> tuple:
    """Galpixel ``p``'s z motion ``(vz, az, jz)`` as int64, 0 beyond ``order``."""
    z0 = np.int64(zm[0][p]) if order >= 1 else np.int64(0)
    z1 = np.int64(zm[1][p]) if order >= 2 else np.int64(0)
    z2 = np.int64(zm[2][p]) if order >= 3 else np.int64(0)
    return z0, z1, z2


@nb.njit(cache=True, inline="always")
def _motion_at(mot: tuple, zm: tuple, p: int, order: int) -> tuple:
    """Galpixel ``p``'s ``(vx, vy, ax, ay, jx, jy, vz, az, jz)`` as int64, 0 beyond ``order``."""
    z = np.int64(0)
    vx = np.int64(mot[0][p]) if order >= 1 else z
    vy = np.int64(mot[1][p]) if order >= 1 else z
    ax = np.int64(mot[2][p]) if order >= 2 else z
    ay = np.int64(mot[3][p]) if order >= 2 else z
    jx = np.int64(mot[4][p]) if order >= 3 else z
    jy = np.int64(mot[5][p]) if order >= 3 else z
    vz = np.int64(zm[0][p]) if order >= 1 else z
    az = np.int64(zm[1][p]) if order >= 2 else z
    jz = np.int64(zm[2][p]) if order >= 3 else z
    return vx, vy, ax, ay, jx, jy, vz, az, jz


@subroutine(nrt=True)
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


@subroutine(nrt=True)
def _spill_resident(new: tuple, cnew: tuple, q: int, stats: np.ndarray) -> None:
    """The galpixel about to be overwritten goes to the cache if nearer than the cache's entry."""
    if cnew[6][q] == 1 or new[1][q] < cnew[1][q]:
        _copy(new, q, cnew, q)
        stats[3] += 1


@subroutine(nrt=True)
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
            qr, qc, fx, fy, d, vx, vy, ax, ay, vz, az = step(
                r, c, cold[2][0][p], cold[2][1][p], cold[1][p],
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
def u64(i: int) -> np.uint64:
    """An index as unsigned: numba then skips its negative-index wraparound code."""
    return np.uint64(i)


