"""Numba kernels: distance from points to a triangle soup (see :mod:`.distance`).

Triangles are bucketed by bounding box into a uniform grid of about T cells; each
point searches shells of cells around its own until no unvisited cell can be nearer
than the best triangle found (a triangle is tested only when its box is nearer).
:func:`nearest_facing` also says which triangle, among those facing a given way
(:mod:`.carry` carries a full mesh's normals to its simplified levels with it).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from service.numba_subroutine import subroutine


@subroutine(nrt=True)
def _point_triangle_sq(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> float:
    """Squared distance from point ``p`` to triangle ``a b c`` (Ericson, RTCD 5.1.5)."""
    ab0, ab1, ab2 = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    ac0, ac1, ac2 = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    ap0, ap1, ap2 = p[0] - a[0], p[1] - a[1], p[2] - a[2]
    d1 = ab0 * ap0 + ab1 * ap1 + ab2 * ap2
    d2 = ac0 * ap0 + ac1 * ap1 + ac2 * ap2
    q0, q1, q2 = a[0], a[1], a[2]
    if d1 <= 0.0 and d2 <= 0.0:
        pass
    else:
        bp0, bp1, bp2 = p[0] - b[0], p[1] - b[1], p[2] - b[2]
        d3 = ab0 * bp0 + ab1 * bp1 + ab2 * bp2
        d4 = ac0 * bp0 + ac1 * bp1 + ac2 * bp2
        cp0, cp1, cp2 = p[0] - c[0], p[1] - c[1], p[2] - c[2]
        d5 = ab0 * cp0 + ab1 * cp1 + ab2 * cp2
        d6 = ac0 * cp0 + ac1 * cp1 + ac2 * cp2
        vc = d1 * d4 - d3 * d2
        vb = d5 * d2 - d1 * d6
        va = d3 * d6 - d5 * d4
        if d3 >= 0.0 and d4 <= d3:
            q0, q1, q2 = b[0], b[1], b[2]
        elif d6 >= 0.0 and d5 <= d6:
            q0, q1, q2 = c[0], c[1], c[2]
        elif vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
            v = d1 / (d1 - d3)
            q0, q1, q2 = a[0] + v * ab0, a[1] + v * ab1, a[2] + v * ab2
        elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
            w = d2 / (d2 - d6)
            q0, q1, q2 = a[0] + w * ac0, a[1] + w * ac1, a[2] + w * ac2
        elif va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
            w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
            q0 = b[0] + w * (c[0] - b[0])
            q1 = b[1] + w * (c[1] - b[1])
            q2 = b[2] + w * (c[2] - b[2])
        else:
            den = va + vb + vc
            if den <= 0.0:  # degenerate triangle: nearest of its corners is close enough
                q0, q1, q2 = a[0], a[1], a[2]
            else:
                v = vb / den
                w = vc / den
                q0 = a[0] + ab0 * v + ac0 * w
                q1 = a[1] + ab1 * v + ac1 * w
                q2 = a[2] + ab2 * v + ac2 * w
    e0, e1, e2 = p[0] - q0, p[1] - q1, p[2] - q2
    return e0 * e0 + e1 * e1 + e2 * e2


@subroutine(nrt=True)
def _box_sq(p: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float:
    """Squared distance from ``p`` to the axis-aligned box ``lo``..``hi``."""
    s = 0.0
    for k in range(3):
        if p[k] < lo[k]:
            s += (lo[k] - p[k]) ** 2
        elif p[k] > hi[k]:
            s += (p[k] - hi[k]) ** 2
    return s


@subroutine(nrt=True)
def _build_grid(lo: np.ndarray, hi: np.ndarray, origin: np.ndarray, h: np.ndarray,
                res: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bucket triangle boxes ``lo``..``hi`` (T, 3) into a grid: CSR (start, items)."""
    t = lo.shape[0]
    ncell = res[0] * res[1] * res[2]
    rng = np.empty((t, 6), dtype=np.int64)
    count = np.zeros(ncell + 1, dtype=np.int64)
    for j in range(t):
        for k in range(3):
            rng[j, k] = min(max(int((lo[j, k] - origin[k]) / h[k]), 0), res[k] - 1)
            rng[j, 3 + k] = min(max(int((hi[j, k] - origin[k]) / h[k]), 0), res[k] - 1)
        for x in range(rng[j, 0], rng[j, 3] + 1):
            for y in range(rng[j, 1], rng[j, 4] + 1):
                for z in range(rng[j, 2], rng[j, 5] + 1):
                    count[(x * res[1] + y) * res[2] + z + 1] += 1
    for c in range(ncell):
        count[c + 1] += count[c]
    fill = count[:-1].copy()
    items = np.empty(count[-1], dtype=np.int64)
    for j in range(t):
        for x in range(rng[j, 0], rng[j, 3] + 1):
            for y in range(rng[j, 1], rng[j, 4] + 1):
                for z in range(rng[j, 2], rng[j, 5] + 1):
                    c = (x * res[1] + y) * res[2] + z
                    items[fill[c]] = j
                    fill[c] += 1
    return count, items


