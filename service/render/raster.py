"""Shared scan conversion: triangle setup and row spans in a zone's pixel grid.

Every raster-based occlusion method (``zbuffer``, ``runlength``, ``bsp``) uses these
helpers, so they cover exactly the same pixels and differ only in *which* surface
wins a pixel.  Sampling is at pixel centres ``(c + 0.5, r + 0.5)``; spans are
half-open in both directions (a pixel centre on a shared edge belongs to exactly
one of the two triangles), and a triangle's depth is the plane through its three
projected vertices, exact for the parallel projection used by every zone.

The z-buffers take a ``key`` (:func:`service.render.depth_sort.tie_source`) and then
draw the triangles in any order with the pixels the depth order gives: a pixel
stores the float32 of the depth that took it, and drawn in the depth order a
triangle takes it when its float64 depth is below the stored one, so an exact tie
goes to the triangle earlier in that order, and so does a near one (two depths that
round to one float32).  That outcome needs no order (:func:`_tie_takes`): a lower
float32 always takes the pixel; at the same float32 ``s``, a triangle whose depth is
below ``s`` beats one whose depth is not, the later of two below ``s`` wins (each
took it from the one before) and the earlier of two not below ``s`` (neither could
take it).  The order of two tied triangles is found from their polygons only where a
tie happens (:func:`service.render.depth_sort.earlier_in_order`): no key per triangle
is computed for a frame.  Without one (``NO_TIE_SOURCE``) ties go to the triangle
drawn first.
"""

from __future__ import annotations

import functools

import numba as nb
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from service.numba_subroutine import subroutine
from service.render.depth_sort import earlier_in_order


@nb.njit(cache=True, nogil=True, inline="always")
def triangle_setup(p0: np.ndarray, p1: np.ndarray, p2: np.ndarray, rows: int) -> tuple:
    """Prepare a projected triangle for :func:`row_span`.

    Parameters
    ----------
    p0, p1, p2 : ndarray, shape (3,)
        Projected vertices ``(sx, sy, depth)``.
    rows : int
        Number of rows of the grid (spans are clipped to it).

    Returns
    -------
    tuple
        ``(ok, r_first, r_last, ax, ay, bx, by, cx, cy, dz0, dzdx, dzdy)``: ``ok`` is
        False for a triangle with no area on screen; rows ``r_first..r_last``
        (inclusive) may hold pixels; a, b, c are the vertices sorted by row
        coordinate; depth at (x, y) is ``dz0 + dzdx * x + dzdy * y``.
    """
    return setup_xyz(p0[0], p0[1], p0[2], p1[0], p1[1], p1[2], p2[0], p2[1], p2[2], rows)


@nb.njit(cache=True, nogil=True, inline="always")
def setup_xyz(
    ax: float, ay: float, az: float,
    bx: float, by: float, bz: float,
    cx: float, cy: float, cz: float,
    rows: int,
) -> tuple:
    """:func:`triangle_setup` from the nine coordinates (no array views in hot loops)."""
    # sort by y (then x) so a shared edge is always evaluated from the same end
    if by < ay or (by == ay and bx < ax):
        ax, ay, az, bx, by, bz = bx, by, bz, ax, ay, az
    if cy < by or (cy == by and cx < bx):
        bx, by, bz, cx, cy, cz = cx, cy, cz, bx, by, bz
        if by < ay or (by == ay and bx < ax):
            ax, ay, az, bx, by, bz = bx, by, bz, ax, ay, az
    det = (bx - ax) * (cy - ay) - (cx - ax) * (by - ay)
    if det == 0.0 or not np.isfinite(det):
        return (False, 0, -1, ax, ay, bx, by, cx, cy, 0.0, 0.0, 0.0)
    dzdx = ((bz - az) * (cy - ay) - (cz - az) * (by - ay)) / det
    dzdy = ((cz - az) * (bx - ax) - (bz - az) * (cx - ax)) / det
    dz0 = az - dzdx * ax - dzdy * ay
    r_first = max(int(np.ceil(ay - 0.5)), 0)
    r_last = min(int(np.ceil(cy - 0.5)) - 1, rows - 1)
    return (True, r_first, r_last, ax, ay, bx, by, cx, cy, dz0, dzdx, dzdy)


@nb.njit(cache=True, nogil=True, inline="always")
def _edge_x(x0: float, y0: float, x1: float, y1: float, y: float) -> float:
    """X where the edge (x0, y0)-(x1, y1) (with y0 < y1) crosses the line at y.

    The fraction of the edge's height, ``(y - y0) / (y1 - y0)``, is taken first: it
    depends on rows only, so :func:`_zone_spans` finds it once for every zone.
    """
    return x0 + (x1 - x0) * ((y - y0) / (y1 - y0))


@nb.njit(cache=True, nogil=True, inline="always")
def row_span(
    ax: float, ay: float, bx: float, by: float, cx: float, cy: float, r: int, cols: int
) -> tuple:
    """Pixel columns covered by a set-up triangle on row ``r``.

    Returns
    -------
    tuple of int
        ``(c_first, c_last)`` inclusive, clipped to ``0..cols-1``; empty when
        ``c_first > c_last``.
    """
    y = r + 0.5
    x_long = _edge_x(ax, ay, cx, cy, y)
    if y < by:
        x_short = _edge_x(ax, ay, bx, by, y)
    else:
        x_short = _edge_x(bx, by, cx, cy, y)
    xl = min(x_long, x_short)
    xr = max(x_long, x_short)
    c_first = max(int(np.ceil(xl - 0.5)), 0)
    c_last = min(int(np.ceil(xr - 0.5)) - 1, cols - 1)
    return c_first, c_last


