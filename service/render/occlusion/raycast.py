"""Per-pixel ray casting: the accuracy reference for every other occlusion method.

For zone ``k`` (shear ``t = tan(theta_k)``) and pixel ``(r, c)`` the ray is the
zone's projection line through the display-plane point ``(X, Y, 0)`` with
``X = (c + 0.5) s - width/2`` and ``Y = height/2 - (r + 0.5) s``: the points
``(X + z t, Y, z)``.  Each candidate triangle is intersected with that ray in
world space, in float64, and the nearest hit (largest ``z``, smallest depth ``-z``)
wins.  This deliberately shares no code with :mod:`service.render.raster`, so comparing a
raster method against it catches scan-conversion bugs.

Intersection test (watertight, Pluecker form)
---------------------------------------------
For a ray with origin ``o`` and direction ``d = (t, 0, 1)`` and a triangle edge
``a -> b`` the edge value is the scalar triple product ``E = d . ((a - o) x (b - o))``.
The ray passes through the triangle when the three edge values have the sign of
the triangle's orientation ``D = d . ((b - a) x (c - a))``; the hit depth comes from
the triangle's plane.  Triangles seen edge-on (``D == 0``) are never hit.

``E`` is computed so that swapping ``a`` and ``b`` negates it *exactly* in floating
point, so two triangles sharing an edge agree bit for bit on which side of it a
pixel centre lies.

Tie rule (half-open coverage)
-----------------------------
A pixel centre exactly on an edge (``E == 0``) belongs to the triangle that lies
to the edge's right on screen (+column); on a horizontal edge, to the triangle
below it (+row).  Two triangles sharing an edge lie on opposite sides of it, so
exactly one of them claims such a pixel; like the raster rule (``[x_left,
x_right)`` in columns and ``[y_top, y_bottom)`` in rows) a square's left and top
edges are inside and its right and bottom edges outside.  Among hits at exactly
the same depth the triangle earlier in ``order`` wins.

Speed
-----
Triangles are binned per zone into ``TILE x TILE`` pixel tiles by their projected
bounding box; tiles are processed in parallel, and within a tile the candidates
are sorted by their nearest point so the search stops as soon as no remaining
triangle can come nearer than the best hit so far.
"""

from __future__ import annotations

import time

import numba as nb
import numpy as np

from service.display import DisplaySettings
from service.numba_subroutine import subroutine
from service.render.occlusion import Visibility
from service.render.scene import SceneArrays

TILE = 16
"""Side of a binning tile in pixels."""


@nb.njit(cache=True, nogil=True, inline="always")
def _edge(
    ax: float, ay: float, az: float, bx: float, by: float, bz: float, ox: float, oy: float, t: float
) -> float:
    """Triple product ``d . ((a - o) x (b - o))`` for ``d = (t, 0, 1)``, ``o = (ox, oy, 0)``.

    Exactly antisymmetric in ``a`` and ``b`` (each term is a difference of two
    products whose factors merely trade places).
    """
    ux, uy = ax - ox, ay - oy
    vx, vy = bx - ox, by - oy
    return t * (uy * bz - az * vy) + (ux * vy - uy * vx)


@nb.njit(cache=True, nogil=True, inline="always")
def _claims_zero_edge(ex: float, ey: float, sign: float) -> bool:
    """Whether a triangle claims pixel centres lying exactly on one of its edges.

    ``(ex, ey)`` is the edge direction ``b - a`` on the display plane (world x
    already sheared, world y); ``sign`` the triangle's orientation.  The inward
    normal on screen (columns right, rows down) is ``sign * (-ey, -ex)``; claim the
    edge when it points to +column, or along +row for a horizontal edge.
    """
    nx = -sign * ey
    if nx != 0.0:
        return nx > 0.0
    return -sign * ex > 0.0


@subroutine(nrt=True)
def _box(
    tri: np.ndarray, t: float, geom: np.ndarray, rows: int, cols: int, out: np.ndarray
) -> None:
    """Pixel bounding box of a triangle (3, 3) in a zone with shear ``t``.

    ``geom`` is ``half_width, half_height, pixel_size``; ``out`` (4,) receives rows
    ``r0, r1`` and columns ``c0, c1``, inclusive, widened by one pixel, clipped.
    """
    x0 = y0 = np.inf
    x1 = y1 = -np.inf
    for k in range(3):
        xs = (tri[k, 0] - tri[k, 2] * t + geom[0]) / geom[2]
        ys = (geom[1] - tri[k, 1]) / geom[2]
        x0, x1, y0, y1 = min(x0, xs), max(x1, xs), min(y0, ys), max(y1, ys)
    # clamp in floating point first so far-off geometry cannot overflow the int cast
    out[0] = max(int(np.ceil(min(max(y0, -2.0), rows + 2.0) - 0.5)) - 1, 0)
    out[1] = min(int(np.floor(min(max(y1, -2.0), rows + 2.0) - 0.5)) + 1, rows - 1)
    out[2] = max(int(np.ceil(min(max(x0, -2.0), cols + 2.0) - 0.5)) - 1, 0)
    out[3] = min(int(np.floor(min(max(x1, -2.0), cols + 2.0) - 0.5)) + 1, cols - 1)


