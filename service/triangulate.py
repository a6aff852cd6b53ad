"""Ear-clipping triangulation of polygons that a fan would get wrong.

A fan from corner 0 is right only for a planar, convex polygon.  A concave polygon,
or one whose corners are off a common plane (exporters write quads that are), is
split here by ear clipping in its best-fit plane (:mod:`service.triangulate_kernel`):
``n`` corners always give ``n - 2`` triangles, wound as the polygon is.
"""

from __future__ import annotations

import numpy as np

from service.triangulate_kernel import ear_clip_2d, ear_clip_polygons


def ear_clip(points: np.ndarray) -> np.ndarray:
    """Triangulate one simple polygon given in the plane.

    Parameters
    ----------
    points : ndarray, shape (n, 2)
        Corners in order, either winding, ``n >= 3``.

    Returns
    -------
    ndarray, shape (n - 2, 3), int64
        Corner indices of each triangle, in the polygon's own winding.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    x, y = pts[:, 0].copy(), pts[:, 1].copy()
    area = float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
    out = np.empty((pts.shape[0] - 2, 3), np.int64)
    ear_clip_2d(x, -y if area < 0 else y, out)
    return out


def triangulate_rows(
    vertices: np.ndarray, polygons: np.ndarray, counts: np.ndarray, rows: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Ear-clip the chosen polygons of a mesh in their best-fit planes.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
    polygons : ndarray, shape (P, K), padded with -1
    counts : ndarray, shape (P,)
    rows : ndarray, shape (S,)
        The polygons to split.

    Returns
    -------
    triangles : ndarray, shape (sum(counts[rows] - 2), 3), int64
        Vertex indices, polygon by polygon in ``rows`` order.
    first : ndarray, shape (S + 1,), int64
        Where each polygon's triangles start (``first[-1]`` is their number).
    """
    rows = np.asarray(rows, dtype=np.int64)
    first = np.zeros(rows.size + 1, np.int64)
    np.cumsum(counts[rows] - 2, out=first[1:])
    tri = ear_clip_polygons(
        np.ascontiguousarray(vertices, dtype=np.float64),
        np.ascontiguousarray(polygons, dtype=np.int64),
        np.ascontiguousarray(counts, dtype=np.int64), rows, first,
    )
    return tri, first