@nb.njit(cache=True, nogil=True, inline="always")
def _tie_takes(below: bool, held_below: bool, t: int, w: int, key: tuple) -> bool:
    """Whether triangle ``t`` takes a pixel from ``w`` at the same stored float32 depth.

    ``below`` and ``held_below``: whether each one's float64 depth is below the
    stored one.  Decided as drawing in the depth order
    (:func:`service.render.depth_sort.earlier_in_order`, from ``key``, a
    :func:`~service.render.depth_sort.tie_source`) would (module docstring): the one
    below wins; of two below, the later; of two not below, the earlier.
    """
    if below != held_below:
        return below
    return earlier_in_order(key, t, w) != below


@nb.njit(cache=True, nogil=True)
def _depth_at(proj: np.ndarray, z: int, tris: np.ndarray, w: int, rows: int,
              x: float, y: float) -> float:
    """Depth of triangle ``w`` at ``(x, y)`` in zone ``z``, as its drawing computed it."""
    i0, i1, i2 = tris[w, 0], tris[w, 1], tris[w, 2]
    st = setup_xyz(
        proj[z, i0, 0], proj[z, i0, 1], proj[z, i0, 2],
        proj[z, i1, 0], proj[z, i1, 1], proj[z, i1, 2],
        proj[z, i2, 0], proj[z, i2, 1], proj[z, i2, 2],
        rows,
    )
    return st[9] + st[10] * x + st[11] * y


@subroutine(nrt=True)
def _takes_tie_proj(d: float, s: float, t: int, w: int, key: tuple, proj: np.ndarray,
                    z: int, tris: np.ndarray, rows: int, x: float, y: float) -> bool:
    """Whether ``t`` (depth ``d``) takes a pixel whose stored depth ``s`` is float32(d).

    The holder ``w``'s depth is set up again from ``proj`` (rare: only at ties).
    """
    if w < 0 or key[3].shape[0] == 0:  # empty, or no key: the order drawn decides
        return d < s
    return _tie_takes(d < s, _depth_at(proj, z, tris, w, rows, x, y) < s, t, w, key)


@nb.njit(cache=True, nogil=True, parallel=True)
def zbuffer_kernel(
    proj: np.ndarray,
    tris: np.ndarray,
    order: np.ndarray,
    draw: np.ndarray,
    tri_out: np.ndarray,
    depth_out: np.ndarray,
    key: tuple,
) -> None:
    """Z-buffer every zone (zones in parallel).

    Parameters
    ----------
    proj : ndarray, shape (Z, V, 3)
    tris : ndarray, shape (T, 3)
    order : ndarray, shape (N,)
        Triangles to draw, in drawing order (front to back saves writes).
    draw : ndarray, shape (Z, T), bool
        Per zone, whether a triangle may be drawn at all (see
        :func:`service.render.cull.zone_mask`).
    tri_out : ndarray, shape (Z, R, C), int32, filled with -1
    depth_out : ndarray, shape (Z, R, C), float32, filled with +inf
    key : tuple of ndarray
        :func:`service.render.depth_sort.tie_source`: ties decided as the depth order
        decides them (module docstring), in any ``order``;
        :data:`~service.render.depth_sort.NO_TIE_SOURCE`: to the first drawn.
    """
    zones, rows, cols = tri_out.shape
    for z in nb.prange(zones):
        pz = proj[z]
        for t in order:
            if not draw[z, t]:
                continue
            st = triangle_setup(pz[tris[t, 0]], pz[tris[t, 1]], pz[tris[t, 2]], rows)
            if not st[0]:
                continue
            for r in range(st[1], st[2] + 1):
                c0, c1 = row_span(st[3], st[4], st[5], st[6], st[7], st[8], r, cols)
                y = r + 0.5
                for c in range(c0, c1 + 1):
                    d = st[9] + st[10] * (c + 0.5) + st[11] * y
                    d32, s = np.float32(d), depth_out[z, r, c]
                    if d32 < s or (d32 == s and _takes_tie_proj(
                            d, s, t, tri_out[z, r, c], key, proj, z, tris, rows, c + 0.5, y)):
                        depth_out[z, r, c] = d
                        tri_out[z, r, c] = t


@nb.njit(cache=True, nogil=True, parallel=True)
def painter_kernel(
    proj: np.ndarray,
    tris: np.ndarray,
    ids: np.ndarray,
    orders: np.ndarray,
    tri_out: np.ndarray,
    depth_out: np.ndarray,
) -> None:
    """Painter's algorithm: draw back to front, each triangle overwriting what is there.

    Parameters
    ----------
    proj : ndarray, shape (Z, V, 3)
    tris : ndarray, shape (T, 3)
    ids : ndarray, shape (T,)
        Value written to ``tri_out`` for each triangle (e.g. the scene triangle a
        BSP fragment came from).
    orders : ndarray, shape (Z, N)
        Per zone, triangles from farthest to nearest.
    tri_out : ndarray, shape (Z, R, C), int32
    depth_out : ndarray, shape (Z, R, C), float32
    """
    zones, rows, cols = tri_out.shape
    for z in nb.prange(zones):
        pz = proj[z]
        for t in orders[z]:
            st = triangle_setup(pz[tris[t, 0]], pz[tris[t, 1]], pz[tris[t, 2]], rows)
            if not st[0]:
                continue
            for r in range(st[1], st[2] + 1):
                c0, c1 = row_span(st[3], st[4], st[5], st[6], st[7], st[8], r, cols)
                y = r + 0.5
                for c in range(c0, c1 + 1):
                    depth_out[z, r, c] = st[9] + st[10] * (c + 0.5) + st[11] * y
                    tri_out[z, r, c] = ids[t]


