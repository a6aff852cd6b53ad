"""Minimal-area bounding rectangle of points in a plane (convex hull + rotating calipers).

The smallest rectangle holding a convex polygon has a side on one of its edges
(Freeman and Shapira 1975), so trying every hull edge's direction is exact.
"""

from __future__ import annotations

import numpy as np


def convex_hull(points: np.ndarray) -> np.ndarray:
    """Convex hull of 2-D points (Andrew's monotone chain), counter-clockwise, shape (H, 2)."""
    pts = np.unique(np.asarray(points, dtype=np.float64), axis=0)
    if pts.shape[0] < 3:
        return pts

    def half(seq: np.ndarray) -> list:
        out: list = []
        for p in seq:
            while len(out) >= 2 and ((out[-1][0] - out[-2][0]) * (p[1] - out[-2][1])
                                     - (out[-1][1] - out[-2][1]) * (p[0] - out[-2][0])) <= 0:
                out.pop()
            out.append(p)
        return out

    lower, upper = half(pts), half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1])


def min_area_rectangle(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Smallest rectangle holding 2-D points (N, 2), N >= 1.

    Returns
    -------
    origin : ndarray, shape (2,)
        The corner from which both sides run.
    axes : ndarray, shape (2, 2)
        Unit side directions (rows; the second is the first turned +90 degrees).
    size : ndarray, shape (2,)
        Side lengths along ``axes`` (either may be 0 for collinear points).
    """
    hull = convex_hull(points)
    edges = np.roll(hull, -1, axis=0) - hull
    lengths = np.linalg.norm(edges, axis=1)
    dirs = edges[lengths > 0] / lengths[lengths > 0, None]
    if dirs.shape[0] == 0:
        dirs = np.array([[1.0, 0.0]])
    perp = np.stack([-dirs[:, 1], dirs[:, 0]], axis=1)
    a = hull @ dirs.T  # (H, E)
    b = hull @ perp.T
    span_a = a.max(0) - a.min(0)
    span_b = b.max(0) - b.min(0)
    e = int(np.argmin(span_a * span_b))
    axes = np.stack([dirs[e], perp[e]])
    origin = a[:, e].min() * dirs[e] + b[:, e].min() * perp[e]
    return origin, axes, np.array([span_a[e], span_b[e]])