@nb.njit(cache=True, nogil=True)
def _setup(wv: np.ndarray, shears: np.ndarray, geom: np.ndarray, rows: int, cols: int) -> tuple:
    """Per zone and triangle: orientation, edge claims, depth plane, pixel bounding box.

    Parameters
    ----------
    wv : ndarray, shape (N, 3, 3)
        World-space corners of the candidate triangles.
    shears : ndarray, shape (Z,)
    geom : ndarray, shape (3,)
        ``half_width, half_height, pixel_size``.

    Returns
    -------
    tuple
        ``sign (Z, N)`` (0 for edge-on), ``claim (Z, N, 3)`` bool,
        ``plane (Z, N, 3)`` with hit ``z = p0 + p1 X + p2 Y``, and
        ``box (Z, N, 4)`` int64 ``r0, r1, c0, c1`` (see :func:`_box`).
    """
    zones, n = shears.shape[0], wv.shape[0]
    sign = np.zeros((zones, n))
    claim = np.zeros((zones, n, 3), np.bool_)
    plane = np.zeros((zones, n, 3))
    box = np.zeros((zones, n, 4), np.int64)
    for z in range(zones):
        t = shears[z]
        for i in range(n):
            a = wv[i, 0]
            e1x, e1y, e1z = wv[i, 1, 0] - a[0], wv[i, 1, 1] - a[1], wv[i, 1, 2] - a[2]
            e2x, e2y, e2z = wv[i, 2, 0] - a[0], wv[i, 2, 1] - a[1], wv[i, 2, 2] - a[2]
            nx = e1y * e2z - e1z * e2y
            ny = e1z * e2x - e1x * e2z
            nz = e1x * e2y - e1y * e2x
            det = t * nx + nz  # n . d
            if det == 0.0 or not np.isfinite(det):
                continue
            sign[z, i] = sg = 1.0 if det > 0 else -1.0
            for k in range(3):
                p, q = wv[i, k], wv[i, (k + 1) % 3]
                ex = (q[0] - p[0]) - (q[2] - p[2]) * t
                claim[z, i, k] = _claims_zero_edge(ex, q[1] - p[1], sg)
            plane[z, i, 0] = (nx * a[0] + ny * a[1] + nz * a[2]) / det
            plane[z, i, 1] = -nx / det
            plane[z, i, 2] = -ny / det
            _box(wv[i], t, geom, rows, cols, box[z, i])
    return sign, claim, plane, box