@nb.njit(cache=True, nogil=True)
def shared_rows(proj: np.ndarray, tris: np.ndarray, order: np.ndarray, rows: int) -> tuple:
    """Rows each triangle may cover, the same in every zone (zones differ only in x).

    Parameters
    ----------
    proj : ndarray, shape (Z, V, 3)
        Row coordinates ``proj[:, :, 1]`` equal in every zone; zone 0's are read.
    tris : ndarray, shape (T, 3)
    order : ndarray, shape (N,)
    rows : int

    Returns
    -------
    r_first, r_last : ndarray, shape (N,), int64
        For ``order[i]``, the rows :func:`triangle_setup` gives in every zone
        (``r_first > r_last`` when none; non-finite rows give none, as the setup
        rejects such a triangle).
    """
    n = order.shape[0]
    r_first = np.empty(n, np.int64)
    r_last = np.empty(n, np.int64)
    p0 = proj[0]
    for i in range(n):
        t = order[i]
        y0, y1, y2 = p0[tris[t, 0], 1], p0[tris[t, 1], 1], p0[tris[t, 2], 1]
        lo = min(y0, min(y1, y2))
        hi = max(y0, max(y1, y2))
        if np.isfinite(lo) and np.isfinite(hi):
            r_first[i] = max(int(np.ceil(lo - 0.5)), 0)
            r_last[i] = min(int(np.ceil(hi - 0.5)) - 1, rows - 1)
        else:
            r_first[i] = 0
            r_last[i] = -1
    return r_first, r_last


@nb.njit(cache=True, nogil=True, inline="always")
def _zbuffer_band(
    proj: np.ndarray,
    tris: np.ndarray,
    order: np.ndarray,
    draw_t: np.ndarray,
    extent: tuple,
    lo: int,
    hi: int,
    tri_out: np.ndarray,
    depth_out: np.ndarray,
    item: np.ndarray,
    shown: np.ndarray,
    tables: tuple,
    marks: np.ndarray,
    b: int,
    key: tuple,
) -> None:
    """Clear rows ``lo..hi`` of every zone, z-buffer them, mark the items in sight.

    The items of the triangles left in sight go into ``shown`` (:func:`_mark_band`),
    with several zones into ``marks[b]`` (B, Z, P) instead.
    Each triangle is set up for every zone at once (:func:`_setup_zones`: what the
    zones share, its rows and the order of its corners, is found once), then drawn
    row by row with every zone's span of that row in turn (:func:`_zone_spans`, one
    loop over the zones with no branch, which the compiler can vectorise), so the
    zones' rows ``r`` are drawn while they are in cache.  Every float operation is
    :func:`setup_xyz`'s and :func:`row_span`'s, in the same order, and a pixel sees
    the triangles in the same order as in :func:`zbuffer_kernel`: the buffers are the
    same bit for bit.
    """
    zones, rows, cols = tri_out.shape
    if zones > 1:  # clears the band between set-up and drawing, marks from pixel counts
        _zbuffer_band_zones(
            tables, tris, order, draw_t, extent, lo, hi, tri_out, depth_out, item, marks, b, key
        )
        return
    drawn = np.empty((2, zones, hi - lo + 1), np.int64)  # columns written, per zone and row
    drawn[0] = cols
    drawn[1] = -1
    _clear_band(tri_out, depth_out, lo, hi)  # one zone: nothing to share, the plain loop
    _zbuffer_band_one(proj, tris, order, draw_t, extent, lo, hi, tri_out, depth_out, drawn, key)
    _mark_band(tri_out, drawn, lo, item, shown)


@intrinsic
def _prefetch_row(typingctx, arr, index):
    """Hint the CPU to fetch row ``index`` of a 2-D array into cache (no load, no fault).

    LLVM's ``llvm.prefetch`` (read, high locality, data): no value is read, so an
    index past the array is harmless and nothing waits on it, unlike a load.
    """
    if not (isinstance(arr, types.Array) and arr.ndim == 2 and isinstance(index, types.Integer)):
        return None
    sig = types.void(arr, index)

    def codegen(context, builder, signature, args):
        aryty, idxty = signature.args
        ary = context.make_array(aryty)(context, builder, args[0])
        first = context.get_constant(idxty, 0)
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, [args[1], first])
        i8p, i32 = ir.IntType(8).as_pointer(), ir.IntType(32)
        fnty = ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "llvm.prefetch.p0i8")
        flags = [ir.Constant(i32, 0), ir.Constant(i32, 3), ir.Constant(i32, 1)]
        builder.call(fn, [builder.bitcast(ptr, i8p), *flags])
        return context.get_dummy_value()

    return sig, codegen


@nb.njit(cache=True, nogil=True, inline="always")
def _clear_band(tri_out: np.ndarray, depth_out: np.ndarray, lo: int, hi: int) -> None:
    """Rows ``lo..hi`` of every zone: no triangle (-1), depth +inf."""
    for z in range(tri_out.shape[0]):
        tri_out[z, lo : hi + 1] = -1
        depth_out[z, lo : hi + 1] = np.inf


