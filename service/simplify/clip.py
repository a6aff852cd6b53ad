"""Cut triangles by a slab ``|n . x - rho| <= eps`` (for the billboard greedy).

A face on the rim of a plane's slab is only partly within EPS of the plane; left
whole, such faces form a ring around every collapsed region, and the rings end up on
a tail of small planes.  Cutting them instead gives the part inside the slab to the
plane and leaves the parts outside (at most two polygons, one each side) to later
planes, so the regions tile the surface.
"""

from __future__ import annotations

import numpy as np


def _clip(points: list, dist: list, keep_below: float, sign: float) -> tuple[list, list]:
    """Sutherland-Hodgman: the part of a convex polygon where ``sign * dist <= keep_below``."""
    out_p, out_d = [], []
    n = len(points)
    for i in range(n):
        p, q = points[i], points[(i + 1) % n]
        dp, dq = dist[i], dist[(i + 1) % n]
        inside_p = sign * dp <= keep_below
        inside_q = sign * dq <= keep_below
        if inside_p:
            out_p.append(p)
            out_d.append(dp)
        if inside_p != inside_q:
            t = (keep_below - sign * dp) / (sign * dq - sign * dp)
            out_p.append(p + t * (q - p))
            out_d.append(dp + t * (dq - dp))
    return out_p, out_d


def _fan(poly: list) -> list:
    return [(poly[0], poly[i], poly[i + 1]) for i in range(1, len(poly) - 1)]


def cut_triangle(corners: np.ndarray, dist: np.ndarray, eps: float) -> tuple[list, list]:
    """Pieces of a triangle inside and outside the slab ``|dist| <= eps``.

    Parameters
    ----------
    corners : ndarray, shape (3, 3)
    dist : ndarray, shape (3,)
        Signed distance of each corner to the plane.
    eps : float

    Returns
    -------
    inside, outside : lists of (3, 3) corner triples
        Triangles (fans of the clipped polygons) in the slab, and out of it.
    """
    pts = [corners[i] for i in range(3)]
    ds = [float(x) for x in dist]
    mid_p, mid_d = _clip(pts, ds, eps, 1.0)
    mid_p, mid_d = _clip(mid_p, mid_d, eps, -1.0) if mid_p else ([], [])
    above = _clip(pts, ds, -eps, -1.0)[0]  # dist >= eps
    below = _clip(pts, ds, -eps, 1.0)[0]   # dist <= -eps
    inside = _fan(mid_p) if len(mid_p) >= 3 else []
    outside = (_fan(above) if len(above) >= 3 else []) + (_fan(below) if len(below) >= 3 else [])
    return inside, outside


def cut_faces(v: np.ndarray, f: np.ndarray, ids: np.ndarray, d: np.ndarray, rho: float,
              eps: float, min_area: float) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                     np.ndarray]:
    """Cut faces ``ids`` by the slab of plane ``d . x = rho``.

    Returns
    -------
    corners : ndarray, shape (K, 3, 3)
        The pieces (each a new triangle with its own three new vertices).
    inside : ndarray, shape (K,), bool
        Whether each piece lies in the slab.
    parent : ndarray, shape (K,), int64
        The face each piece came from.
    cut : ndarray, shape (N,), bool
        Which of ``ids`` were cut into more than one piece (the others stay whole).

    Pieces thinner than ``min_area`` are dropped (their area is far below a texel).
    """
    tri, inside, parent = [], [], []
    cut = np.zeros(ids.shape[0], bool)
    inner = eps * (1.0 - 1e-9)  # so the pieces inside pass the <= eps test exactly
    for q, fid in enumerate(ids):
        c = v[f[fid]]
        ins, outs = cut_triangle(c, c @ d - rho, inner)
        pieces = [(t, True) for t in ins] + [(t, False) for t in outs]
        kept = [(np.array(t), k) for t, k in pieces
                if np.linalg.norm(np.cross(t[1] - t[0], t[2] - t[0])) > 2 * min_area]
        if not ins or not outs or not kept:
            continue
        cut[q] = True
        for t, k in kept:
            tri.append(t)
            inside.append(k)
            parent.append(fid)
    if not tri:
        return np.zeros((0, 3, 3)), np.zeros(0, bool), np.zeros(0, np.int64), cut
    return np.array(tri), np.array(inside), np.array(parent, np.int64), cut
