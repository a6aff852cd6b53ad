"""The banded scatter of one refresh: the galpixel arm of :mod:`.propagate` on all threads.

:func:`scatter_bands` splits the old map's rows into bands, one per thread, and
writes each galpixel where it lands (the z-test: nearest wins); galpixels known
static are left in place, checked :data:`CHUNK` pixels at a time.  It does what
:func:`service.galilean.propagate.sweep`'s galpixel arm does, bit for bit
(tests/galilean/test_gal_speed_equivalence.py); the debris arm and the expansion
follow in :func:`service.galilean.finish.finish`.  :func:`scatter_bands_plain` is
the same body with the still-galpixel bookkeeping compiled out.  Kernels take a map
as :func:`service.galilean.propagate.planes`.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from service.galilean.poisson_table import interior_row
from service.galilean.propagate import step, u64
from service.numba_subroutine import subroutine


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
def _move_colour(o_col: tuple, o_dc: tuple, n_col: tuple, n_dc: tuple, p: np.uint64,
                 q: np.uint64) -> None:
    """Old galpixel ``p``'s colour one refresh on, and its colour derivatives, into new pixel ``q``.

    The colour-motion step of :func:`service.galilean.propagate.sweep` (``dA``,
    ``dB``, ``dC``, ``d2A``), the same float arithmetic; written once for both
    ways step 3 copies (winner by winner and run by run), inlined into each loop.
    """
    da, db, dc, d2a = o_dc[0][p], o_dc[1][p], o_dc[2][p], o_dc[3][p]
    sa = da + 0.5 * d2a
    n_col[0][q] = o_col[0][p] + (sa + db)
    n_col[1][q] = o_col[1][p] + (sa - dc)
    n_col[2][q] = o_col[2][p] + (sa - db + dc)
    n_dc[0][q] = da + d2a
    n_dc[1][q] = db
    n_dc[2][q] = dc
    n_dc[3][q] = d2a


@nb.njit(cache=True, inline="always")
def _all_set(flags: np.ndarray, a: int, b: int) -> bool:
    """Whether ``flags[a:b]`` (uint8) are all non-zero."""
    every = np.uint8(1)
    for k in range(a, b):
        every &= flags[u64(k)]
    return every != 0


@nb.njit(cache=True, inline="always")
def _end_run(
    run_i: np.ndarray,
    run_q: np.ndarray,
    run_n: np.ndarray,
    runs: int,
    wins: int,
    ri: int,
    rq: int,
    rn: int,
    gather: bool,
) -> tuple:
    """Close the open run of ``rn`` winners, if any: ``(runs, wins)`` counted on.

    Stored unless the batch is copied winner by winner (whose z-test counts and
    lists its winners one by one).
    """
    if rn == 0:
        return runs, wins
    if not gather:
        run_i[runs], run_q[runs], run_n[runs] = ri, rq, rn
        wins += rn
    return runs + 1, wins


#: Pixels :func:`scatter_bands` checks at once for galpixels known static.
CHUNK = 32


#: Pixels per batch of rows :func:`scatter_bands` advances before it copies.
BATCH = 4096

#: Mean winners per run below which :func:`scatter_bands` copies the next batch
#: winner by winner rather than run by run (see its ``gather_run``).
GATHER_RUN = 5.0


@subroutine(error_model="numpy")
def _copy_batch(
    gather: bool,
    wins: int,
    runs: int,
    b0: int,
    win_i: np.ndarray,
    win_q: np.ndarray,
    run_i: np.ndarray,
    run_q: np.ndarray,
    run_n: np.ndarray,
    ncol: int,
    order: int,
    old: tuple,
    new: tuple,
    vxb: np.ndarray,
    vyb: np.ndarray,
    axb: np.ndarray,
    ayb: np.ndarray,
    mvy: int,
    may: int,
    mjy: int,
) -> tuple:
    """Step 3 of a batch: the planes the z-test left, plane by plane; ``(mvy, may, mjy)`` on.

    Run by run (``run_i``, ``run_q``, ``run_n``: ``runs`` of them), or, where runs are
    short (``gather``), winner by winner (``win_i``, ``win_q``: ``wins``): one long
    loop per plane either way (a loop per run and plane costs more than the run's
    galpixels).  The same in both kernels, so compiled once for both.
    """
    o_col, o_dep, o_frac, o_mot, o_zm, o_dc, o_deb, o_obj = old
    n_col, n_dep, n_frac, n_mot, n_zm, n_dc, n_deb, n_obj = new
    if gather:
        if ncol == 4:
            for k in range(wins):
                _move_colour(o_col, o_dc, n_col, n_dc,
                             u64(b0 + win_i[k]), u64(win_q[k]))
        else:
            for k in range(wins):
                p, q = u64(b0 + win_i[k]), u64(win_q[k])
                n_col[0][q] = o_col[0][p]
                n_col[1][q] = o_col[1][p]
                n_col[2][q] = o_col[2][p]
        if order >= 1:
            for k in range(wins):
                b, q = u64(win_i[k]), u64(win_q[k])
                n_mot[0][q] = vxb[b]
                n_mot[1][q] = vyb[b]
                mvy = max(mvy, abs(np.int64(vyb[b])))
        if order >= 2:
            for k in range(wins):
                b, q = u64(win_i[k]), u64(win_q[k])
                n_mot[2][q] = axb[b]
                n_mot[3][q] = ayb[b]
                may = max(may, abs(np.int64(ayb[b])))
        if order == 3:
            for k in range(wins):
                p, q = u64(b0 + win_i[k]), u64(win_q[k])
                n_mot[4][q] = o_mot[4][p]
                n_mot[5][q] = o_mot[5][p]
                mjy = max(mjy, abs(np.int64(o_mot[5][p])))
        if order == 1:
            for k in range(wins):
                n_zm[0][u64(win_q[k])] = o_zm[0][u64(b0 + win_i[k])]
        elif order == 2:
            for k in range(wins):
                p, q = u64(b0 + win_i[k]), u64(win_q[k])
                n_zm[0][q] = o_zm[0][p] + o_zm[1][p]
                n_zm[1][q] = o_zm[1][p]
        elif order == 3:
            for k in range(wins):
                p, q = u64(b0 + win_i[k]), u64(win_q[k])
                z0, z1, z2 = o_zm[0][p], o_zm[1][p], o_zm[2][p]
                n_zm[0][q] = z0 + z1 + ((np.int64(z2) + 1) >> 1)
                n_zm[1][q] = z1 + z2
                n_zm[2][q] = z2
    else:
        for k in range(runs):
            i0, q0, m = run_i[k], run_q[k], run_n[k]
            s0 = b0 + i0
            if ncol == 4:
                for j in range(m):
                    _move_colour(o_col, o_dc, n_col, n_dc, u64(s0 + j), u64(q0 + j))
            else:
                for j in range(m):
                    p, q = u64(s0 + j), u64(q0 + j)
                    n_col[0][q] = o_col[0][p]
                    n_col[1][q] = o_col[1][p]
                    n_col[2][q] = o_col[2][p]
            if order >= 1:
                for j in range(m):
                    b, q = u64(i0 + j), u64(q0 + j)
                    n_mot[0][q] = vxb[b]
                    n_mot[1][q] = vyb[b]
                    mvy = max(mvy, abs(np.int64(vyb[b])))
            if order >= 2:
                for j in range(m):
                    b, q = u64(i0 + j), u64(q0 + j)
                    n_mot[2][q] = axb[b]
                    n_mot[3][q] = ayb[b]
                    may = max(may, abs(np.int64(ayb[b])))
            if order == 3:
                for j in range(m):
                    p, q = u64(s0 + j), u64(q0 + j)
                    n_mot[4][q] = o_mot[4][p]
                    n_mot[5][q] = o_mot[5][p]
                    mjy = max(mjy, abs(np.int64(o_mot[5][p])))
            if order == 1:
                for j in range(m):
                    n_zm[0][u64(q0 + j)] = o_zm[0][u64(s0 + j)]
            elif order == 2:
                for j in range(m):
                    p, q = u64(s0 + j), u64(q0 + j)
                    n_zm[0][q] = o_zm[0][p] + o_zm[1][p]
                    n_zm[1][q] = o_zm[1][p]
            elif order == 3:
                for j in range(m):
                    p, q = u64(s0 + j), u64(q0 + j)
                    z0, z1, z2 = o_zm[0][p], o_zm[1][p], o_zm[2][p]
                    n_zm[0][q] = z0 + z1 + ((np.int64(z2) + 1) >> 1)
                    n_zm[1][q] = z1 + z2
                    n_zm[2][q] = z2
    return mvy, may, mjy


@subroutine(constants=("bookkeeping",), error_model="numpy")
def _scatter_band(
    band: int,
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
    interior: np.ndarray,
    threshold: float,
    table: bool,
    gather_run: float,
    buf: tuple,
    bookkeeping: bool,
) -> None:
    """Band ``band`` of :func:`scatter_bands` (``bookkeeping``) or :func:`scatter_bands_plain`.

    The kernels' parameters (see :func:`scatter_bands`), and:

    Parameters
    ----------
    band : int
        The band this call does (its new rows, its row of ``stats``,
        ``reach_out`` and of each batch buffer).
    buf : tuple
        The batch buffers (:func:`batch_buffers`), each shape (bands, size).
    bookkeeping : bool
        A constant (``Literal[bool]``: the kernels pass ``True`` or ``False``), so
        numba compiles a version without the still-galpixel branches and stores
        for :func:`scatter_bands_plain` (with them, the first refresh after every
        change was 15-20 % slower).

    Notes
    -----
    A function of its own, called from each kernel's ``prange`` loop, rather than
    the loop's body: numba compiles a ``prange`` body twice over (the kernel, then
    the body again as a gufunc of its own), so the body as a plain function
    compiles in about half the CPU (docs/compile-time.md, session 8).  Without
    reference counting, because in a plain function every array argument carries a
    reference count, and each view or array handed to an inlined helper (here per
    batch, pixel and run) would cost an atomic increment and decrement; in a gufunc
    those fold away.  Without reference counting a function may not allocate, so
    the kernels allocate the buffers and pass them; it runs within 1-2 % of the
    gufunc body.  A :func:`~service.numba_subroutine.subroutine`: its code is
    optimised and emitted only inside the two kernels (session 9).
    """
    nz, h, w = shape
    o_col, o_dep, o_frac, o_mot, o_zm, o_dc, o_deb, o_obj = old
    n_col, n_dep, n_frac, n_mot, n_zm, n_dc, n_deb, n_obj = new
    k0 = np.int64(0)
    size = buf[0].shape[1]
    rows = size // w
    lo, hi = band * h // bands, (band + 1) * h // bands
    r_lo, r_hi = max(0, lo - reach), min(h, hi + reach)
    # this band's row of each batch buffer, in :func:`batch_buffers`' order
    qb = buf[0][band]
    db = buf[1][band]
    fxb = buf[2][band]
    fyb = buf[3][band]
    vxb = buf[4][band]
    vyb = buf[5][band]
    axb = buf[6][band]
    ayb = buf[7][band]
    run_i = buf[8][band]
    run_q = buf[9][band]
    run_n = buf[10][band]
    win_i = buf[11][band]
    win_q = buf[12][band]
    sb = buf[13][band]
    for k in range(size):  # zeroed here: np.zeros would be a parallel pass of its own
        sb[k] = 0
    n_prop = n_clash = n_drop = np.int64(0)
    mvy = may = mjy = np.int64(0)
    # how step 3 copies the batch: winner by winner (True) or run by run
    gather = gather_run == np.inf
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
                            p, i = u64(p0 + c), u64(i0 + c)
                            deb = o_deb[p]  # every load before the first store
                            qr, qc, fx, fy, d = step(
                                r, c, o_frac[0][p], o_frac[1][p], o_dep[p],
                                k0, k0, k0, k0, k0, k0, k0, k0, k0, 0, fp, fm,
                            )[:5]  # fmt: skip
                            qb[i] = _landing(qr, qc, deb, z, h, w)
                            fxb[i], fyb[i], db[i] = fx, fy, d
                            if bookkeeping:
                                sb[i] = qb[i] == p0 + c
                    elif order == 1:
                        for c in range(ca, cb):
                            p, i = u64(p0 + c), u64(i0 + c)
                            vx, vy = np.int64(o_mot[0][p]), np.int64(o_mot[1][p])
                            vz, deb = np.int64(o_zm[0][p]), o_deb[p]
                            qr, qc, fx, fy, d, vx1, vy1 = step(
                                r, c, o_frac[0][p], o_frac[1][p], o_dep[p],
                                vx, vy, k0, k0, k0, k0, vz, k0, k0, 1, fp, fm,
                            )[:7]  # fmt: skip
                            qb[i] = _landing(qr, qc, deb, z, h, w)
                            fxb[i], fyb[i], db[i], vxb[i], vyb[i] = fx, fy, d, vx1, vy1
                            if bookkeeping:
                                sb[i] = (qb[i] == p0 + c) & ((vx | vy | vz) == 0)
                    elif order == 2:
                        for c in range(ca, cb):
                            p, i = u64(p0 + c), u64(i0 + c)
                            vx, vy = np.int64(o_mot[0][p]), np.int64(o_mot[1][p])
                            ax, ay = np.int64(o_mot[2][p]), np.int64(o_mot[3][p])
                            vz, az = np.int64(o_zm[0][p]), np.int64(o_zm[1][p])
                            deb = o_deb[p]
                            qr, qc, fx, fy, d, vx1, vy1, ax1, ay1 = step(
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
                            p, i = u64(p0 + c), u64(i0 + c)
                            vx, vy = np.int64(o_mot[0][p]), np.int64(o_mot[1][p])
                            ax, ay = np.int64(o_mot[2][p]), np.int64(o_mot[3][p])
                            jx, jy = np.int64(o_mot[4][p]), np.int64(o_mot[5][p])
                            vz, az = np.int64(o_zm[0][p]), np.int64(o_zm[1][p])
                            jz = np.int64(o_zm[2][p])
                            deb = o_deb[p]
                            qr, qc, fx, fy, d, vx1, vy1, ax1, ay1 = step(
                                r, c, o_frac[0][p], o_frac[1][p], o_dep[p],
                                vx, vy, ax, ay, jx, jy, vz, az, jz, 3, fp, fm,
                            )[:9]  # fmt: skip
                            qb[i] = _landing(qr, qc, deb, z, h, w)
                            fxb[i], fyb[i], db[i] = fx, fy, d
                            vxb[i], vyb[i], axb[i], ayb[i] = vx1, vy1, ax1, ay1
                            if bookkeeping:
                                still = (vx | vy | ax | ay | jx | jy | vz | az | jz) == 0
                                sb[i] = (qb[i] == p0 + c) & still
            # the Poisson tests of the band's own old rows in the batch, while
            # they are in cache (what poisson_interiors would compute)
            if table:
                for r in range(max(r0, lo), min(r0 + nr, hi)):
                    interior_row(o_dep, o_deb, np.int64(zb + r * w), np.int64(r), h, w,
                                 threshold, interior)
            # 2. z-test in scan order; the open run is kept in registers
            runs = wins = 0
            ri, rq, rn = np.int64(-2), np.int64(0), np.int64(0)  # no run open
            skip = 0
            for i in range(nr * w):
                if skip:
                    skip -= 1
                    continue
                p = u64(b0 + i)
                if (bookkeeping and use_same and (i & (CHUNK - 1)) == 0
                        and own_lo <= i and i + CHUNK <= own_hi
                        and _all_set(same_in, b0 + i, b0 + i + CHUNK)
                        and _all_set(n_deb, b0 + i, b0 + i + CHUNK)):
                    # a chunk of still galpixels on their own pixels, nothing
                    # landed there yet: each is the first to land on its own
                    # pixel (as below), all at once
                    for j in range(b0 + i, b0 + i + CHUNK):
                        n_deb[u64(j)] = 0
                    if record:
                        for j in range(b0 + i, b0 + i + CHUNK):
                            same_out[u64(j)] = 1
                    n_prop += CHUNK
                    skip = CHUNK - 1
                    continue
                known = bookkeeping and use_same and same_in[p] != 0  # still, new holds it
                q = b0 + i if known else qb[i]
                own = own_lo <= i < own_hi
                if q < 0 or q < q_lo or q >= q_hi:
                    if q != -1 and own:
                        n_prop += 1
                        n_drop += q == -2
                    continue
                n_prop += own
                fresh = n_deb[u64(q)] != 0
                if known and fresh:
                    # the first to land on its own pixel, which holds it already
                    n_deb[u64(q)] = 0
                    if bookkeeping and record:
                        same_out[u64(q)] = 1
                    continue
                d = np.int64(o_dep[p]) if known else db[i]
                if not fresh:
                    n_clash += 1
                    if d >= n_dep[u64(q)]:
                        continue
                n_dep[u64(q)] = d
                n_deb[u64(q)] = 0
                if known:  # step 1 skipped it: its batch entries for the copy
                    _unmoved(p, u64(i), o_frac, fxb, fyb, vxb, vyb, axb, ayb)
                # the fraction, object and origin planes here, one galpixel at a
                # time, the others by runs in step 3: a loop per plane and run
                # costs more than these stores (scatter 5 % less CPU on a head
                # turn, 9-11 % on the 100k scene; moving the motion planes here
                # too lost it again, the colour planes as well cost 40 %)
                n_frac[0][u64(q)] = fxb[u64(i)]
                n_frac[1][u64(q)] = fyb[u64(i)]
                n_obj[u64(q)] = o_obj[p]
                if track:
                    src_idx[u64(q)] = b0 + i - zb
                if bookkeeping and record:
                    still = known or (sb[i] != 0 and _no_colour_motion(o_dc, ncol, p))
                    same_out[u64(q)] = still
                if gather:
                    win_i[wins], win_q[wins] = i, q
                    wins += 1
                # a run goes on while winners follow each other in the scan and
                # land side by side; it is closed at the first that does not
                # (nothing to do on the paths that win nothing)
                if i == ri + rn and q == rq + rn:
                    rn += 1
                else:
                    runs, wins = _end_run(run_i, run_q, run_n, runs, wins, ri, rq, rn, gather)
                    ri, rq, rn = i, q, 1
            runs, wins = _end_run(run_i, run_q, run_n, runs, wins, ri, rq, rn, gather)
            # 3. copy the other planes (:func:`_copy_batch`)
            mvy, may, mjy = _copy_batch(gather, wins, runs, b0, win_i, win_q, run_i, run_q, run_n,
                                        ncol, order, old, new, vxb, vyb, axb, ayb, mvy, may, mjy)
            # the next batch (rows next to these, much alike) is copied winner
            # by winner if this one's runs were short
            gather = wins < gather_run * runs
    stats[band, 0] += n_prop
    stats[band, 1] += n_clash
    stats[band, 2] += n_drop
    reach_out[band, 0] = mvy
    reach_out[band, 1] = may
    reach_out[band, 2] = mjy


def batch_buffers(bands: int, shape: tuple) -> tuple:
    """The batch buffers the scatter kernels write, each shape (bands, size).

    ``size`` is a batch of whole rows, about :data:`BATCH` pixels of a map of
    ``shape`` (Z, H, W): 1 to H rows.  Made by the caller (a stage keeps its own),
    so that the kernels allocate nothing and compile without reference counting.
    """
    _, h, w = shape
    size = max(1, min(h, BATCH // w)) * w
    i64, i32, i16 = ((bands, size), np.int64), ((bands, size), np.int32), ((bands, size), np.int16)
    return (
        np.empty(*i64),  # landing pixel; -1 debris, -2 off the map
        np.empty(*i64),  # new depth
        np.empty(*i16), np.empty(*i16),  # new fraction
        np.empty(*i32), np.empty(*i32), np.empty(*i32), np.empty(*i32),  # new motion
        np.empty(*i64),  # first batch index of a run
        np.empty(*i64),  # its landing pixel
        np.empty(*i64),  # its length
        np.empty(*i64),  # every winner's batch index (gathering)
        np.empty(*i64),  # and its new pixel
        np.empty((bands, size), np.uint8),  # 1: no motion, lands on its own pixel
    )


@nb.njit(cache=True, nogil=True, parallel=True, error_model="numpy", _nrt=False)
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
    interior: np.ndarray,
    threshold: float,
    table: bool,
    gather_run: float,
    buf: tuple,
) -> None:
    """First sweep without its debris arm or cache, the new rows in parallel bands.

    Bit for bit the result of :func:`sweep` without cache, the debris arm left to
    :func:`finish`.  Maps are :func:`planes`; ``new``'s debris all 1 on entry.

    Each batch of old rows (about :data:`BATCH` pixels) is done in three steps:

    1. *advance* (plain element-wise loops, SIMD): every galpixel's landing pixel,
       new fraction, motion and depth into batch buffers;
    2. *z-test* (the only sequential part, in scan order like the paper's scan):
       each landing galpixel against the new map's debris flag and depth, which it
       writes when it wins, with its fraction, object and origin; winners from
       consecutive old pixels that land on consecutive new pixels are gathered
       into runs;
    3. *copy*: the other fields, plane by plane, run by run (contiguous), or
       winner by winner where runs are short (``gather_run``).

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
    interior : ndarray, shape (N,), uint8
        Out, when ``table``: :func:`service.galilean.poisson_table.poisson_interiors`
        of ``old`` (each band its own rows, right after advancing them, while
        their depths and debris flags are in cache; no parallel pass of its own).
    threshold : float
        The Poisson threshold of ``interior``, in fixed-point depth units.
    table : bool
        Whether to compute ``interior``.
    gather_run : float
        How step 3 copies a batch: winner by winner (one loop per plane over the
        batch's winners) when the band's previous batch had fewer than
        ``gather_run`` winners per run, else run by run; the first batch of a band
        run by run, unless ``gather_run`` is inf (always winner by winner; 0:
        always run by run).  Either way gives the same map, bit for bit.
    buf : tuple
        Scratch: :func:`batch_buffers` for ``bands`` and ``shape`` (overwritten).

    Notes
    -----
    *No reference counting* (``_nrt=False``): the kernel allocates nothing, its
    caller makes ``buf``.  Its own code, which unpacks and repacks the maps'
    tuples for the parallel loop, then carries no reference-count pair per array
    (400 calls, 4,800 ``extractvalue``): its compile took 0.9x the CPU.

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
    # a parallel loop takes tuples one level deep: the maps' planes go in one by one
    o0, o1, o2, o3, o4, o5, o6, o7 = old
    n0, n1, n2, n3, n4, n5, n6, n7 = new
    for band in nb.prange(bands):
        _scatter_band(
            np.int64(band), (o0, o1, o2, o3, o4, o5, o6, o7), (n0, n1, n2, n3, n4, n5, n6, n7),
            src_idx, shape, order, fp, fm, ncol, track, reach, bands, stats, reach_out, same_in,
            same_out, use_same, record, interior, threshold, table, gather_run, buf, True,
        )


@nb.njit(cache=True, nogil=True, parallel=True, error_model="numpy", _nrt=False)
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
    interior: np.ndarray,
    threshold: float,
    table: bool,
    gather_run: float,
    buf: tuple,
) -> None:
    """:func:`scatter_bands` without its still-galpixel bookkeeping (compiled out).

    What a refresh runs when it neither uses nor records ``same``: ``use_same`` and
    ``record`` are ignored (taken as False).
    """
    # a parallel loop takes tuples one level deep: the maps' planes go in one by one
    o0, o1, o2, o3, o4, o5, o6, o7 = old
    n0, n1, n2, n3, n4, n5, n6, n7 = new
    for band in nb.prange(bands):
        _scatter_band(
            np.int64(band), (o0, o1, o2, o3, o4, o5, o6, o7), (n0, n1, n2, n3, n4, n5, n6, n7),
            src_idx, shape, order, fp, fm, ncol, track, reach, bands, stats, reach_out, same_in,
            same_out, use_same, record, interior, threshold, table, gather_run, buf, False,
        )


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