@nb.njit(cache=True, nogil=True)
def _zbuffer_band_zones(
    tables: tuple,
    tris: np.ndarray,
    order: np.ndarray,
    draw_t: np.ndarray,
    extent: tuple,
    lo: int,
    hi: int,
    tri_out: np.ndarray,
    depth_out: np.ndarray,
    item: np.ndarray,
    marks: np.ndarray,
    b: int,
    key: tuple,
) -> None:
    """:func:`_zbuffer_band` for several zones; marks the items in sight in ``marks[b]``.

    ``tables`` is :func:`vertex_tables` of the projection.  Two passes: every
    triangle with rows in the band is set up first, into a table
    (:func:`_setup_band`), then drawn from it (:func:`_draw_band`).  Set-ups one
    after another overlap in the CPU; set up between two triangles' drawing, each
    waited on the drawing before it (0.1 ms of a 5-zone game frame of 1.3 on one
    thread).  One zone draws as before: the table made it slower there.

    The items in sight are marked from how many of the band's pixels each triangle
    holds at the end, counted as it draws (:func:`_draw_band`), instead of from a
    pass over the columns drawn (0.145 ms of a 5-zone game frame, one thread).

    Not inlined (nor are its two passes) into the parallel kernel: numba's inlining
    into a ``prange`` body cost 5 s more cold compile (17.2 s against 12.2 before
    the two passes); called, the kernel compiles in 9.6 s and runs as fast.
    """
    zones, n = tri_out.shape[0], order.shape[0]
    xs = np.empty((n, 3, zones))  # per triangle and zone: x of corners a, b, c
    plane = np.empty((n, 3, zones))  # per triangle and zone: dz0, dzdx, dzdy
    ys = np.empty((n, 3))  # per triangle: y of corners a, b, c (every zone's)
    trs = np.empty((n, 3), np.int64)  # per triangle: its index, first and last row here
    row = np.empty(tris.shape[0], np.int64)  # per triangle index: its row of the table
    m = _setup_band(tables, tris, order, draw_t, extent, lo, hi, xs, plane, ys, trs, row)
    _clear_band(tri_out, depth_out, lo, hi)  # after the set-up: its reads stay in cache
    held = np.zeros((m, zones), np.int64)  # per triangle and zone: pixels it holds
    if _draw_band(xs, plane, ys, trs, row, m, tri_out, depth_out, held) and key[3].shape[0]:
        # a tie met in the order drawn: the band again, ties decided by the key
        _clear_band(tri_out, depth_out, lo, hi)
        _draw_band_keyed(xs, plane, ys, trs, row, m, tri_out, depth_out, key)
        _count_held(tri_out, row, lo, hi, held)
    if marks.shape[2] == 0:
        return
    for j in range(m):
        p = item[trs[j, 0]]
        for z in range(zones):
            marks[b, z, p] |= held[j, z] > 0


@subroutine(nrt=True)
def _setup_band(
    tables: tuple, tris: np.ndarray, order: np.ndarray, draw_t: np.ndarray, extent: tuple,
    lo: int, hi: int, xs: np.ndarray, plane: np.ndarray, ys: np.ndarray, trs: np.ndarray,
    row: np.ndarray,
) -> int:
    """Set up, in draw order, the triangles of ``order`` with rows in ``lo..hi``.

    The corners of the triangles set up a few later are fetched into cache
    (:func:`_prefetch_row`) meanwhile: 0.03 ms of a 5-zone game frame of 1.05 frozen,
    0.09 of 1.12 moving (one thread, best of 250).  Fills the first rows of ``xs``,
    ``plane`` (N, 3, Z) (:func:`_setup_zones`),
    ``ys`` (N, 3) and ``trs`` (N, 3) (the triangle, its first and last row in the
    band) with the triangles drawn in some zone, and ``row`` (T,) at those
    triangles with their row of the table; returns how many.
    """
    r_first, r_last = extent
    xz, yd = tables
    m, n = 0, order.shape[0]
    for i in range(n):
        # the triangles drawn next, in no order in memory: their corners 8 on (and
        # their corner indices 16 on) into cache while this one is set up
        _prefetch_row(tris, order[min(i + 16, n - 1)])
        ahead = order[min(i + 8, n - 1)]
        for k in range(3):
            _prefetch_row(yd, tris[ahead, k])
            _prefetch_row(xz, tris[ahead, k])
        if r_last[i] < lo or r_first[i] > hi or r_first[i] > r_last[i]:
            continue  # the rows are shared: skip the triangle in every zone at once
        ay, by, cy, any_live = _setup_zones(tables, tris, order[i], draw_t, xs, plane, m)
        ys[m, 0], ys[m, 1], ys[m, 2] = ay, by, cy
        trs[m, 0], trs[m, 1], trs[m, 2] = order[i], max(r_first[i], lo), min(r_last[i], hi)
        row[order[i]] = m
        m += any_live  # a triangle drawn in no zone: its row is used again
    return m


@subroutine(nrt=True)
def _draw_band(
    xs: np.ndarray, plane: np.ndarray, ys: np.ndarray, trs: np.ndarray, row: np.ndarray,
    m: int, tri_out: np.ndarray, depth_out: np.ndarray, held: np.ndarray,
) -> bool:
    """Draw the ``m`` triangles :func:`_setup_band` set up, in every zone.

    Row by row, with every zone's span of that row in turn (:func:`_zone_spans`, one
    loop over the zones with no branch), so the zones' rows ``r`` are drawn while
    they are in cache.  ``held`` (m, Z), zero before, gets how many of the band's
    pixels each triangle holds at the end: a pixel taken adds one to the triangle
    drawing and takes one from the triangle it held before (rare: drawn nearest
    first, 44 of the game scene's 47,669 pixels written at 5 zones), found by
    ``row``.

    Ties go to the triangle drawn first; returns whether any was met (a depth whose
    float32 equals the one stored), where the key's rule could differ
    (:func:`_draw_band_keyed` then draws the band again).  Deciding them here by the
    key cost the 5-zone pass a fifth more on the game scene (best of 400, one
    thread): the rare path's array reads slowed the loop that never takes it.
    """
    zones, cols = tri_out.shape[0], tri_out.shape[2]
    spans = np.empty((2, zones), np.int64)  # per zone: first and last column of a row
    ties = 0
    for j in range(m):
        t = trs[j, 0]
        ay, by, cy = ys[j, 0], ys[j, 1], ys[j, 2]
        for r in range(trs[j, 1], trs[j, 2] + 1):
            y = r + 0.5
            _zone_spans(xs, j, ay, by, cy, y, cols, spans)
            for z in range(zones):
                c0, c1 = spans[0, z], spans[1, z]
                if c0 > c1:  # a zone the triangle does not draw in has every x 0: empty
                    continue
                p0, p1, p2 = plane[j, 0, z], plane[j, 1, z], plane[j, 2, z]
                taken = 0
                dz = depth_out[z, r]  # the zone's row
                tz = tri_out[z, r]
                # unsigned columns: no negative-index fix-up per pixel (1 % fewer
                # instructions in the 5-zone pass); 0 <= c0 <= c1 here, so no wrap
                for c in range(np.uint64(c0), np.uint64(c1 + 1)):
                    d = p0 + p1 * (c + 0.5) + p2 * y
                    d32, s = np.float32(d), dz[c]
                    if d32 < s or (d32 == s and d < s):  # as d < s: first drawn wins
                        before = tz[c]
                        if before >= 0:  # taken from the triangle that held it
                            held[row[before], z] -= 1
                        dz[c] = d
                        tz[c] = t
                        taken += 1
                    ties += d32 == s
                held[j, z] += taken
    return ties > 0


