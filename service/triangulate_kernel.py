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


@nb.njit(cache=True, nogil=True)
def _cross2(ax: float, ay: float, bx: float, by: float, cx: float, cy: float) -> float:
    """Twice the signed area of triangle a, b, c (positive when counter-clockwise)."""
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


@nb.njit(cache=True, nogil=True)
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


@nb.njit(cache=True, nogil=True)
def _dot(a: np.ndarray, b: np.ndarray) -> float:
    """Dot product of two 3-vectors (no BLAS)."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@nb.njit(cache=True, nogil=True)
def _cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product of two 3-vectors."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                     a[0] * b[1] - a[1] * b[0]])


@nb.njit(cache=True, nogil=True)
def _plane_normal(pts: np.ndarray) -> np.ndarray:
    """Best-fit plane normal of corners ``pts`` (n, 3): Newell's, or a fallback if tiny."""
    n = pts.shape[0]
    normal = np.zeros(3)
    for i in range(n):
        p, q = pts[i], pts[(i + 1) % n]
        normal[0] += (p[1] - q[1]) * (p[2] + q[2])
        normal[1] += (p[2] - q[2]) * (p[0] + q[0])
        normal[2] += (p[0] - q[0]) * (p[1] + q[1])
    # the diameter, and the corner farthest from its line
    bi, bj, diam2 = 0, 0, 0.0
    for i in range(n):
        for j in range(i + 1, n):
            d = pts[j] - pts[i]
            dd = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
            if dd > diam2:
                bi, bj, diam2 = i, j, dd
    length = np.sqrt(_dot(normal, normal))
    if length > 1e-9 * diam2:
        return normal / length
    axis = pts[bj] - pts[bi]
    best = np.zeros(3)
    best_len = 0.0
    for k in range(n):
        c = _cross3(axis, pts[k] - pts[bi])
        cl = np.sqrt(_dot(c, c))
        if cl > best_len:
            best, best_len = c, cl
    if best_len == 0.0:
        return np.array([0.0, 0.0, 1.0])  # all on one line: any plane through it
    return best / best_len


@nb.njit(cache=True, nogil=True)
def _project(pts: np.ndarray, normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """2-D coordinates of ``pts`` (n, 3) in a right-handed basis (u, v) of the plane."""
    ax = np.zeros(3)
    ax[np.argmin(np.abs(normal))] = 1.0
    u = _cross3(normal, ax)
    u /= np.sqrt(_dot(u, u))
    v = _cross3(normal, u)
    x = pts[:, 0] * u[0] + pts[:, 1] * u[1] + pts[:, 2] * u[2]
    y = pts[:, 0] * v[0] + pts[:, 1] * v[1] + pts[:, 2] * v[2]
    return x, y


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
        for i in range(k):
            pts[i] = vertices[polygons[r, i]]
        centre = pts.sum(axis=0) / k
        pts -= centre
        x, y = _project(pts, _plane_normal(pts))
        area = 0.0
        for i in range(k):
            area += x[i] * y[(i + 1) % k] - x[(i + 1) % k] * y[i]
        if area < 0.0:  # a fallback normal may face the other way
            y = -y
        local = np.empty((k - 2, 3), np.int64)
        ear_clip_2d(x, y, local)
        for t in range(k - 2):
            for c in range(3):
                out[first[s] + t, c] = polygons[r, local[t, c]]
    return out
