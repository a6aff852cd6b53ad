"""Numba kernels of the billboard-cloud builder (see :mod:`.billboard`).

A face's *valid* offsets for a plane of unit normal ``d`` form the interval
``[hi - eps, lo + eps]`` where ``lo``/``hi`` are the least and greatest ``d . v`` over
its corners (empty when the face is thicker than ``2 eps`` along ``d``).  Its *penalty*
offsets, where the plane misses it by less than another ``eps`` (a near-tangent
plane), are ``[hi - 2 eps, lo + 2 eps]`` less the valid ones.  Both kernels below
write a face's weight as two nested intervals: ``-penalty * w`` over the outer one and
``(1 + penalty) * w`` over the inner one, ``w`` being the face's area projected on
the plane.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from service.numba_subroutine import subroutine

HALF_DIAGONAL = 0.7072
"""Half a texel's diagonal (slightly over sqrt(2) / 2), the slack of conservative cover."""


@nb.njit(cache=True, nogil=True)
def _extent(v: np.ndarray, f: np.ndarray, d: np.ndarray) -> tuple[float, float]:
    """Least and greatest ``d . v`` over the corners of face ``f`` (3,)."""
    lo, hi = np.inf, -np.inf
    for k in range(3):
        i = f[k]
        s = d[0] * v[i, 0] + d[1] * v[i, 1] + d[2] * v[i, 2]
        lo = min(lo, s)
        hi = max(hi, s)
    return lo, hi


@subroutine(nrt=True)
def _add_bins(row: np.ndarray, a: float, b: float, rho0: float, drho: float,
              w: float) -> None:
    """Add ``w`` to every bin of ``row`` whose centre lies in ``[a, b]``."""
    n = row.shape[0]
    k0 = max(int(np.ceil((a - rho0) / drho - 0.5)), 0)
    k1 = min(int(np.floor((b - rho0) / drho - 0.5)), n - 1)
    for k in range(k0, k1 + 1):
        row[k] += w


@nb.njit(cache=True, nogil=True)
def hough_accumulate(v: np.ndarray, faces: np.ndarray, area: np.ndarray, ids: np.ndarray,
                     dirs: np.ndarray, rho0: float, drho: float, eps: float,
                     penalty: float, sign: float, acc: np.ndarray) -> None:
    """Add (``sign`` = 1) or remove (-1) faces ``ids`` from the Hough density ``acc``.

    Parameters
    ----------
    v : ndarray, shape (V, 3), float64
    faces : ndarray, shape (F, 3), int64
    area : ndarray, shape (F, 3), float64
        Area vectors (area times unit normal).
    ids : ndarray, shape (N,), int64
        The faces to add or remove.
    dirs : ndarray, shape (D, 3), float64
        Bin-centre normals.
    rho0, drho : float
        Offset of the first bin's lower edge and the bin width.
    eps, penalty : float
    sign : float
    acc : ndarray, shape (D, R), float64
        Density per (direction, offset) bin, updated in place.
    """
    for q in range(ids.shape[0]):
        f = ids[q]
        for j in range(dirs.shape[0]):
            d = dirs[j]
            lo, hi = _extent(v, faces[f], d)
            if hi - lo > 4.0 * eps:
                continue
            w = abs(area[f, 0] * d[0] + area[f, 1] * d[1] + area[f, 2] * d[2])
            if penalty > 0.0:
                _add_bins(acc[j], hi - 2 * eps, lo + 2 * eps, rho0, drho, -sign * penalty * w)
            if hi - lo <= 2.0 * eps:
                _add_bins(acc[j], hi - eps, lo + eps, rho0, drho, sign * (1 + penalty) * w)