@subroutine(nrt=True)
def _draw_band_keyed(
    xs: np.ndarray, plane: np.ndarray, ys: np.ndarray, trs: np.ndarray, row: np.ndarray,
    m: int, tri_out: np.ndarray, depth_out: np.ndarray, key: tuple,
) -> None:
    """:func:`_draw_band` with ties decided by ``key`` (:func:`_takes_tie_band`), no counts."""
    zones, cols = tri_out.shape[0], tri_out.shape[2]
    spans = np.empty((2, zones), np.int64)
    for j in range(m):
        t = trs[j, 0]
        ay, by, cy = ys[j, 0], ys[j, 1], ys[j, 2]
        for r in range(trs[j, 1], trs[j, 2] + 1):
            y = r + 0.5
            _zone_spans(xs, j, ay, by, cy, y, cols, spans)
            for z in range(zones):
                p0, p1, p2 = plane[j, 0, z], plane[j, 1, z], plane[j, 2, z]
                dz, tz = depth_out[z, r], tri_out[z, r]
                for c in range(np.uint64(max(spans[0, z], 0)), np.uint64(spans[1, z] + 1)):
                    d = p0 + p1 * (c + 0.5) + p2 * y
                    d32, s = np.float32(d), dz[c]
                    if d32 < s or (d32 == s and _takes_tie_band(
                            d, s, t, tz[c], key, plane, row, z, c + 0.5, y)):
                        dz[c] = d
                        tz[c] = t


@subroutine(nrt=True)
def _count_held(tri_out: np.ndarray, row: np.ndarray, lo: int, hi: int,
                held: np.ndarray) -> None:
    """``held`` (m, Z): how many pixels of rows ``lo..hi`` each triangle holds, counted."""
    held[:] = 0
    for z in range(tri_out.shape[0]):
        for r in range(lo, hi + 1):
            for c in range(tri_out.shape[2]):
                t = tri_out[z, r, c]
                if t >= 0:
                    held[row[t], z] += 1


@subroutine(nrt=True)
def _takes_tie_band(d: float, s: float, t: int, w: int, key: tuple, plane: np.ndarray,
                    row: np.ndarray, z: int, x: float, y: float) -> bool:
    """:func:`_takes_tie_proj` in :func:`_draw_band`: ``w``'s depth from its set-up table row."""
    if w < 0 or key[3].shape[0] == 0:
        return d < s
    j = row[w]
    held = plane[j, 0, z] + plane[j, 1, z] * x + plane[j, 2, z] * y
    return _tie_takes(d < s, held < s, t, w, key)


@nb.njit(cache=True, nogil=True, inline="always")
def _zbuffer_band_one(
    proj: np.ndarray,
    tris: np.ndarray,
    order: np.ndarray,
    draw_t: np.ndarray,
    extent: tuple,
    lo: int,
    hi: int,
    tri_out: np.ndarray,
    depth_out: np.ndarray,
    drawn: np.ndarray,
    key: tuple,
) -> None:
    """:func:`_zbuffer_band`'s drawing for one zone (buffers already cleared)."""
    rows, cols = tri_out.shape[1], tri_out.shape[2]
    r_first, r_last = extent
    for i in range(order.shape[0]):
        if r_last[i] < lo or r_first[i] > hi:
            continue
        t = order[i]
        if not draw_t[t, 0]:
            continue
        i0, i1, i2 = tris[t, 0], tris[t, 1], tris[t, 2]
        st = setup_xyz(
            proj[0, i0, 0], proj[0, i0, 1], proj[0, i0, 2],
            proj[0, i1, 0], proj[0, i1, 1], proj[0, i1, 2],
            proj[0, i2, 0], proj[0, i2, 1], proj[0, i2, 2],
            rows,
        )
        if not st[0]:
            continue
        for r in range(max(st[1], lo), min(st[2], hi) + 1):
            c0, c1 = row_span(st[3], st[4], st[5], st[6], st[7], st[8], r, cols)
            if c0 > c1:
                continue
            drawn[0, 0, r - lo] = min(drawn[0, 0, r - lo], c0)
            drawn[1, 0, r - lo] = max(drawn[1, 0, r - lo], c1)
            y = r + 0.5
            for c in range(c0, c1 + 1):
                d = st[9] + st[10] * (c + 0.5) + st[11] * y
                d32, s = np.float32(d), depth_out[0, r, c]
                if d32 < s or (d32 == s and _takes_tie_proj(  # a typed 0: the signature
                        # zbuffer_kernel's zone index compiles (a literal would be another)
                        d, s, t, tri_out[0, r, c], key, proj, np.int64(0), tris, rows, c + 0.5,
                        y)):
                    depth_out[0, r, c] = d
                    tri_out[0, r, c] = t


