"""Thimbleby, Inglis and Witten's SIRD (IEEE Computer 27(10), 1994), rows in parallel.

Per row (the paper's figure, in its variable names):

* every pixel starts linked to itself, ``same[x] = x``;
* for each ``x`` left to right, the point at height ``z(x)`` is seen by the left
  eye through ``left = x - (s + (s & y & 1)) / 2`` and by the right eye through
  ``right = left + s`` (symmetric constraints; odd ``s`` alternate rounding by row);
* **hidden-surface removal**: the point is dropped if anything nearer blocks either
  line of sight: for ``t = 1, 2, ...`` while the line's height
  ``zt = z + 2 (2 - mu z) t / (mu E)`` stays below the row's highest ``z``, a
  neighbour ``z(x - t)`` or ``z(x + t)`` at or above ``zt`` hides it (the paper
  loops to ``zt < 1``; nothing above the row's maximum can block, so we stop there);
* a visible pair is linked without conflicts: follow ``same[left]`` until it meets
  ``left`` or ``right``, re-linking so every pixel holds one link to its right;
* right to left, a pixel linked to itself takes the pattern at a stable coordinate,
  ``pattern[y mod Hp, x mod Wp]``; any other copies ``out[same[x]]``.

Every constraint holds by construction (0 broken); the kernel counts constraints
(visible, in-row pairs) and hidden points.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from service.autostereogram.geometry import separation_rows


@nb.njit(cache=True)
def _hidden(zr: np.ndarray, x: int, z: float, zmax: float, step: float) -> bool:
    """True if a nearer neighbour blocks a line of sight from (x, z); ``step`` = dzt/dt."""
    w = zr.shape[0]
    t = 1
    zt = z + step
    while zt <= zmax:
        if x - t >= 0 and zr[x - t] >= zt:
            return True
        if x + t < w and zr[x + t] >= zt:
            return True
        t += 1
        zt = z + step * t
    return False


@nb.njit(cache=True)
def _link(same: np.ndarray, left: int, right: int) -> None:
    """Record ``left == right`` in ``same`` without two links from one pixel (TIW)."""
    k = same[left]
    while k != left and k != right:
        if k < right:
            left = k
            k = same[left]
        else:
            same[left] = right
            left = right
            k = same[left]
            right = k
    same[left] = right


@nb.njit(cache=True)
def _heights(drow: np.ndarray, far: float, inv_range: float, zr: np.ndarray) -> None:
    """``z`` of one row into ``zr`` (rows with something above the far plane only)."""
    f = np.float32(far)
    k = np.float32(inv_range)
    for x in range(drow.shape[0]):
        z = (f - drow[x]) * k
        z = z if z > np.float32(0.0) else np.float32(0.0)
        zr[x] = z if z < np.float32(1.0) else np.float32(1.0)


@nb.njit(cache=True)
def _right_bound(zr: np.ndarray, step: float, rb: np.ndarray) -> float:
    """``rb[x] = max over t >= 1 of zr[x + t] - step t`` (a bound on right occluders).

    Returns the row's largest ``z``.
    """
    w = zr.shape[0]
    acc = np.float32(-1.0)
    zmax = np.float32(0.0)
    for x in range(w - 1, -1, -1):
        rb[x] = acc
        zx = zr[x]
        zmax = max(zmax, zx)
        acc = max(acc, zx) - step
    return zmax


@nb.njit(cache=True)
def _link_flat(sr: np.ndarray, same: np.ndarray, y: int) -> int:
    """TIW's constraint loop over a row with nothing above the far plane (no occlusion).

    Returns the constraints made.  The common case, a ``left`` not linked yet, is
    tested inline before :func:`_link`'s general search.
    """
    w = sr.shape[0]
    par = y & 1
    ncons = 0
    for x in range(w):
        s = sr[x]
        left = x - ((s + (s & par)) >> 1)
        right = left + s
        if left < 0 or right >= w:
            continue
        ncons += 1
        if same[left] == left:
            same[left] = right
        else:
            _link(same, left, right)
    return ncons


@nb.njit(cache=True)
def _link_row(zr: np.ndarray, sr: np.ndarray, same: np.ndarray, rb: np.ndarray, y: int,
              zmax: float, eye_sep: float, mu: float) -> tuple[int, int]:
    """TIW's constraint loop over one row; returns (constraints, hidden points).

    ``sr`` holds ``s(z)``; ``rb`` is :func:`_right_bound`'s output when ``zmax > 0``
    (else :func:`_link_flat` does the row).  With the smallest sight-line slope
    ``step0 (2 - mu)``, ``lb`` (running, left) and ``rb`` bound every possible
    occluder, so the exact search (:func:`_hidden`) runs only where they reach the
    point's height.
    """
    if zmax <= 0.0:
        return _link_flat(sr, same, y), 0
    w = zr.shape[0]
    step0 = 2.0 / (mu * eye_sep)
    smin = np.float32(step0 * (2.0 - mu))
    par = y & 1
    lb = np.float32(-1.0)
    ncons = 0
    nhid = 0
    for x in range(w):
        s = sr[x]
        z = zr[x]
        left = x - ((s + (s & par)) >> 1)
        right = left + s
        near = z < zmax and (lb >= z or rb[x] >= z)
        lb = max(lb, z) - smin
        if left < 0 or right >= w:
            continue
        if near and _hidden(zr, x, z, zmax, step0 * (2.0 - mu * z)):
            nhid += 1
            continue
        ncons += 1
        if same[left] == left:
            same[left] = right
        else:
            _link(same, left, right)
    return ncons, nhid


@nb.njit(cache=True)
def _colour_row(o: np.ndarray, same: np.ndarray, prow: np.ndarray, nc: int) -> None:
    """Right to left: free pixels take ``prow[x mod Wp]``, linked ones their link's colour."""
    pw = prow.shape[0]
    w = same.shape[0]
    u = (w - 1) % pw
    if nc == 1:  # grey: one byte a pixel, the loop LLVM can keep tight
        for x in range(w - 1, -1, -1):
            k = same[x]
            o[x] = prow[u, 0] if k == x else o[k]
            u = u - 1 if u > 0 else pw - 1
        return
    for x in range(w - 1, -1, -1):
        k = same[x]
        if k == x:
            for c in range(nc):
                o[x * nc + c] = prow[u, c]
        else:
            for c in range(nc):
                o[x * nc + c] = o[k * nc + c]
        u = u - 1 if u > 0 else pw - 1


