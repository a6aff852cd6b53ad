"""The Poisson test (equation 34) and the expansion sweep (seed 002, section 3.1).

Inside one smooth surface the depth map z(x, y) is locally a plane, so its
Laplacian vanishes; where two surfaces abut it has a source.  On the pixel grid

    lap z(x0, y0) = z(x0+1, y0) + z(x0-1, y0) + z(x0, y0+1) + z(x0, y0-1) - 4 z(x0, y0)   (34)

and the **Poisson flag** of a pixel is 1 ("yes, a source": an edge) when
``|lap z| > threshold``, when any of the five pixels is debris or empty (depth
``Z_EMPTY``, or +inf in a float map), and on the map's border; 0 inside a surface.

The **second sweep** scans the new map for debris.  A debris pixel is *expanded*
when a neighbour (left; optionally also up, right, down) is a galpixel propagated
this refresh whose origin in the old map (its reverse propagation, which the first
sweep recorded exactly) had Poisson flag 0: the debris lies inside an expanding
surface.  It is then filled by replicating that neighbour (``"replicate"``: colour,
depth, derivatives and all, fraction zeroed) or by averaging the colour and depth
of all qualifying neighbours (``"average"``; motion from the first).  Otherwise the
debris stays (a just-unobscured pixel).  As in the paper's sequential scan, an
expanded pixel inherits its neighbour's origin and so can qualify the pixels after
it (this fills the corners where a row gap meets a column gap); a run of debris
next to an *edge* galpixel is never started.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from service.galilean.fixed_point import Z_EMPTY

#: Expansion mode name -> kernel code.
EXPANSION_MODES: dict[str, int] = {"replicate": 0, "average": 1}

#: Neighbour offsets (dr, dc) in the order they are consulted: left, up, right, down.
NEIGHBOURS = np.array([[0, -1], [-1, 0], [0, 1], [1, 0]], np.int64)


@nb.njit(cache=True, inline="always")
def poisson_flag(depth: np.ndarray, debris: np.ndarray, z: int, r: int, c: int,
                 threshold: float) -> int:
    """Poisson flag of pixel (z, r, c): 1 for a source/edge/debris/border, 0 interior."""
    h, w = depth.shape[1], depth.shape[2]
    if r == 0 or c == 0 or r == h - 1 or c == w - 1:
        return 1
    if (debris[z, r, c] | debris[z, r, c - 1] | debris[z, r, c + 1]
            | debris[z, r - 1, c] | debris[z, r + 1, c]):
        return 1
    d0, d1, d2 = depth[z, r, c], depth[z, r, c + 1], depth[z, r, c - 1]
    d3, d4 = depth[z, r + 1, c], depth[z, r - 1, c]
    if d0 == Z_EMPTY or d1 == Z_EMPTY or d2 == Z_EMPTY or d3 == Z_EMPTY or d4 == Z_EMPTY:
        return 1  # fixed-point depth: empty
    lap = d1 + d2 + d3 + d4 - 4 * d0  # int64 for a fixed-point map (exact)
    if not np.isfinite(np.float64(lap)) or abs(lap) > threshold:
        return 1
    return 0


@nb.njit(cache=True)
def poisson_map(depth: np.ndarray, debris: np.ndarray, threshold: float) -> np.ndarray:
    """Poisson flag map of a whole map.

    Parameters
    ----------
    depth : ndarray, shape (Z, H, W), int32 (fixed point, ``Z_EMPTY`` empty) or float
    debris : ndarray, shape (Z, H, W), uint8
    threshold : float
        In the depth array's units (``poisson_threshold * 2^fz`` for a galpixmap).

    Returns
    -------
    ndarray, shape (Z, H, W), uint8
    """
    out = np.empty(depth.shape, np.uint8)
    for z in range(depth.shape[0]):
        for r in range(depth.shape[1]):
            for c in range(depth.shape[2]):
                out[z, r, c] = poisson_flag(depth, debris, z, r, c, threshold)
    return out


@nb.njit(cache=True)
def expand_pixel(
    new: tuple, src_idx: np.ndarray, old_depth: np.ndarray, old_debris: np.ndarray,
    threshold: float, z: int, r: int, c: int, n_neighbours: int, mode: int,
) -> bool:
    """Try to expand into debris pixel (z, r, c) of the new map; True if filled.

    A neighbour qualifies when it is a galpixel (not debris) whose origin ``src_idx``
    in the old map passes the Poisson test there (flag 0, surface interior); the
    flag is evaluated on demand from the old map's depth and debris.
    """
    h, w = src_idx.shape[1], src_idx.shape[2]
    col, dep, frac, deb = new[0], new[1], new[2], new[6]
    first, n = -1, 0
    acc0 = acc1 = acc2 = accd = 0.0
    for k in range(n_neighbours):
        rr, cc = r + NEIGHBOURS[k, 0], c + NEIGHBOURS[k, 1]
        if rr < 0 or cc < 0 or rr >= h or cc >= w or deb[z, rr, cc] == 1:
            continue
        s = src_idx[z, rr, cc]
        if s < 0 or poisson_flag(old_depth, old_debris, z, s // w, s % w, threshold) == 1:
            continue
        if first < 0:
            first = rr * w + cc
        n += 1
        acc0 += col[0, z, rr, cc]
        acc1 += col[1, z, rr, cc]
        acc2 += col[2, z, rr, cc]
        accd += np.float64(dep[z, rr, cc])
    if first < 0:
        return False
    _replicate(new, z, first // w, first % w, r, c)
    if mode == 1:
        col[0, z, r, c] = acc0 / n
        col[1, z, r, c] = acc1 / n
        col[2, z, r, c] = acc2 / n
        dep[z, r, c] = np.floor(accd / n + 0.5)  # round half up (fixed-point depth)
    frac[0, z, r, c] = 0
    frac[1, z, r, c] = 0
    src_idx[z, r, c] = src_idx[z, first // w, first % w]
    return True


@nb.njit(cache=True, inline="always")
def _replicate(m: tuple, z: int, r: int, c: int, qr: int, qc: int) -> None:
    """Copy every field of galpixel (z, r, c) to (z, qr, qc) of the same map."""
    for k in range(3):
        m[0][k, z, qr, qc] = m[0][k, z, r, c]
    m[1][z, qr, qc] = m[1][z, r, c]
    for k in range(m[3].shape[0]):
        m[3][k, z, qr, qc] = m[3][k, z, r, c]
    for k in range(m[4].shape[0]):
        m[4][k, z, qr, qc] = m[4][k, z, r, c]
    for k in range(m[5].shape[0]):
        m[5][k, z, qr, qc] = m[5][k, z, r, c]
    m[6][z, qr, qc] = 0
    m[7][z, qr, qc] = m[7][z, r, c]
