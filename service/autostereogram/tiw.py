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

Speed: the exact occlusion search runs only where a cheap bound says a neighbour
might block.  Every sight line rises at least ``c = step(z)`` per pixel for a point
at or below ``z``, so ``max over t >= 1 of z(x - t) - c t`` (and the same to the
right) bounds what can block it.  With the heights tilted, ``z(u) + c u``, that
bound is a running maximum: a chain of one ``max`` per pixel instead of a
subtraction and a maximum, and four such chains (left and right, for ``c`` the
slope at ``z = BAND_Z`` and at ``z = 1``) run side by side in one loop.  The second
slope keeps the exact search away from the points of a slope that rises as fast as
the flattest sight line (the seed's streak case), which the ``z = 1`` bound cannot
tell from hidden ones.  Scratch rows are per thread, so a frame touches no
image-sized buffers besides depth and output (and the links, when kept).
"""

from __future__ import annotations

import numba as nb
import numpy as np

#: Points at or below this height need a rise as steep as their band's sight line.
BAND_Z = 0.75
#: Slack on the float32 occluder bounds (their rounding over a sight line's reach is less).
BOUND_SLACK = 4e-6


@nb.njit(cache=True)
def _occluder(zr: np.ndarray, x: int, z: float, zmax: float, step: float, direction: int,
              last: int) -> int:
    """A neighbour on one side (``direction`` -1 or +1) that blocks the sight line, or -1.

    The line rises ``step`` per pixel from ``(x, z)``; ``z(x + direction t) >= z + step t``
    for some ``t >= 1`` with ``z + step t <= zmax`` hides the point (TIW's loop).
    ``last``, the occluder found for an earlier point (or -1), is tried first: the
    points in one shadow share it, so a run of hidden points costs one test each.
    """
    w = zr.shape[0]
    if last >= 0:
        t = (last - x) * direction
        if t >= 1 and zr[last] >= z + step * t:
            return last
    t = 1
    zt = z + step
    xt = x + direction
    while zt <= zmax and 0 <= xt < w:
        if zr[xt] >= zt:
            return xt
        t += 1
        zt = z + step * t
        xt += direction
    return -1


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


@nb.njit(cache=True, inline="always")
def _row_geometry(drow: np.ndarray, far: float, inv_range: float, eye_sep: float, mu: float,
                  zr: np.ndarray, sr: np.ndarray) -> tuple[int, int]:
    """``z`` and ``s(z)`` of one row into ``zr`` and ``sr``; returns (pixels above, NaNs).

    The float32 arithmetic of :func:`service.autostereogram.geometry.separation_rows`
    (so :func:`~service.autostereogram.geometry.separation_map` names the separations
    drawn), in loops with no loop-carried dependence (inlined, so they vectorise).
    """
    e = np.float32(eye_sep)
    m = np.float32(mu)
    f = np.float32(far)
    k = np.float32(inv_range)
    above = 0
    bad = 0
    w = drow.shape[0]
    for x in range(w):
        d = drow[x]
        bad += d != d
        z = (f - d) * k
        z = z if z > np.float32(0.0) else np.float32(0.0)  # NaN and -inf -> 0
        above += z > np.float32(0.0)
        zr[x] = z if z < np.float32(1.0) else np.float32(1.0)
    for x in range(w):  # one output per loop: it vectorises
        t = m * zr[x]
        sr[x] = np.int32((np.float32(1.0) - t) * e / (np.float32(2.0) - t) + np.float32(0.5))
    return above, bad


@nb.njit(cache=True)
def _look_right(zr: np.ndarray, c_band: float, c_min: float, look: np.ndarray) -> float:
    """``look[x]`` = 1 where a neighbour to the right might block ``x``; returns the row's max.

    ``acc = max over t >= 1 of z(x + t) - c t`` bounds the right occluders of every
    point whose sight line rises at least ``c`` per pixel: ``c_band`` for points at or
    below ``BAND_Z``, ``c_min`` (the flattest sight line) for any.  Two independent
    chains in one loop (one subtraction and one maximum a pixel each).
    """
    w = zr.shape[0]
    cb = np.float32(c_band)
    cm = np.float32(c_min)
    bz = np.float32(BAND_Z)
    slack = np.float32(BOUND_SLACK)
    acc_b = np.float32(-1.0)
    acc_m = np.float32(-1.0)
    zmax = np.float32(0.0)
    for x in range(w - 1, -1, -1):
        z = zr[x]
        bound = acc_b if z <= bz else acc_m
        look[x] = bound + slack >= z
        zmax = max(zmax, z)
        acc_b = max(acc_b, z) - cb
        acc_m = max(acc_m, z) - cm
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
def _link_row(zr: np.ndarray, sr: np.ndarray, same: np.ndarray, look: np.ndarray, y: int,
              zmax: float, eye_sep: float, mu: float) -> tuple[int, int]:
    """TIW's constraint loop over a row with something above the far plane.

    Returns (constraints, hidden points).  The exact search (:func:`_occluder`)
    runs to the right where :func:`_look_right` says so, and to the left where the
    mirror bound (two chains kept here as ``x`` moves right) reaches the point.
    """
    w = zr.shape[0]
    step0 = 2.0 / (mu * eye_sep)
    cb = np.float32(step0 * (2.0 - mu * BAND_Z))
    cm = np.float32(step0 * (2.0 - mu))
    bz = np.float32(BAND_Z)
    slack = np.float32(BOUND_SLACK)
    acc_b = np.float32(-1.0)
    acc_m = np.float32(-1.0)
    par = y & 1
    ncons = 0
    nhid = 0
    occ_l = -1  # the last occluders found on each side
    occ_r = -1
    for x in range(w):
        s = sr[x]
        z = zr[x]
        bound = acc_b if z <= bz else acc_m
        look_left = bound + slack >= z
        acc_b = max(acc_b, z) - cb
        acc_m = max(acc_m, z) - cm
        left = x - ((s + (s & par)) >> 1)
        right = left + s
        if left < 0 or right >= w:
            continue
        look_right = look[x] != 0
        if (look_left or look_right) and z < zmax:
            step = step0 * (2.0 - mu * z)
            if look_left:
                occ_l = _occluder(zr, x, z, zmax, step, -1, occ_l)
                if occ_l >= 0:
                    nhid += 1
                    continue
            if look_right:
                occ_r = _occluder(zr, x, z, zmax, step, 1, occ_r)
                if occ_r >= 0:
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


@nb.njit(cache=True)
def _empty_row(o: np.ndarray, same: np.ndarray, keep_links: bool, prow: np.ndarray,
               nc: int) -> int:
    """A row on the far plane, where the pattern is ``s(0)`` wide: the pattern, tiled.

    Every point links ``x`` to ``x + s(0)``, so each pixel copies the pixel ``s(0)`` to
    its right and the right-most ``s(0)`` take ``prow[x mod Wp]``: with ``Wp = s(0)``
    every pixel is ``prow[x mod Wp]``, no link or colour pass needed.  The links are
    written only if kept.  Returns the constraints (``W - s(0)``).
    """
    w = same.shape[0]
    pw = prow.shape[0]
    u = 0
    for x in range(w):
        for c in range(nc):
            o[x * nc + c] = prow[u, c]
        u = u + 1 if u + 1 < pw else 0
    if keep_links:
        for x in range(w):
            same[x] = x + pw if x < w - pw else x
    return w - pw


@nb.njit(cache=True, parallel=True, nogil=True)
def tiw_kernel(depth: np.ndarray, far: float, inv_range: float, eye_sep: float, mu: float,
               pattern: np.ndarray, out: np.ndarray, links: np.ndarray, keep_links: bool,
               heights: np.ndarray, scratch: np.ndarray, counts: np.ndarray) -> None:
    """Draw a SIRD by symmetric constraints with hidden-surface removal, rows in parallel.

    One parallel loop over rows (heights and separations, occlusion, links, colours),
    so a frame pays for one fork and join of the threads.

    Parameters
    ----------
    depth : ndarray, shape (H, W), float32
    far, inv_range, eye_sep, mu : float
        As :func:`service.autostereogram.row.row_kernel`.
    pattern : ndarray, shape (Hp, Wp, C), uint8
    out : ndarray, shape (H, W * C), uint8
        Written.
    links : ndarray, shape (H, W) or (threads, W), int32
        ``same[]`` per row (``links[y, x] > x`` links x to it, ``== x`` none): written
        per row if ``keep_links``, else per-thread scratch (a frame then writes no
        image-sized buffer but its output: 4 bytes a pixel less memory traffic).
    keep_links : bool
    heights : ndarray, shape (threads, W), float32
        Per-thread scratch: ``z`` of the row (``threads`` >= numba's thread count).
    scratch : ndarray, shape (threads, 2, W), int32
        Per-thread scratch: ``s(z)`` of the row, and where to search to the right.
    counts : ndarray, shape (H, 3), int64
        Written per row: constraints, hidden points, NaN depths.
    """
    h, w = depth.shape
    ph, pw, nc = pattern.shape
    step0 = 2.0 / (mu * eye_sep)
    c_band = step0 * (2.0 - mu * BAND_Z)
    c_min = step0 * (2.0 - mu)
    for y in nb.prange(h):
        tid = nb.get_thread_id()
        zr = heights[tid]
        sr = scratch[tid, 0]
        look = scratch[tid, 1]
        same = links[y] if keep_links else links[tid]
        above, bad = _row_geometry(depth[y], far, inv_range, eye_sep, mu, zr, sr)
        counts[y, 2] = bad
        if above == 0 and sr[0] == pw:
            counts[y, 0] = _empty_row(out[y], same, keep_links, pattern[y % ph], nc)
            counts[y, 1] = 0
            continue
        for x in range(w):
            same[x] = x
        if above > 0:
            zmax = _look_right(zr, c_band, c_min, look)
            ncons, nhid = _link_row(zr, sr, same, look, y, zmax, eye_sep, mu)
        else:
            ncons, nhid = _link_flat(sr, same, y), 0
        _colour_row(out[y], same, pattern[y % ph], nc)
        counts[y, 0] = ncons
        counts[y, 1] = nhid