@subroutine(nrt=True)
def _nearest(p: np.ndarray, facing: np.ndarray, corners: np.ndarray, normals: np.ndarray,
             grid: tuple, best: float) -> tuple[float, int]:
    """Squared distance from ``p`` to the nearest triangle, and which, searching shells.

    A triangle whose ``normals[j]`` points against ``facing`` (3,) (a negative dot
    product) is skipped; a zero ``facing`` skips none.  ``grid`` is :func:`_grid`'s.
    Returns ``(inf, -1)`` when no triangle qualifies.
    """
    lo, hi, origin, h, res, start, items = grid
    # the cell as three scalars (a 3-array here was allocated per point)
    c0 = min(max(int(np.floor((p[0] - origin[0]) / h[0])), 0), res[0] - 1)
    c1 = min(max(int(np.floor((p[1] - origin[1]) / h[1])), 0), res[1] - 1)
    c2 = min(max(int(np.floor((p[2] - origin[2]) / h[2])), 0), res[2] - 1)
    hmin = min(h[0], h[1], h[2])
    rmax = max(res[0], res[1], res[2])
    found = -1
    for r in range(rmax + 1):
        if r > 0 and best <= ((r - 1) * hmin) ** 2:
            break
        for x in range(max(c0 - r, 0), min(c0 + r, res[0] - 1) + 1):
            for y in range(max(c1 - r, 0), min(c1 + r, res[1] - 1) + 1):
                on_shell = abs(x - c0) == r or abs(y - c1) == r
                step = 1 if on_shell else 2 * r
                z = max(c2 - r, 0) if on_shell else c2 - r
                while z <= min(c2 + r, res[2] - 1):
                    if z >= 0:
                        cell = (x * res[1] + y) * res[2] + z
                        for q in range(start[cell], start[cell + 1]):
                            j = items[q]
                            if _box_sq(p, lo[j], hi[j]) >= best:
                                continue
                            if (facing[0] * normals[j, 0] + facing[1] * normals[j, 1]
                                    + facing[2] * normals[j, 2]) < 0.0:
                                continue
                            d = _point_triangle_sq(p, corners[j, 0], corners[j, 1],
                                                   corners[j, 2])
                            if d < best:
                                best = d
                                found = j
                    z += max(step, 1)
    return best, found


@subroutine(nrt=True)
def _column_extreme(a: np.ndarray, k: int, sign: float) -> float:
    """``a[:, k].min()`` (``sign`` -1) or ``.max()`` (1) of ``a`` (n >= 1, m): the first NaN if any.

    As numpy's (and numba's) reduction, written out: numba compiles ``.min()`` and
    ``.max()`` of a strided column as code of their own, for each layout.
    """
    m = a[0, k]
    for i in range(1, a.shape[0]):
        if m != m:
            break
        v = a[i, k]
        if v != v or (v < m if sign < 0.0 else v > m):
            m = v
    return m


@subroutine(nrt=True)
def _grid(corners: np.ndarray) -> tuple:
    """Triangle boxes and the grid of about T cells they are bucketed in.

    Returns ``(lo, hi, origin, h, res, start, items)`` for :func:`_nearest`.
    """
    t = corners.shape[0]
    lo = np.empty((t, 3))
    hi = np.empty((t, 3))
    for j in range(t):
        for k in range(3):
            lo[j, k] = min(corners[j, 0, k], corners[j, 1, k], corners[j, 2, k])
            hi[j, k] = max(corners[j, 0, k], corners[j, 1, k], corners[j, 2, k])
    origin = np.empty(3)
    h = np.empty(3)
    res = np.empty(3, dtype=np.int64)
    side = max(int(np.ceil(t ** (1.0 / 3.0))), 1)
    ext = np.empty((3, 1))  # a column, as lo and hi: one signature of _column_extreme
    for k in range(3):
        origin[k] = _column_extreme(lo, k, -1.0)
        ext[k, 0] = _column_extreme(hi, k, 1.0) - origin[k]
    cell = max(_column_extreme(ext, np.int64(0), 1.0) / side, 1e-12)
    for k in range(3):
        res[k] = max(int(np.ceil(ext[k, 0] / cell)), 1)
        h[k] = max(ext[k, 0] / res[k], cell)
    start, items = _build_grid(lo, hi, origin, h, res)
    return lo, hi, origin, h, res, start, items


@nb.njit(cache=True, nogil=True)
def points_to_triangles(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Distance from each point to the nearest triangle.

    Parameters
    ----------
    points : ndarray, shape (N, 3), float64
    corners : ndarray, shape (T, 3, 3), float64
        Triangle corners; T >= 1.

    Returns
    -------
    ndarray, shape (N,), float64
    """
    grid = _grid(corners)
    anywhere = np.zeros(3)
    normals = np.zeros((corners.shape[0], 3))  # with ``anywhere``: no triangle skipped
    out = np.empty(points.shape[0])
    for i in range(points.shape[0]):
        out[i] = np.sqrt(_nearest(points[i], anywhere, corners, normals, grid, np.inf)[0])
    return out


@nb.njit(cache=True, nogil=True)
def nearest_facing(points: np.ndarray, facing: np.ndarray, corners: np.ndarray,
                   normals: np.ndarray) -> np.ndarray:
    """The nearest triangle to each point among those that face its way.

    Parameters
    ----------
    points : ndarray, shape (N, 3), float64
    facing : ndarray, shape (N, 3), float64
        A direction per point: only triangles whose normal has a non-negative dot
        product with it are candidates (all are when none is).
    corners : ndarray, shape (T, 3, 3), float64
        Triangle corners; T >= 1.
    normals : ndarray, shape (T, 3), float64
        Each triangle's normal.

    Returns
    -------
    ndarray, shape (N,), int64
        Index of the nearest qualifying triangle.
    """
    grid = _grid(corners)
    anywhere = np.zeros(3)
    out = np.empty(points.shape[0], np.int64)
    for i in range(points.shape[0]):
        j = _nearest(points[i], facing[i], corners, normals, grid, np.inf)[1]
        if j < 0:
            j = _nearest(points[i], anywhere, corners, normals, grid, np.inf)[1]
        out[i] = j
    return out