@nb.njit(cache=True, nogil=True, inline="always")
def _mark_band(
    tri_out: np.ndarray, drawn: np.ndarray, lo: int, item: np.ndarray, shown: np.ndarray
) -> None:
    """Mark ``shown[z, item[t]]`` for each triangle ``t`` seen in the band's rows.

    :func:`service.render.light.mark_shown`'s result, from the columns each row had drawn
    (``drawn`` (2, Z, rows of the band)) instead of every column: the rest of a row
    is empty.  Bands mark in parallel; they only ever write True.
    """
    if shown.shape[1] == 0:
        return
    for z in range(drawn.shape[1]):
        for k in range(drawn.shape[2]):
            for c in range(drawn[0, z, k], drawn[1, z, k] + 1):
                t = tri_out[z, lo + k, c]
                if t >= 0:
                    shown[z, item[t]] = True


@nb.njit(cache=True, nogil=True, inline="always")
def _corner_order(
    y0: float, y1: float, y2: float, x0: float, x1: float, x2: float
) -> tuple[int, int, int]:
    """Which corners (0-2) :func:`setup_xyz` makes a, b and c: sorted by y, then x."""
    ia, ib, ic = 0, 1, 2
    ax, ay, bx, by, cx, cy = x0, y0, x1, y1, x2, y2
    if by < ay or (by == ay and bx < ax):
        ia, ib = ib, ia
        ax, ay, bx, by = bx, by, ax, ay
    if cy < by or (cy == by and cx < bx):
        ib, ic = ic, ib
        bx, by = cx, cy
        if by < ay or (by == ay and bx < ax):
            ia, ib = ib, ia
    return ia, ib, ic


@nb.njit(cache=True, nogil=True, inline="always")
def _pick(k: int, a: int, b: int, c: int) -> int:
    """``(a, b, c)[k]`` without building a tuple to index at run time."""
    return a if k == 0 else (b if k == 1 else c)


@nb.njit(cache=True, nogil=True, inline="always")
def _setup_zones(
    tables: tuple, tris: np.ndarray, t: int, draw_t: np.ndarray, xs: np.ndarray,
    plane: np.ndarray, j: int,
) -> tuple[float, float, float, bool]:
    """:func:`setup_xyz` of triangle ``t`` in every zone it is drawn in.

    Zones share each corner's row and depth (only x is sheared), so the order of the
    corners is found once, unless two share a row (then x breaks the tie, per zone).
    ``tables`` is :func:`vertex_tables` of the projection; ``tris`` (T, 3) and
    ``draw_t`` (T, Z) are read by element (an array view per triangle cost a fifth
    of the set-up).  Fills row ``j`` of ``xs`` (N, 3, Z) with the sorted corners' x
    (0 where the triangle is not drawn: only there are all three 0, as a drawn
    triangle has area) and of ``plane`` (N, 3, Z) with the depth plane; returns the
    sorted corners' y (the same in every zone) and whether it draws in any zone.
    """
    xz, yd = tables
    i0, i1, i2 = tris[t, 0], tris[t, 1], tris[t, 2]
    y0, y1, y2 = yd[i0, 0], yd[i1, 0], yd[i2, 0]
    tie = y0 == y1 or y1 == y2 or y0 == y2
    ia, ib, ic = _corner_order(y0, y1, y2, 0.0, 0.0, 0.0)
    a, b, c = _pick(ia, i0, i1, i2), _pick(ib, i0, i1, i2), _pick(ic, i0, i1, i2)
    ay, by, cy = yd[a, 0], yd[b, 0], yd[c, 0]
    az, bz, cz = yd[a, 1], yd[b, 1], yd[c, 1]
    any_live = False
    for z in range(xs.shape[2]):
        if tie:  # the x order of two corners on one row may differ between zones
            ja, jb, jc = _corner_order(y0, y1, y2, xz[i0, z], xz[i1, z], xz[i2, z])
            a, b, c = _pick(ja, i0, i1, i2), _pick(jb, i0, i1, i2), _pick(jc, i0, i1, i2)
            az, bz, cz = yd[a, 1], yd[b, 1], yd[c, 1]
        ax, bx, cx = xz[a, z], xz[b, z], xz[c, z]
        det = (bx - ax) * (cy - ay) - (cx - ax) * (by - ay)
        ok = draw_t[t, z] and det != 0.0 and np.isfinite(det)
        if ok:
            dzdx = ((bz - az) * (cy - ay) - (cz - az) * (by - ay)) / det
            dzdy = ((cz - az) * (bx - ax) - (bz - az) * (cx - ax)) / det
            plane[j, 0, z], plane[j, 1, z], plane[j, 2, z] = az - dzdx * ax - dzdy * ay, dzdx, dzdy
            xs[j, 0, z], xs[j, 1, z], xs[j, 2, z] = ax, bx, cx
        else:  # finite, for the spans of dead zones (empty: every x is 0)
            xs[j, 0, z] = xs[j, 1, z] = xs[j, 2, z] = 0.0
        any_live |= ok
    return ay, by, cy, any_live


@nb.njit(cache=True, nogil=True)
def vertex_tables(proj: np.ndarray) -> tuple:
    """The projection by vertex, as the one-pass kernel reads it.

    Parameters
    ----------
    proj : ndarray, shape (Z, V, 3)
        Rows and depths equal in every zone.

    Returns
    -------
    xz : ndarray, shape (V, Z)
        Each vertex's column in every zone, side by side: a triangle's set-up reads
        its corners' 3 x 5 columns from 3 cache lines instead of 15 (10 % of the
        5-zone pass on a moving game scene, where nothing stays in cache).
    yd : ndarray, shape (V, 2)
        Each vertex's row and depth.
    """
    zones, n = proj.shape[0], proj.shape[1]
    xz = np.empty((n, zones))
    yd = np.empty((n, 2))
    for v in range(n):
        yd[v, 0] = proj[0, v, 1]
        yd[v, 1] = proj[0, v, 2]
        for z in range(zones):
            xz[v, z] = proj[z, v, 0]
    return xz, yd


