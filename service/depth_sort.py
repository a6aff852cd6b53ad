"""Stage 3: depth sort by average z, nearest first (thesis section 2.1.2).

The thesis sorts with heapsort for its small memory use.  We use numpy's stable
sort (``np.argsort(kind="stable")``, a radix/merge sort) instead: one vectorised call,
and stability gives the thesis's tie rule for free: polygons with equal average z
keep their list order, which is object order, so the earlier object takes
precedence (thesis section 3.2).  One sort serves every zone: under the zones'
parallel projections depth along every view ray is -z.
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True, nogil=True)
def average_z(vertices: np.ndarray, polygons: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Average z of each polygon's vertices.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
    polygons : ndarray, shape (P, K), padded with -1
    counts : ndarray, shape (P,)

    Returns
    -------
    ndarray, shape (P,), float64
    """
    out = np.empty(polygons.shape[0])
    for p in range(polygons.shape[0]):
        s = 0.0
        for k in range(counts[p]):
            s += vertices[polygons[p, k], 2]
        out[p] = s / counts[p]
    return out


def sort_polygons(avg_z: np.ndarray, keep: np.ndarray | None = None) -> np.ndarray:
    """Polygon indices from nearest (highest average z) to farthest.

    Parameters
    ----------
    avg_z : ndarray, shape (P,)
    keep : ndarray, shape (P,), bool, optional
        Polygons that survived the cull; others are left out.

    Returns
    -------
    ndarray, shape (N,), int64
        Ties keep polygon (object) order.
    """
    idx = np.arange(avg_z.shape[0]) if keep is None else np.nonzero(keep)[0]
    # a stable sort of ascending indices keeps equal keys in index (object) order
    return idx[np.argsort(-avg_z[idx], kind="stable")].astype(np.int64)


def triangle_order(polygon_order: np.ndarray, triangle_polygon: np.ndarray) -> np.ndarray:
    """Expand a polygon order into the order of their (fan) triangles.

    Parameters
    ----------
    polygon_order : ndarray, shape (N,)
    triangle_polygon : ndarray, shape (T,)
        Polygon of each triangle; a polygon's triangles are contiguous.

    Returns
    -------
    ndarray, shape (M,), int64
    """
    return _triangle_order(
        np.ascontiguousarray(polygon_order, np.int64),
        np.ascontiguousarray(triangle_polygon, np.int64),
    )


@nb.njit(cache=True, nogil=True)
def _triangle_order(polygon_order: np.ndarray, triangle_polygon: np.ndarray) -> np.ndarray:
    """Numba body of :func:`triangle_order`."""
    n_poly = triangle_polygon.max() + 1 if triangle_polygon.size else 0
    first = np.full(n_poly + 1, 0, np.int64)
    for t in range(triangle_polygon.size):
        first[triangle_polygon[t] + 1] += 1
    for p in range(n_poly):
        first[p + 1] += first[p]
    total = 0
    for p in polygon_order:
        total += first[p + 1] - first[p]
    out = np.empty(total, np.int64)
    i = 0
    for p in polygon_order:
        for t in range(first[p], first[p + 1]):
            out[i] = t
            i += 1
    return out
