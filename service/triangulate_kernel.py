"""Numba kernels for ear-clipping triangulation (see :mod:`service.triangulate`).

A polygon is projected onto its best-fit plane (Newell normal, or for a polygon whose
net area is nearly zero, the plane through its diameter and its farthest corner) and
clipped ear by ear in two dimensions.  Every polygon of ``n`` corners gives exactly
``n - 2`` triangles, wound as the polygon is: when no proper ear exists (a
self-intersecting outline, collinear corners) the most convex corner is clipped.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from service.numba_subroutine import subroutine


@nb.njit(cache=True, nogil=True)
def _cross2(ax: float, ay: float, bx: float, by: float, cx: float, cy: float) -> float:
    """Twice the signed area of triangle a, b, c (positive when counter-clockwise)."""
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


@subroutine(nrt=True)
def _is_ear(x: np.ndarray, y: np.ndarray, ring: np.ndarray, m: int, i: int) -> bool:
    """Whether corner ``ring[i]`` of the ``m`` left is a convex corner with no other inside."""
    a, b, c = ring[(i - 1) % m], ring[i], ring[(i + 1) % m]
    if _cross2(x[a], y[a], x[b], y[b], x[c], y[c]) <= 0.0:
        return False
    for j in range(m):
        p = ring[j]
        if p == a or p == b or p == c:
            continue
        px, py = x[p], y[p]
        if (px == x[a] and py == y[a]) or (px == x[b] and py == y[b]) or (
                px == x[c] and py == y[c]):
            continue  # a repeated corner touches the ear only at its own corner
        if (_cross2(x[a], y[a], x[b], y[b], px, py) >= 0.0
                and _cross2(x[b], y[b], x[c], y[c], px, py) >= 0.0
                and _cross2(x[c], y[c], x[a], y[a], px, py) >= 0.0):
            return False
    return True


@nb.njit(cache=True, nogil=True)
def ear_clip_2d(x: np.ndarray, y: np.ndarray, out: np.ndarray) -> None:
    """Ear-clip a counter-clockwise polygon into ``out``, shape (n - 2, 3) local indices.

    ``x``, ``y`` (n,) are the corners in order.  Triangles keep the polygon's order
    (each is counter-clockwise when the polygon is simple and counter-clockwise).
    """
    n = x.shape[0]
    ring = np.arange(n)
    m, t = n, 0
    while m > 3:
        pick = -1
        for i in range(m):
            if _is_ear(x, y, ring, m, i):
                pick = i
                break
        if pick < 0:  # no proper ear: clip the most convex corner
            best = -np.inf
            for i in range(m):
                a, b, c = ring[(i - 1) % m], ring[i], ring[(i + 1) % m]
                turn = _cross2(x[a], y[a], x[b], y[b], x[c], y[c])
                if turn > best:
                    best, pick = turn, i
        out[t, 0] = ring[(pick - 1) % m]
        out[t, 1] = ring[pick]
        out[t, 2] = ring[(pick + 1) % m]
        t += 1
        for j in range(pick, m - 1):
            ring[j] = ring[j + 1]
        m -= 1
    out[t, 0], out[t, 1], out[t, 2] = ring[0], ring[1], ring[2]


@subroutine(nrt=True)
def _plane_normal(pts: np.ndarray) -> tuple[float, float, float]:
    """Best-fit plane normal of corners ``pts`` (n, 3): Newell's, or a fallback if tiny.

    Scalars only, no array expressions: numba compiles each of those (array
    subtraction, division, ``sum(axis=0)``) as code of its own, which cost most of
    this file's compile time and nothing here needs.
    """
    n = pts.shape[0]
    nx, ny, nz = 0.0, 0.0, 0.0
    for i in range(n):
        j = (i + 1) % n
        nx += (pts[i, 1] - pts[j, 1]) * (pts[i, 2] + pts[j, 2])
        ny += (pts[i, 2] - pts[j, 2]) * (pts[i, 0] + pts[j, 0])
        nz += (pts[i, 0] - pts[j, 0]) * (pts[i, 1] + pts[j, 1])
    # the diameter, and the corner farthest from its line
    bi, bj, diam2 = 0, 0, 0.0
    for i in range(n):
        for j in range(i + 1, n):
            d0, d1, d2 = pts[j, 0] - pts[i, 0], pts[j, 1] - pts[i, 1], pts[j, 2] - pts[i, 2]
            dd = d0 * d0 + d1 * d1 + d2 * d2
            if dd > diam2:
                bi, bj, diam2 = i, j, dd
    length = np.sqrt(nx * nx + ny * ny + nz * nz)
    if length > 1e-9 * diam2:
        return nx / length, ny / length, nz / length
    a0, a1, a2 = pts[bj, 0] - pts[bi, 0], pts[bj, 1] - pts[bi, 1], pts[bj, 2] - pts[bi, 2]
    b0, b1, b2 = 0.0, 0.0, 0.0
    best_len = 0.0
    for k in range(n):
        p0, p1, p2 = pts[k, 0] - pts[bi, 0], pts[k, 1] - pts[bi, 1], pts[k, 2] - pts[bi, 2]
        c0, c1, c2 = a1 * p2 - a2 * p1, a2 * p0 - a0 * p2, a0 * p1 - a1 * p0
        cl = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
        if cl > best_len:
            b0, b1, b2, best_len = c0, c1, c2, cl
    if best_len == 0.0:
        return 0.0, 0.0, 1.0  # all on one line: any plane through it
    return b0 / best_len, b1 / best_len, b2 / best_len


@subroutine(nrt=True)
def _project(pts: np.ndarray, n0: float, n1: float, n2: float, x: np.ndarray,
             y: np.ndarray) -> None:
    """2-D coordinates of ``pts`` (n, 3) in a right-handed basis (u, v) of the plane.

    The normal is ``(n0, n1, n2)``; ``u`` is it crossed with the axis it is least along
    (the first such, NaN first, as ``np.argmin``); written into ``x``, ``y`` (n,).
    """
    m, k = abs(n0), 0
    a = abs(n1)
    if not np.isnan(m) and (a < m or np.isnan(a)):
        m, k = a, 1
    a = abs(n2)
    if not np.isnan(m) and (a < m or np.isnan(a)):
        k = 2
    x0, x1, x2 = 1.0 if k == 0 else 0.0, 1.0 if k == 1 else 0.0, 1.0 if k == 2 else 0.0
    u0, u1, u2 = n1 * x2 - n2 * x1, n2 * x0 - n0 * x2, n0 * x1 - n1 * x0
    ul = np.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
    u0, u1, u2 = u0 / ul, u1 / ul, u2 / ul
    v0, v1, v2 = n1 * u2 - n2 * u1, n2 * u0 - n0 * u2, n0 * u1 - n1 * u0
    for i in range(pts.shape[0]):
        x[i] = pts[i, 0] * u0 + pts[i, 1] * u1 + pts[i, 2] * u2
        y[i] = pts[i, 0] * v0 + pts[i, 1] * v1 + pts[i, 2] * v2


@nb.njit(cache=True, nogil=True)
def ear_clip_polygons(
    vertices: np.ndarray, polygons: np.ndarray, counts: np.ndarray, rows: np.ndarray,
    first: np.ndarray,
) -> np.ndarray:
    """Ear-clip polygons ``rows`` of a mesh in their best-fit planes.

    ``vertices`` (V, 3), ``polygons`` (P, K) padded, ``counts`` (P,), ``rows`` (S,)
    the polygons to split, ``first`` (S + 1,) where each one's triangles start
    (cumulative ``counts[rows] - 2``).  Returns vertex indices, shape (first[-1], 3).
    """
    out = np.empty((first[-1], 3), np.int64)
    for s in range(rows.shape[0]):
        r = rows[s]
        k = counts[r]
        pts = np.empty((k, 3))
        for c in range(3):
            total = 0.0  # the corners' mean, summed in order (as ``sum(axis=0)``)
            for i in range(k):
                pts[i, c] = vertices[polygons[r, i], c]
                total += pts[i, c]
            centre = total / k
            for i in range(k):
                pts[i, c] -= centre
        n0, n1, n2 = _plane_normal(pts)
        x = np.empty(k)
        y = np.empty(k)
        _project(pts, n0, n1, n2, x, y)
        area = 0.0
        for i in range(k):
            area += x[i] * y[(i + 1) % k] - x[(i + 1) % k] * y[i]
        if area < 0.0:  # a fallback normal may face the other way
            for i in range(k):
                y[i] = -y[i]
        local = np.empty((k - 2, 3), np.int64)
        ear_clip_2d(x, y, local)
        for t in range(k - 2):
            for c in range(3):
                out[first[s] + t, c] = polygons[r, local[t, c]]
    return out