@nb.njit(cache=True, nogil=True)
def best_offset(v: np.ndarray, faces: np.ndarray, area: np.ndarray, ids: np.ndarray,
                d: np.ndarray, eps: float, penalty: float,
                fixed: np.ndarray) -> tuple[float, float]:
    """The offset of greatest density for normal ``d`` over faces ``ids`` (exact sweep).

    A face's weight is its area projected on the plane, or ``fixed[q]`` where that is
    positive (the merge step weighs faces by count).

    Returns
    -------
    density : float
    rho : float
        ``d . x = rho`` is the plane (the middle of the best run).
    """
    n = ids.shape[0]
    pos = np.empty(4 * n)
    wt = np.empty(4 * n)
    m = 0
    for q in range(n):
        f = ids[q]
        lo, hi = _extent(v, faces[f], d)
        if hi - lo > 4.0 * eps:
            continue
        w = abs(area[f, 0] * d[0] + area[f, 1] * d[1] + area[f, 2] * d[2])
        if fixed[q] > 0.0:
            w = fixed[q]
        if penalty > 0.0:
            pos[m], wt[m] = hi - 2 * eps, -penalty * w
            pos[m + 1], wt[m + 1] = np.nextafter(lo + 2 * eps, np.inf), penalty * w
            m += 2
        if hi - lo <= 2.0 * eps:
            pos[m], wt[m] = hi - eps, (1 + penalty) * w
            pos[m + 1], wt[m + 1] = np.nextafter(lo + eps, np.inf), -(1 + penalty) * w
            m += 2
    if m == 0:
        return 0.0, 0.0
    order = np.argsort(pos[:m])
    best, at, run = -np.inf, 0.0, 0.0
    for r in range(m):
        i = order[r]
        run += wt[i]
        nxt = pos[order[r + 1]] if r + 1 < m else pos[i]
        if run > best and (r + 1 == m or nxt > pos[i]):
            best, at = run, 0.5 * (pos[i] + nxt)
    return best, at


@nb.njit(cache=True, nogil=True)
def face_distance(v: np.ndarray, faces: np.ndarray, ids: np.ndarray, d: np.ndarray,
                  rho: float) -> np.ndarray:
    """Greatest distance of each face's corners to plane ``d . x = rho``, shape (N,)."""
    out = np.empty(ids.shape[0])
    for q in range(ids.shape[0]):
        lo, hi = _extent(v, faces[ids[q]], d)
        out[q] = max(hi - rho, rho - lo)
    return out


@subroutine(nrt=True)
def _cover(i: int, j: int, f: int, nrm: np.ndarray, colour: np.ndarray, tex: np.ndarray,
           normal: np.ndarray, height: np.ndarray, top: np.ndarray) -> None:
    """Texel (i, j) shows face ``f`` if it is the highest there so far."""
    if tex[i, j, 3] and top[i, j] >= height[f]:
        return
    top[i, j] = height[f]
    tex[i, j, 3] = 255
    for k in range(3):
        tex[i, j, k] = colour[f, k]
        normal[i, j, k] = nrm[f, k]


@nb.njit(cache=True, nogil=True)
def _min_max(a: np.ndarray) -> tuple[float, float]:
    """``(a.min(), a.max())`` of ``a`` (n >= 1,), the first NaN if any, as numpy's.

    Written out: numba compiles ``.min()`` and ``.max()`` as generic code of their own
    (an ``nditer`` loop), most of :func:`shoot_texture`'s compile.
    """
    lo = a[0]
    hi = a[0]
    for i in range(1, a.shape[0]):
        v = a[i]
        if lo == lo and (v != v or v < lo):
            lo = v
        if hi == hi and (v != v or v > hi):
            hi = v
    return lo, hi