@nb.njit(cache=True, nogil=True, inline="always")
def _zone_spans(
    xs: np.ndarray, j: int, ay: float, by: float, cy: float, y: float, cols: int,
    spans: np.ndarray,
) -> None:
    """:func:`row_span` of one row in every zone: ``spans`` (2, Z) first and last column.

    ``xs`` (N, 3, Z): row ``j`` holds the triangle's corners (:func:`_setup_zones`).

    Which short edge the row crosses, and how far down each edge the row lies,
    depend on y alone (zones share rows), so both are found once: the loop over
    zones has no branch and no division left (:func:`_edge_x`'s arithmetic).
    """
    upper = y < by
    s0 = 0 if upper else 1  # the short edge: a-b above corner b, b-c below
    ys0 = ay if upper else by
    ys1 = by if upper else cy
    f_long = (y - ay) / (cy - ay)
    f_short = (y - ys0) / (ys1 - ys0)
    for z in range(xs.shape[2]):
        x_long = xs[j, 0, z] + (xs[j, 2, z] - xs[j, 0, z]) * f_long
        x_short = xs[j, s0, z] + (xs[j, s0 + 1, z] - xs[j, s0, z]) * f_short
        xl = min(x_long, x_short)
        xr = max(x_long, x_short)
        spans[0, z] = max(int(np.ceil(xl - 0.5)), 0)
        spans[1, z] = min(int(np.ceil(xr - 0.5)) - 1, cols - 1)


@nb.njit(cache=True, nogil=True, parallel=True)
def zbuffer_zones_kernel(
    proj: np.ndarray,
    tris: np.ndarray,
    order: np.ndarray,
    draw_t: np.ndarray,
    bands: np.ndarray,
    tri_out: np.ndarray,
    depth_out: np.ndarray,
    item: np.ndarray,
    shown: np.ndarray,
    xz: np.ndarray,
    yd: np.ndarray,
    threads: int,
    key: tuple,
) -> None:
    """Z-buffer every zone in one pass over the triangles, bands of rows in parallel.

    Zones are sheared parallel projections that differ only in x, so a triangle
    covers the same rows (hololines) in every zone: its row extent is found once
    (:func:`shared_rows`) and each band of rows draws it into every zone.  Per zone
    and triangle the arithmetic is :func:`zbuffer_kernel`'s, in the same order, so
    the buffers are bit-identical to it.

    Parameters
    ----------
    proj : ndarray, shape (Z, V, 3)
        ``proj[:, :, 1]`` must be equal in every zone.
    tris : ndarray, shape (T, 3)
    order : ndarray, shape (N,)
        Triangles to draw, in drawing order.
    draw_t : ndarray, shape (T, Z), bool
        Per triangle, the zones it may be drawn in (the transpose of
        :func:`service.render.cull.zone_mask`).
    bands : ndarray, shape (B, 2), int64
        First and last row of each band; together they cover every row once.  Bands
        run in parallel in the order given (interleave them to share the work).  No
        rows (:func:`no_bands`): ``threads`` bands, cut where each gets the same
        share of the frame's triangle rows (:func:`balanced_bands`).
    tri_out : ndarray, shape (Z, R, C), int32
        Out; need not be initialised (-1 where empty).
    depth_out : ndarray, shape (Z, R, C), float32
        Out; need not be initialised (+inf where empty).
    item : ndarray, shape (T,), int
        Item of each triangle (e.g. its polygon), for ``shown``.
    shown : ndarray, shape (Z, P), bool, filled with False
        Out: ``shown[z, p]`` where zone z shows an item p (what
        :func:`service.render.light.mark_shown` finds in the buffers, found while each band
        is fresh and only in the columns it drew).  Shape (Z, 0): not wanted.
    xz, yd : ndarray, shape (V, Z) and (V, 2)
        :func:`vertex_tables` of ``proj`` where the caller has them
        (:func:`service.render.projection.project_tables`); with no rows the kernel makes
        them (one zone reads ``proj`` as it is and needs none).
    threads : int
        Threads the kernel runs on (``numba.get_num_threads()``, which a kernel
        cached on disk cannot call itself), for ``bands`` with no rows.
    key : tuple of ndarray
        :func:`service.render.depth_sort.tie_source`: ties decided as the depth order
        decides them (module docstring), so ``order`` may be any order (index order
        needs no sort); :data:`~service.render.depth_sort.NO_TIE_SOURCE`: ties to the
        triangle drawn first.
    """
    extent = shared_rows(proj, tris, order, tri_out.shape[1])
    if tri_out.shape[0] > 1 and xz.shape[0] == 0:  # several zones read proj by vertex
        tables = vertex_tables(proj)
    else:  # given, or one zone (which reads proj as it is)
        tables = (xz, yd)
    rows, cols = tri_out.shape[1], tri_out.shape[2]
    if bands.shape[0] == 0 and threads <= 1:  # one band: nothing to balance
        use = np.empty((1, 2), np.int64)
        use[0, 0], use[0, 1] = 0, rows - 1
    elif bands.shape[0] == 0:
        # a typed BAND_SETUP: a global constant would type as a literal, a signature
        # the warm-up could not compile ahead of this kernel (render/warmup_jobs.py)
        use = balanced_bands(extent[0], extent[1], rows, threads, cols // 64 + 1,
                             np.int64(BAND_SETUP))
    else:
        use = bands.copy()  # writable, as balanced_bands' (one type for both)
    # several zones: each band marks its own copy without a branch, merged after
    marks = _band_marks(use.shape[0] if tri_out.shape[0] > 1 else 0, shown.shape)
    for b in nb.prange(use.shape[0]):
        lo, hi = use[b, 0], use[b, 1]
        _zbuffer_band(  # the index cast: numba types a prange index int64, then uint64 in
            # the parallel loop's body, and _zbuffer_band_zones would compile for both
            proj, tris, order, draw_t, extent, lo, hi, tri_out, depth_out, item, shown, tables,
            marks, np.int64(b), key,
        )
    for b in range(marks.shape[0]):
        for z in range(shown.shape[0]):
            for p in range(shown.shape[1]):
                shown[z, p] |= marks[b, z, p]


