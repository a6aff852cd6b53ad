"""Stage 3: depth sort by average z, nearest first (thesis section 2.1.2).

The thesis sorts with heapsort for its small memory use.  We use numpy's stable
sort (``np.lexsort``, a radix/merge sort) instead: it is a single vectorised call,
and stability gives the thesis's tie rule for free: polygons with equal average z
keep their list order, which is object order, so the earlier object takes
precedence (thesis section 3.2).  One sort serves every zone: under the zones'
parallel projections depth along every view ray is -z.
"""

from __future__ import annotations

import numpy as np

from service.mesh import polygon_mean


def average_z(vertices: np.ndarray, polygons: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Average z of each polygon's vertices, shape (P,)."""
    return polygon_mean(vertices[:, 2], polygons, counts)


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
    return idx[np.lexsort((idx, -avg_z[idx]))].astype(np.int64)


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
    n_poly = int(triangle_polygon.max()) + 1 if triangle_polygon.size else 0
    per = np.bincount(triangle_polygon, minlength=n_poly)
    first = np.concatenate([[0], np.cumsum(per)[:-1]])
    counts = per[polygon_order]
    starts = np.repeat(first[polygon_order], counts)
    offs = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    return (starts + offs).astype(np.int64)