@nb.njit(cache=True, nogil=True)
def shoot_texture(uv: np.ndarray, faces: np.ndarray, ids: np.ndarray, nrm: np.ndarray,
                  colour: np.ndarray, height: np.ndarray, tex: np.ndarray,
                  normal: np.ndarray) -> None:
    """Orthographic texture shoot of faces ``ids`` onto one billboard.

    Parameters
    ----------
    uv : ndarray, shape (V, 2), float64
        Every vertex projected on the billboard, in texels (x along a row, y down).
    faces : ndarray, shape (F, 3), int64
    ids : ndarray, shape (N,), int64
    nrm : ndarray, shape (F, 3), int8
        Face normals scaled to -127..127.
    colour : ndarray, shape (F, 3), uint8
    height : ndarray, shape (F,), float64
        Each face's height toward the viewer the layer is for: where faces overlap
        on the plane, the highest is kept (the depth test of the shoot).
    tex : ndarray, shape (H, W, 4), uint8
        Colour and alpha (0 or 255), zeroed by the caller, filled here.
    normal : ndarray, shape (H, W, 3), int8
        Normal of the face seen at each covered texel.

    Coverage is conservative: every texel a face overlaps is covered (its centre lies
    within half a texel diagonal of each edge's line, and its square meets the face's
    box), so a face thinner than a texel leaves no hole; a silhouette grows by under
    one texel.
    """
    h, w = tex.shape[0], tex.shape[1]
    top = np.empty((h, w))
    for q in range(ids.shape[0]):
        f = ids[q]
        x = np.empty(3)
        y = np.empty(3)
        for k in range(3):
            x[k], y[k] = uv[faces[f, k], 0], uv[faces[f, k], 1]
        area = (x[1] - x[0]) * (y[2] - y[0]) - (y[1] - y[0]) * (x[2] - x[0])
        sgn = 1.0 if area >= 0 else -1.0
        # inward unit edge normals, so each edge function is a distance in texels
        nx, ny, off = np.empty(3), np.empty(3), np.empty(3)
        for k in range(3):
            ex, ey = x[(k + 1) % 3] - x[k], y[(k + 1) % 3] - y[k]
            ln = max(np.sqrt(ex * ex + ey * ey), 1e-12)
            nx[k], ny[k] = -sgn * ey / ln, sgn * ex / ln
            off[k] = -(nx[k] * x[k] + ny[k] * y[k])
        xlo, xhi = _min_max(x)
        ylo, yhi = _min_max(y)
        x0, x1 = max(int(xlo - 1), 0), min(int(xhi + 1) + 1, w)
        y0, y1 = max(int(ylo - 1), 0), min(int(yhi + 1) + 1, h)
        for i in range(y0, y1):
            for j in range(x0, x1):
                inside = True
                for k in range(3):  # half a texel diagonal of slack: conservative
                    if nx[k] * (j + 0.5) + ny[k] * (i + 0.5) + off[k] < -HALF_DIAGONAL:
                        inside = False
                        break
                if inside and (xlo - 0.5 <= j + 1 and j <= xhi + 0.5
                               and ylo - 0.5 <= i + 1 and i <= yhi + 0.5):
                    _cover(i, j, f, nrm, colour, tex, normal, height, top)


@nb.njit(cache=True, nogil=True)
def dilate_texture(tex: np.ndarray, normal: np.ndarray, steps: int) -> None:
    """Grow the opaque texels of ``tex`` (H, W, 4) by ``steps`` texels (4-neighbours).

    A new texel copies the colour and ``normal`` (H, W, 3) of an opaque neighbour.
    This closes the cracks a view ray finds between neighbouring billboards: a face
    is shot along its plane's normal, so seen along another direction its texels sit
    up to ``EPS * tan(angle)`` away from where the ray meets the plane.
    """
    h, w = tex.shape[0], tex.shape[1]
    src = np.empty((h, w), np.bool_)
    for _ in range(steps):
        for i in range(h):
            for j in range(w):
                src[i, j] = tex[i, j, 3] != 0
        for i in range(h):
            for j in range(w):
                if src[i, j]:
                    continue
                for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1)):
                    a, b = i + di, j + dj
                    if 0 <= a < h and 0 <= b < w and src[a, b]:
                        for k in range(4):
                            tex[i, j, k] = tex[a, b, k]
                        for k in range(3):
                            normal[i, j, k] = normal[a, b, k]
                        break


@nb.njit(cache=True, nogil=True)
def tile_grid(alpha: np.ndarray, tex_shape: np.ndarray, tex_offset: np.ndarray, tile: int,
              layers: int) -> tuple[np.ndarray, np.ndarray]:
    """Which ``tile`` x ``tile`` texel tiles of each billboard hold a texel with alpha > 0.

    ``alpha`` (N,) uint8 is every texel's alpha (billboard after billboard, ``layers``
    layers of rows x cols each, as ``BillboardCloud.rgba``).  Returns the grids (G,)
    uint8, 1 where a tile of either layer holds a visible texel, each billboard's
    ceil(rows / tile) x ceil(cols / tile) tiles row-major, and where each billboard's
    grid starts, (P + 1,) int64.
    """
    p_count = tex_shape.shape[0]
    start = np.zeros(p_count + 1, np.int64)
    for p in range(p_count):
        start[p + 1] = start[p] + ((tex_shape[p, 0] + tile - 1) // tile) * (
            (tex_shape[p, 1] + tile - 1) // tile)
    grid = np.zeros(start[p_count], np.uint8)
    for p in range(p_count):
        rows, cols = tex_shape[p, 0], tex_shape[p, 1]
        tcols = (cols + tile - 1) // tile
        for layer in range(layers):
            base = tex_offset[p] + layer * rows * cols
            for i in range(rows):
                g = start[p] + (i // tile) * tcols
                for j in range(cols):
                    if alpha[base + i * cols + j] > 0:
                        grid[g + j // tile] = 1
    return grid, start