@nb.njit(cache=True, nogil=True)
def _band_marks(bands: int, shape: tuple) -> np.ndarray:
    """``bands`` copies of ``shown`` (B, Z, P), False: made outside the parallel kernel.

    Inside it, numba makes ``np.zeros`` a parallel loop of its own: one more wake-up
    of the threads every frame, 0.05 ms with ``OMP_WAIT_POLICY=PASSIVE`` (as
    ``holo-bench`` and ``holo-service`` run), also at one zone, where it is empty.
    """
    return np.zeros((bands, shape[0], shape[1]), np.bool_)


#: A triangle's set-up in :func:`balanced_bands`' unit, triangle rows drawn: where the
#: game scene's two bands take the same time on one thread (5 zones: the cut at row
#: 76-77 frozen, 80-82 moving; one zone 76), within a row or two of what this gives.
BAND_SETUP = 3


@nb.njit(cache=True, nogil=True)
def balanced_bands(
    r_first: np.ndarray, r_last: np.ndarray, rows: int, n: int, base: int, setup: int = 0
) -> np.ndarray:
    """``n`` bands of rows, each holding about the same share of the work.

    A row's work is the triangles whose rows cover it plus ``base`` (its clearing
    and marking, in triangle rows), plus ``setup`` for each triangle that starts
    on it (its set-up).  Fixed bands gave one of two threads 57-63 % of
    the game scene's rows drawn (its triangles crowd part of the screen); several
    bands per thread even that out but set up every triangle that crosses a band
    edge again.  Without the set-up the game scene's cut at 5 zones fell 6-8 rows
    low on the screen: the band above it, with the far scene's many small
    triangles, took 55 % of the pass on one thread (736 against 614 us).

    Parameters
    ----------
    r_first, r_last : ndarray, shape (N,), int64
        Rows of each triangle (:func:`shared_rows`; none where ``r_first > r_last``).
    rows : int
        Rows of the screen (>= 1).
    n : int
        Bands wanted (as many as threads); at most ``rows`` are made.
    base : int
        Work of an empty row, in triangle rows.
    setup : int
        Work of a triangle's set-up, in triangle rows.

    Returns
    -------
    ndarray, shape (min(n, rows), 2), int64
        First and last row of each band, top to bottom; each band has a row, and
        together they cover every row once.
    """
    n = max(1, min(n, rows))
    diff = np.zeros(rows + 1, np.int64)
    starts = np.zeros(rows, np.int64)
    for i in range(r_first.shape[0]):
        if r_first[i] <= r_last[i]:  # then 0 <= r_first <= r_last < rows
            diff[r_first[i]] += 1
            diff[r_last[i] + 1] -= 1
            starts[r_first[i]] += setup
    cum = np.empty(rows, np.int64)  # work of rows 0..r
    covering, total = 0, 0
    for r in range(rows):
        covering += diff[r]
        total += covering + base + starts[r]
        cum[r] = total
    bands = np.empty((n, 2), np.int64)
    lo = 0
    for b in range(n - 1):
        target = total * (b + 1) // n
        last = rows - (n - b)  # leaves a row for each band after this one
        r = lo
        while r < last and cum[r] < target:
            r += 1
        bands[b, 0], bands[b, 1] = lo, r
        lo = r + 1
    bands[n - 1, 0], bands[n - 1, 1] = lo, rows - 1
    return bands


@functools.lru_cache(maxsize=1)
def no_bands() -> np.ndarray:
    """An empty (0, 2) bands array: :func:`zbuffer_zones_kernel` balances its own.

    Read-only, as :func:`row_bands`' arrays are, so both are one kernel signature.
    """
    bands = np.zeros((0, 2), np.int64)
    bands.flags.writeable = False
    return bands


@functools.lru_cache(maxsize=64)
def row_bands(rows: int, threads: int, per_thread: int = 3) -> np.ndarray:
    """Bands of rows for :func:`zbuffer_zones_kernel`, interleaved across threads.

    Numba hands each thread a contiguous run of loop iterations, so band ``i`` of
    the result is chosen to give each thread every ``threads``-th band of the
    screen: a scene crowded in one part of the screen still loads all threads.

    Parameters
    ----------
    rows : int
    threads : int
        Threads the kernel will use (>= 1).
    per_thread : int
        Bands per thread when there are several; more balance the load better,
        fewer set up triangles that cross a band edge fewer times.  One thread gets
        one band.

    Returns
    -------
    ndarray, shape (B, 2), int64
        ``[first_row, last_row]`` of each band; read-only (one array per arguments,
        kept: building it cost more than a 5-zone frame's triangle set-up).
    """
    n = 1 if threads <= 1 else min(rows, threads * per_thread)  # one thread: no band edges
    edges = np.linspace(0, rows, n + 1).astype(np.int64)
    bands = np.stack([edges[:-1], edges[1:] - 1], axis=1)
    bands = bands[bands[:, 0] <= bands[:, 1]]
    perm = np.concatenate([np.arange(k, bands.shape[0], threads) for k in range(threads)])
    bands = np.ascontiguousarray(bands[perm])
    bands.flags.writeable = False
    return bands