@nb.njit(cache=True, parallel=True, nogil=True)
def tiw_kernel(depth: np.ndarray, far: float, inv_range: float, eye_sep: float, mu: float,
               pattern: np.ndarray, out: np.ndarray, zbuf: np.ndarray, sbuf: np.ndarray,
               links: np.ndarray, bound: np.ndarray, counts: np.ndarray) -> None:
    """Draw a SIRD by symmetric constraints with hidden-surface removal, rows in parallel.

    Parameters
    ----------
    depth : ndarray, shape (H, W), float32
    far, inv_range, eye_sep, mu : float
        As :func:`service.autostereogram.row.row_kernel`.
    pattern : ndarray, shape (Hp, Wp, C), uint8
    out : ndarray, shape (H, W * C), uint8
        Written.
    zbuf, bound : ndarray, shape (H, W), float32
        Scratch: ``z`` per pixel and the right-occluder bound.
    sbuf : ndarray, shape (H, W), int32
        Scratch: ``s(z)`` per pixel.
    links : ndarray, shape (H, W), int32
        Written: ``same[]`` per row (``links[y, x] > x`` links x to it, ``== x`` none).
    counts : ndarray, shape (H, 3), int64
        Written per row: constraints, hidden points, NaN depths.
    """
    h, w = depth.shape
    ph, pw, nc = pattern.shape
    smin = np.float32(2.0 / (mu * eye_sep) * (2.0 - mu))
    separation_rows(depth, far, inv_range, eye_sep, mu, sbuf, counts)
    for y in nb.prange(h):
        zr = zbuf[y]
        same = links[y]
        for x in range(w):
            same[x] = x
        zmax = 0.0
        if counts[y, 0] > 0:
            _heights(depth[y], far, inv_range, zr)
            zmax = _right_bound(zr, smin, bound[y])
        ncons, nhid = _link_row(zr, sbuf[y], same, bound[y], y, zmax, eye_sep, mu)
        _colour_row(out[y], same, pattern[y % ph], nc)
        counts[y, 0] = ncons
        counts[y, 1] = nhid
