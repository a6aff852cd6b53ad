"""The second pass of one refresh: debris arm, expansion and display copy, in row bands.

After :func:`service.galilean.scatter_bands.scatter_bands` (or
:func:`service.galilean.propagate.scatter` with the obscuration cache on),
:func:`finish` visits the new map's rows in bands, one per thread: it copies old
galpixels into pixels still debris (the debris arm), expands debris inside an
expanding surface (:mod:`.poisson`) and copies the displayed rows out
(:func:`service.galilean.show.show_row`).  At each band's top row an exact fix-up
(:func:`_rows` with ``fix``) visits the pixels the band above changed.  Together with the
scatter it does what :func:`service.galilean.propagate.sweep` and
:func:`service.galilean.propagate.second_sweep` do, bit for bit.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from service.galilean.poisson_table import interior_at
from service.galilean.propagate import u64
from service.galilean.show import show_row
from service.numba_subroutine import subroutine


@nb.njit(cache=True, inline="always")
def _expanded_colour(
    c0: np.ndarray,
    c1: np.ndarray,
    c2: np.ndarray,
    dep: np.ndarray,
    p: np.uint64,
    q: np.uint64,
    mode: int,
    n: int,
    acc0: float,
    acc1: float,
    acc2: float,
    accd: float,
) -> None:
    """Write an expanded pixel ``p``'s colour and depth, each plane once.

    The mean of the ``n`` neighbours taken (``mode`` 1, sums ``acc*``, depth
    rounded half up) or the first of them, ``q`` (replication); one helper for
    the band scan and the fix-up.
    """
    if mode == 1:
        c0[p] = acc0 / n
        c1[p] = acc1 / n
        c2[p] = acc2 / n
        dep[p] = np.floor(accd / n + 0.5)
    else:
        c0[p] = c0[q]
        c1[p] = c1[q]
        c2[p] = c2[q]
        dep[p] = dep[q]


@subroutine()
def _rows(new: tuple, old: tuple, src_idx: np.ndarray, deb64: np.ndarray, snap: np.ndarray,
          shape: tuple, k0: int, k1: int, fix: bool, n_mot: int, n_zm: int, ncol: int,
          threshold: float, n_neighbours: int, mode: int, track: bool, same_out: np.ndarray,
          interior: np.ndarray, table: bool, counts: np.ndarray, margin: int,
          out_colour: np.ndarray, out_depth: np.ndarray, out_debris: np.ndarray, write_out: bool,
          zs: float, columns: np.ndarray) -> None:
    """:func:`finish`'s scan of a band's rows ``[k0, k1)`` (row ``k`` = ``z H + r``), or its fix-up.

    ``new`` is the new map as :func:`planes`, ``old`` the old map's colour planes,
    depth, debris and object planes; ``counts`` (4,) accumulates expanded, debris
    left, rows fixed and pixels redone; ``columns`` (2, W) int64 is the fix-up's
    scratch (it allocates nothing: no reference counting).  One loop for both, so that a pixel is
    decided and written by the same lines: inlined helpers taking the planes
    cost a reference-count pair per plane and call (docs/galilean.md, 2026-11-26,
    third session).  :func:`finish` passes ``fix`` as a typed ``np.bool_``, not a
    constant, so numba compiles one kernel for both (a constant compiled one
    ``Literal[bool]`` specialisation per value: 3 s of CPU more from a cold cache,
    for a scan no faster; docs/compile-time.md).

    **Scan** (``fix`` False): every debris pixel in scan order, eight galpixels
    skipped per test of ``deb64``; each row's debris flags are first copied to
    ``snap`` when it is not empty (for the fix-up).

    **Fix-up** (``fix`` True, see :func:`finish`): row ``k0`` (untouched by the
    band's scan) is scanned in full; in the rows below, up to ``k1``, only the
    debris pixels (as the scatter left them, ``snap``) whose left or upper
    neighbour this fix-up expanded are scanned again, until a row in which it
    expands nothing.  Right and lower neighbours' debris flags are read from
    ``snap``, as the one-band scan sees them; the counts are corrected for the
    pixels the band had done.
    """
    nz, h, w = shape
    # every plane in a local of its own, once: taking arrays out of tuples inside
    # the loop costs a reference-count pair each time (~1 us per expansion)
    (c0, c1, c2), dep, (f0, f1), mot, zm, dc, deb, obj = new
    m0, m1, m2, m3, m4, m5 = mot
    z0, z1, z2 = zm
    d0, d1, d2, d3 = dc
    o0, o1, o2, o_dep, o_deb, o_obj = old
    # the right and lower neighbours' debris flags: as the scatter left them
    # (``snap``) in the fix-up, else ``deb``; chosen at each read, so that the
    # scan's reads are of ``deb``, which its own writes keep in registers
    ww = w - 2 * margin
    keep = not fix and snap.size > 0
    expanded = left = 0
    n8 = 8 * deb64.size
    # fix-up: columns it expanded in the row above (ascending), and in this row
    prev, cur = columns[0], columns[1]
    n_prev = 0
    for k in range(k0, k1):
        z = k // h
        r = k - z * h
        zb = z * h * w
        base = k * w
        if keep:
            for c in range(w):
                snap[u64(base + c)] = deb[u64(base + c)]
        n_cur = i = 0
        c = np.int64(-1)
        chain = False  # the pixel just done was expanded: its right neighbour is due
        while True:
            # the next pixel due: every one in the scan and the fix-up's top row;
            # below it, one whose upper (``prev``) or left (``chain``) neighbour
            # the fix-up expanded
            if not fix or k == k0:
                c += 1
                if c >= w:
                    break
                p = u64(base + c)
                if not fix and (p & 7) == 0 and c + 8 <= w and p + 8 <= n8 and deb64[p >> 3] == 0:
                    c += 7  # eight galpixels: nothing to do
                    continue
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
            p = u64(base + c)
            if (snap[p] if fix else deb[p]) == 0:
                continue
            # what the band's scan did here: 0 nothing (the scan, the top row),
            # 1 expanded, 2 debris arm
            spec = 0 if not fix or k == k0 else (1 if deb[p] == 0 else 2)
            if fix:
                counts[3] += 1
            same_out[p] = 0
            near = (
                (c > 0 and deb[u64(base + c - 1)] == 0)
                or (c < w - 1 and (snap[u64(base + c + 1)] if fix else deb[u64(base + c + 1)]) == 0)
                or (r > 0 and deb[u64(base + c - w)] == 0)
                or (r < h - 1 and (snap[u64(base + c + w)] if fix else deb[u64(base + c + w)]) == 0)
            )
            # expansion (poisson.expand_pixel, same arithmetic)
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
                if not ok or (deb[u64(qi)] if kk < 2 or not fix else snap[u64(qi)]) == 1:
                    continue
                sq = np.int64(src_idx[u64(qi)])
                if sq < 0:
                    continue
                # Poisson test of the origin: from the table, or on the spot
                if table:
                    if interior[u64(zb + sq)] == 0:
                        continue
                elif not interior_at(o_dep, o_deb, zb, sq, h, w, threshold):
                    continue
                if first < 0:
                    first = qi
                n += 1
                acc0 += c0[u64(qi)]
                acc1 += c1[u64(qi)]
                acc2 += c2[u64(qi)]
                accd += np.float64(dep[u64(qi)])
            if first < 0:
                # debris arm (also for old debris: it keeps the colour it last
                # showed); in the fix-up a pixel the band expanded stays expanded
                # (the fix-up only adds galpixels), one it left as debris holds the same
                left += spec == 0
                if spec == 0:
                    c0[p] = o0[p]
                    c1[p] = o1[p]
                    c2[p] = o2[p]
                    dep[p] = o_dep[p]
                    obj[p] = o_obj[p]
                    if track:
                        src_idx[p] = -1
                continue
            q = u64(first)
            _expanded_colour(c0, c1, c2, dep, p, q, mode, n, acc0, acc1, acc2, accd)
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
            f0[p] = 0
            f1[p] = 0
            src_idx[p] = src_idx[q]
            expanded += spec != 1
            left -= spec == 2
            if fix:
                # taken as changed for the pixels right of and below it (not compared)
                cur[n_cur] = c
                n_cur += 1
                chain = True
        if write_out and margin <= r < h - margin:
            show_row(c0, c1, c2, dep, deb, base + margin, ww, out_colour, out_depth, out_debris,
                     (z * (h - 2 * margin) + r - margin) * ww, zs)
        if fix:
            counts[2] += 1
            if n_cur == 0:
                break  # the rows below saw this row as it is now
            prev, cur, n_prev = cur, prev, n_cur
    counts[0] += expanded
    counts[1] += left


@nb.njit(cache=True, nogil=True, parallel=True, _nrt=False)
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
    columns: np.ndarray,
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
    columns : ndarray, shape (bands, 2, W), int64
        Scratch of the fix-up (overwritten): the kernel allocates nothing, so it
        compiles without reference counting (``_nrt=False``; its own code, which
        unpacks and repacks the maps' tuples, then carries no reference-count
        pair per array).
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
        _rows(
            ((c0, c1, c2), dep, (f0, f1), (m0, m1, m2, m3, m4, m5), (z0, z1, z2),
             (d0, d1, d2, d3), deb, obj),
            (o0, o1, o2, o_dep, o_deb, o_obj), src_idx, deb64, snap if b > 0 else snap[:0],
            shape, lo, hi, np.bool_(False), n_mot, n_zm, ncol, threshold, n_neighbours, mode, track,
            same_out, interior, table, band_stats[b], margin, out_colour, out_depth, out_debris,
            write_out, zs, columns[b],
        )
    for b in range(1, bands):  # in order: a fix-up reads the row above it as final
        _rows(
            new, (o0, o1, o2, o_dep, o_deb, o_obj), src_idx, deb64, snap if b > 0 else snap[:0],
            shape, b * rows // bands, (b + 1) * rows // bands, np.bool_(True), n_mot, n_zm, ncol,
            threshold, n_neighbours, mode, track, same_out, interior, table, band_stats[b],
            margin, out_colour, out_depth, out_debris, write_out, zs, columns[b],
        )
    for b in range(bands):
        stats[5] += band_stats[b, 0]
        stats[6] += band_stats[b, 1]