@nb.njit(cache=True, nogil=True)
def _bin(sign: np.ndarray, box: np.ndarray, ty: int, tx: int) -> tuple:
    """Bin triangles into tiles per zone, keeping their input order within each tile.

    Serial: it is a small part of the cost, and a parallel kernel compiles slowly.

    Returns
    -------
    tuple
        ``start (Z * ty * tx + 1,)`` offsets into ``items (M,)`` of triangle indices.
    """
    zones, n = sign.shape
    nt = ty * tx
    counts = np.zeros(zones * nt + 1, np.int64)
    for z in range(zones):
        for i in range(n):
            if sign[z, i] == 0.0 or box[z, i, 0] > box[z, i, 1] or box[z, i, 2] > box[z, i, 3]:
                continue
            for yy in range(box[z, i, 0] // TILE, box[z, i, 1] // TILE + 1):
                for xx in range(box[z, i, 2] // TILE, box[z, i, 3] // TILE + 1):
                    counts[z * nt + yy * tx + xx + 1] += 1
    start = np.cumsum(counts)
    items = np.empty(start[-1], np.int64)
    for z in range(zones):
        fill = start[z * nt : (z + 1) * nt].copy()
        for i in range(n):
            if sign[z, i] == 0.0 or box[z, i, 0] > box[z, i, 1] or box[z, i, 2] > box[z, i, 3]:
                continue
            for yy in range(box[z, i, 0] // TILE, box[z, i, 1] // TILE + 1):
                for xx in range(box[z, i, 2] // TILE, box[z, i, 3] // TILE + 1):
                    items[fill[yy * tx + xx]] = i
                    fill[yy * tx + xx] += 1
    return start, items


@nb.njit(cache=True, nogil=True, inline="always")
def _hit(
    wv: np.ndarray, i: int, sg: float, claim: np.ndarray, ox: float, oy: float, t: float
) -> bool:
    """Whether the ray through ``(ox, oy, 0)`` along ``(t, 0, 1)`` hits triangle ``i``."""
    for k in range(3):
        p, q = wv[i, k], wv[i, (k + 1) % 3]
        e = sg * _edge(p[0], p[1], p[2], q[0], q[1], q[2], ox, oy, t)
        if e < 0.0 or (e == 0.0 and not claim[k]):
            return False
    return True


@nb.njit(cache=True, nogil=True, parallel=True)
def _cast(
    wv: np.ndarray,
    rank: np.ndarray,
    znear: np.ndarray,
    sign: np.ndarray,
    claim: np.ndarray,
    plane: np.ndarray,
    box: np.ndarray,
    start: np.ndarray,
    items: np.ndarray,
    shears: np.ndarray,
    geom: np.ndarray,
    tri_out: np.ndarray,
    depth_out: np.ndarray,
) -> None:
    """Cast every pixel's ray against its tile's triangles (tiles in parallel).

    Parameters
    ----------
    wv : ndarray, shape (N, 3, 3)
        World corners, sorted by ``znear`` descending.
    rank : ndarray, shape (N,)
        Position of each candidate in ``order``; written to ``tri_out``, and the
        lower rank wins an exact depth tie.
    znear : ndarray, shape (N,)
        Largest world z of each triangle (its nearest point), non-increasing.
    geom : ndarray, shape (3,)
        ``half_width, half_height, pixel_size``.
    tri_out, depth_out : ndarray, shape (Z, R, C)
    """
    zones, rows, cols = tri_out.shape
    ty, tx = (rows + TILE - 1) // TILE, (cols + TILE - 1) // TILE
    nt = ty * tx
    for job in nb.prange(zones * nt):
        z, tile = job // nt, job % nt
        t = shears[z]
        lo, hi = start[job], start[job + 1]
        r0, c0 = (tile // tx) * TILE, (tile % tx) * TILE
        for r in range(r0, min(r0 + TILE, rows)):
            oy = geom[1] - (r + 0.5) * geom[2]
            for c in range(c0, min(c0 + TILE, cols)):
                ox = (c + 0.5) * geom[2] - geom[0]
                best_z, best = -np.inf, -1
                for j in range(lo, hi):
                    i = items[j]
                    if znear[i] < best_z:
                        break  # sorted: nothing further down can be nearer
                    b = box[z, i]
                    if r < b[0] or r > b[1] or c < b[2] or c > b[3]:
                        continue
                    if not _hit(wv, i, sign[z, i], claim[z, i], ox, oy, t):
                        continue
                    hz = plane[z, i, 0] + plane[z, i, 1] * ox + plane[z, i, 2] * oy
                    if hz > best_z or (hz == best_z and rank[i] < rank[best]):
                        best_z, best = hz, i
                if best >= 0:
                    tri_out[z, r, c] = rank[best]
                    depth_out[z, r, c] = -best_z


def raycast(
    scene: SceneArrays, proj: np.ndarray, display: DisplaySettings, order: np.ndarray
) -> Visibility:
    """Per-pixel ray casting in world space (the accuracy reference).

    Parameters
    ----------
    scene : SceneArrays
        World-space geometry; ``scene.triangles`` (T, 3) indexes ``scene.vertices`` (V, 3).
    proj : ndarray, shape (Z, V, 3)
        Projected vertices; unused (the rays are cast in world space), taken so that
        every occlusion method has the same signature.
    display : DisplaySettings
    order : ndarray, shape (N,), int
        Candidate triangles, nearest first; earlier wins exact depth ties.

    Returns
    -------
    Visibility
        ``triangle`` (Z, R, C) int32 scene triangle index or -1; ``depth`` (Z, R, C)
        float32 ``-z`` or +inf; ``stats`` with ``candidates``, ``bin_entries``, ``ms``.
    """
    t0 = time.perf_counter()
    vis = Visibility.empty(display.zones, display.rows, display.cols)
    order = np.asarray(order, np.int64).reshape(-1)
    wv = scene.vertices[scene.triangles[order]] if order.size else np.zeros((0, 3, 3))
    znear = wv[:, :, 2].max(axis=1) if order.size else np.zeros(0)
    # nearest point first; stable, so equal znear keeps the given order
    srt = np.argsort(-znear, kind="stable")
    wv, znear = np.ascontiguousarray(wv[srt]), np.ascontiguousarray(znear[srt])
    rank = np.ascontiguousarray(srt.astype(np.int64))  # tie rank = position in order
    shears = display.shears()
    geom = np.array([display.width / 2, display.height / 2, display.pixel_size])
    sign, claim, plane, box = _setup(wv, shears, geom, display.rows, display.cols)
    ty, tx = -(-display.rows // TILE), -(-display.cols // TILE)
    start, items = _bin(sign, box, ty, tx)
    tri_rank = np.full(vis.triangle.shape, -1, np.int32)
    _cast(wv, rank, znear, sign, claim, plane, box, start, items, shears, geom, tri_rank, vis.depth)
    hit = tri_rank >= 0
    vis.triangle[hit] = order[tri_rank[hit]]
    vis.stats = {
        "candidates": int(order.size),
        "bin_entries": int(items.size),
        "ms": (time.perf_counter() - t0) * 1e3,
    }
    return vis
