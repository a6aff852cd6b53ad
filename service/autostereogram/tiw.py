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
might block.  First, a point can be hidden only within ``reach`` (``zmax / c_min``)
pixels of a step ``|z(v + 1) - z(v)|`` at least as steep as the flattest sight line
``c_min``: heights cannot climb faster on average than their steepest step.  On a
row with few such steps (smooth surfaces, silhouettes) the bounds and searches run
only in the spans those steps reach; the rest links as a flat row.  Within a span
every sight line of a point at or below ``z`` rises at least ``c = step(z)`` per
pixel, so ``max over t >= 1 of z(x - t) - c t`` (and the same to the right) bounds
what can block it: running maxima, two per side (``c`` at ``z = BAND_Z`` and at
``z = 1``); a shadow's points try the last occluder found first.  On a row full of
steep steps (the seed's slope) the left side needs no bound: only a strictly higher
pixel can block, and past one that does not, only the next strictly higher one to
its left, so a walk over those (each pixel's nearest strictly higher pixel, found
by the usual stack walk) decides each point, on the slope in one test.  The right
side keeps the two running maxima, in 24-bit fixed point (integer chains are
shorter), the band at ``z = DENSE_BAND_Z`` (no slope point then needs a search).  A row
on the far plane with a pattern ``s(0)`` wide is the pattern tiled.  Scratch rows
are per thread, so a frame touches no image-sized buffers besides depth and output
(and the links, when kept).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from service.numba_subroutine import subroutine

#: Points at or below this height need a rise as steep as their band's sight line.
BAND_Z = 0.75
#: Slack on the float32 occluder bounds (their rounding over a sight line's reach is less).
BOUND_SLACK = 4e-6
#: Slack on the steepness test (float32 differences of heights in [0, 1] round by less).
EDGE_SLACK = 1e-6
#: The band of the dense rows' right bounds (their left side needs none): points at or
#: below it need a rise as steep as its sight line; on the seed's slope no point then
#: needs a search.
DENSE_BAND_Z = 0.95
#: Fixed-point unit of the dense rows' right bounds (heights in [0, 1] as integers).
FIXED_ONE = 16777216
#: A row with more than W / DENSE_EDGES steep steps is bounded pixel by pixel, not in spans.
DENSE_EDGES = 16


@subroutine(nrt=True)
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


@nb.njit(cache=True, inline="always")
def _fixed_heights(zr: np.ndarray, q: np.ndarray) -> float:
    """``q = trunc(z 2^24)`` (inlined: it vectorises); returns a bound on the row's max.

    The bound is the largest ``z`` exactly where it is at least 1/2 (``z 2^24`` is
    then an integer), else just above it: TIW's searches up to a higher bound find
    the same occluders (nothing is higher than the row's largest ``z``).
    """
    m = 0
    for x in range(zr.shape[0]):
        v = np.int32(zr[x] * np.float32(FIXED_ONE))
        q[x] = v
        m = max(m, v)
    return m / FIXED_ONE if m >= FIXED_ONE // 2 else (m + 1) / FIXED_ONE


@subroutine(nrt=True)
def _look_right(q: np.ndarray, c_band: float, c_min: float, look: np.ndarray) -> None:
    """``look[x]`` = 1 where a neighbour to the right might block ``x``.

    ``acc = max over t >= 1 of z(x + t) - c t`` bounds the right occluders of every
    point whose sight line rises at least ``c`` per pixel: ``c_band`` for points at or
    below ``DENSE_BAND_Z``, ``c_min`` (the flattest sight line) for any.  Two
    independent chains in one loop, in integers (``q = trunc(z 2^24)``, ``c`` rounded
    down a unit, the slack two units wider): an integer maximum and subtraction
    cost a cycle each, the float ones several, and the chains are the loop's
    critical path.
    """
    w = q.shape[0]
    cb = np.int64(c_band * FIXED_ONE) - 1
    cm = np.int64(c_min * FIXED_ONE) - 1
    bz = np.int64(DENSE_BAND_Z * FIXED_ONE)
    slack = np.int64(BOUND_SLACK * FIXED_ONE) + 2
    acc_b = np.int64(-FIXED_ONE)
    acc_m = np.int64(-FIXED_ONE)
    for x in range(w - 1, -1, -1):
        v = np.int64(q[x])
        bound = acc_b if v <= bz else acc_m
        look[x] = bound + slack >= v
        acc_b = max(acc_b, v) - cb
        acc_m = max(acc_m, v) - cm


@subroutine(nrt=True)
def _steep_edges(zr: np.ndarray, c_min: float, edges: np.ndarray) -> tuple[int, float]:
    """Flag the steps steep enough to hide; returns (their number, a bound on the row's max).

    ``edges[v]`` = 1 where ``|z(v + 1) - z(v)| >= c_min`` (0 for the last pixel and the
    padding).  The bound is ``(m + 1) / 2^24`` with ``m`` the largest ``z 2^24``
    truncated, just above the row's largest ``z`` (an integer maximum vectorises, a
    float one does not).  Not inlined: inlining it in the parallel loop's body cost
    2.5 s of compilation and no time a frame.
    """
    w = zr.shape[0]
    em = np.float32(c_min - EDGE_SLACK)
    n = 0
    m = 0
    for v in range(w - 1):
        e = abs(zr[v + 1] - zr[v]) >= em
        edges[v] = np.uint8(e)
        n += e
    for v in range(w - 1, edges.shape[0]):
        edges[v] = 0
    for x in range(w):
        m = max(m, np.int32(zr[x] * np.float32(16777216.0)))
    return n, (m + 1) / 16777216.0


@subroutine(nrt=True)
def _spans(edges: np.ndarray, w: int, reach: int, spans: np.ndarray) -> int:
    """The pixels a steep edge can reach, as merged spans ``spans[2k] .. spans[2k + 1]``.

    A point at ``z`` is hidden to its left only if ``z(x - t) >= z + step(z) t`` for some
    ``t <= reach``; then some fall ``z(v) - z(v + 1)`` with ``x - t <= v < x`` is at least
    ``step(z) >= c_min`` (the heights cannot climb faster on average than their
    steepest step).  So only ``x`` in ``v + 1 .. v + reach`` of a steep edge ``v`` can
    hide to the left, ``v + 1 - reach .. v`` to the right.  Edges are read eight at
    a time (they are rare on smooth surfaces).  Returns the number of spans.
    """
    n = 0
    end = -2
    for i in range(edges.shape[0] // 8):
        b = 8 * i  # eight flags at once (not edges.view(np.uint64): 0.3 s more to compile)
        if (edges[b] | edges[b + 1] | edges[b + 2] | edges[b + 3] | edges[b + 4]
                | edges[b + 5] | edges[b + 6] | edges[b + 7]) == 0:
            continue
        last = 8 * i + 7
        while edges[last] == 0:
            last -= 1
        hi = min(w - 1, last + reach)
        if n > 0 and 8 * i + 1 - reach <= end + 1:  # every edge here joins the open span
            spans[2 * n - 1] = hi
        else:
            first = 8 * i
            while edges[first] == 0:
                first += 1
            spans[2 * n] = max(0, first + 1 - reach)
            spans[2 * n + 1] = hi
            n += 1
        end = hi
    return n


@subroutine(nrt=True)
def _look_right_span(zr: np.ndarray, lo: int, hi: int, reach: int, c_band: float, c_min: float,
                look: np.ndarray) -> None:
    """``look[x]`` = 1 for ``x`` in ``lo .. hi`` where a neighbour to the right might block.

    ``acc = max over t >= 1 of z(x + t) - c t`` bounds the right occluders of every
    point whose sight line rises at least ``c`` per pixel: ``c_band`` for points at or
    below ``BAND_Z``, ``c_min`` (the flattest sight line) for any.  Two independent
    chains in one loop (one subtraction and one maximum a pixel each), started
    ``reach`` pixels to the right of ``hi`` (no occluder further away counts).
    """
    w = zr.shape[0]
    cb = np.float32(c_band)
    cm = np.float32(c_min)
    bz = np.float32(BAND_Z)
    slack = np.float32(BOUND_SLACK)
    acc_b = np.float32(-1.0)
    acc_m = np.float32(-1.0)
    for x in range(min(w - 1, hi + reach), lo - 1, -1):
        z = zr[x]
        bound = acc_b if z <= bz else acc_m
        look[x] = bound + slack >= z
        acc_b = max(acc_b, z) - cb
        acc_m = max(acc_m, z) - cm


@subroutine(nrt=True)
def _link_flat(sr: np.ndarray, same: np.ndarray, y: int, lo: int, hi: int) -> int:
    """TIW's constraint loop over points ``lo .. hi - 1`` that nothing can hide.

    Returns the constraints made.  The common case, a ``left`` not linked yet, is
    tested inline before :func:`_link`'s general search.
    """
    w = sr.shape[0]
    par = y & 1
    ncons = 0
    for x in range(lo, hi):
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


@nb.njit(cache=True, inline="always")
def _hidden_left(zr: np.ndarray, pg: np.ndarray, x: int, z: float, zmax: float,
                 step: float) -> bool:
    """Whether a neighbour to the left blocks ``x`` (TIW's loop, over the candidates only).

    ``pg[x]`` is the nearest pixel to the left strictly higher than ``z`` (-1 if none):
    nothing between can block (it is no higher than ``z``, and the sight line is
    above ``z``).  Past a candidate ``j`` that does not block, the next that can is
    ``pg[j]``: everything between is no higher than ``z(j)``, and the line there is
    higher than at ``j`` (``z + step t`` grows with ``t``, rounding included).  So the
    walk tests the same pixels' heights against the same ``z + step t`` as the loop
    over every ``t``, skipping only pixels that cannot block, and stops where that
    loop does (``z + step t > zmax``).
    """
    j = pg[x]
    while j >= 0:
        zt = z + step * (x - j)
        if zt > zmax:
            return False
        if zr[j] >= zt:
            return True
        j = pg[j]
    return False


@subroutine(nrt=True)
def _link_row(zr: np.ndarray, sr: np.ndarray, same: np.ndarray, look: np.ndarray,
              pg: np.ndarray, y: int, zmax: float, eye_sep: float,
              mu: float) -> tuple[int, int]:
    """TIW's constraint loop over a row with something above the far plane.

    Returns (constraints, hidden points).  To the left, the walk over strictly
    higher pixels (:func:`_hidden_left`; ``pg``, scratch, gets each pixel's nearest
    strictly higher pixel to its left, the usual stack walk: amortised one step a
    pixel) replaces a bound and a search: on the seed's slope it decides every point
    in one test.  To the right, the exact search (:func:`_occluder`) runs where
    :func:`_look_right` says so.
    """
    w = zr.shape[0]
    step0 = 2.0 / (mu * eye_sep)
    par = y & 1
    ncons = 0
    nhid = 0
    occ_r = np.int64(-1)  # the last occluder found to the right (typed: one signature)
    for x in range(w):
        z = zr[x]
        j = x - 1
        while j >= 0 and zr[j] <= z:
            j = pg[j]
        pg[x] = j
        s = sr[x]
        left = x - ((s + (s & par)) >> 1)
        right = left + s
        if left < 0 or right >= w:
            continue
        look_right = look[x] != 0
        if (j >= 0 or look_right) and z < zmax:
            step = step0 * (2.0 - mu * z)
            if j >= 0 and _hidden_left(zr, pg, x, z, zmax, step):
                nhid += 1
                continue
            if look_right:
                occ_r = _occluder(zr, x, z, zmax, step, np.int64(1), occ_r)
                if occ_r >= 0:
                    nhid += 1
                    continue
        ncons += 1
        if same[left] == left:
            same[left] = right
        else:
            _link(same, left, right)
    return ncons, nhid


@subroutine(nrt=True)
def _link_span(zr: np.ndarray, sr: np.ndarray, same: np.ndarray, look: np.ndarray, y: int,
               lo: int, hi: int, reach: int, zmax: float, eye_sep: float,
               mu: float) -> tuple[int, int]:
    """TIW's constraint loop over ``lo .. hi``, a span a steep edge can reach.

    Returns (constraints, hidden points).  The exact search (:func:`_occluder`)
    runs to the right where :func:`_look_right_span` says so, and to the left where the
    mirror bound (two chains kept here as ``x`` moves right, started ``reach``
    pixels before ``lo``) reaches the point.
    """
    w = zr.shape[0]
    step0 = 2.0 / (mu * eye_sep)
    cb = np.float32(step0 * (2.0 - mu * BAND_Z))
    cm = np.float32(step0 * (2.0 - mu))
    bz = np.float32(BAND_Z)
    slack = np.float32(BOUND_SLACK)
    acc_b = np.float32(-1.0)
    acc_m = np.float32(-1.0)
    for x in range(max(0, lo - reach), lo):
        z = zr[x]
        acc_b = max(acc_b, z) - cb
        acc_m = max(acc_m, z) - cm
    par = y & 1
    ncons = 0
    nhid = 0
    occ_l = np.int64(-1)  # the last occluders found on each side (typed, see _link_row)
    occ_r = np.int64(-1)
    for x in range(lo, hi + 1):
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
                occ_l = _occluder(zr, x, z, zmax, step, np.int64(-1), occ_l)
                if occ_l >= 0:
                    nhid += 1
                    continue
            if look_right:
                occ_r = _occluder(zr, x, z, zmax, step, np.int64(1), occ_r)
                if occ_r >= 0:
                    nhid += 1
                    continue
        ncons += 1
        if same[left] == left:
            same[left] = right
        else:
            _link(same, left, right)
    return ncons, nhid


@subroutine(nrt=True)
def _link_sparse(zr: np.ndarray, sr: np.ndarray, same: np.ndarray, rows: np.ndarray,
              edges: np.ndarray, y: int, zmax: float, eye_sep: float,
              mu: float) -> tuple[int, int]:
    """TIW's constraint loop over a row whose steep edges are few.

    Occlusion is looked for only in the spans a steep edge can reach (:func:`_spans`);
    between them the row links as a flat one (:func:`_link_flat`).  ``rows`` is the
    thread's scratch: ``rows[1]`` the right bounds, ``rows[2]`` the spans.  ``zmax``
    may exceed the row's largest ``z`` (the searches then look a little further and
    find the same occluders: nothing higher than the row's largest ``z`` exists).
    """
    w = zr.shape[0]
    step0 = 2.0 / (mu * eye_sep)
    c_band = step0 * (2.0 - mu * BAND_Z)
    c_min = step0 * (2.0 - mu)
    reach = int(zmax / c_min) + 1  # no line of sight climbs past zmax further away
    spans = rows[2]
    nspans = _spans(edges, w, reach, spans)
    ncons = 0
    nhid = 0
    done = np.int64(0)
    for k in range(nspans):
        lo = np.int64(spans[2 * k])
        hi = np.int64(spans[2 * k + 1])
        ncons += _link_flat(sr, same, y, done, lo)
        _look_right_span(zr, lo, hi, reach, c_band, c_min, rows[1])
        c, h = _link_span(zr, sr, same, rows[1], y, lo, hi, reach, zmax, eye_sep, mu)
        ncons += c
        nhid += h
        done = hi + 1
    return ncons + _link_flat(sr, same, y, done, w), nhid


@subroutine(nrt=True)
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


@subroutine(nrt=True)
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
               heights: np.ndarray, scratch: np.ndarray, edges: np.ndarray,
               counts: np.ndarray) -> None:
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
    scratch : ndarray, shape (threads, 3, W), int32
        Per-thread scratch: ``s(z)`` of the row, where to search to the right, spans.
    edges : ndarray, shape (threads, W8), uint8
        Per-thread scratch: the row's steep steps (``W8``: ``W`` rounded up to 8).
    counts : ndarray, shape (H, 3), int64
        Written per row: constraints, hidden points, NaN depths.
    """
    h, w = depth.shape
    ph, pw, nc = pattern.shape
    step0 = 2.0 / (mu * eye_sep)
    c_dense = step0 * (2.0 - mu * DENSE_BAND_Z)
    c_min = step0 * (2.0 - mu)
    for yp in nb.prange(h):
        y = np.int64(yp)  # one signature for the callees (prange types its index twice)
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
        if above == 0:
            ncons, nhid = _link_flat(sr, same, y, np.int64(0), w), 0
        else:
            nsteep, zbound = _steep_edges(zr, c_min, edges[tid])
            if nsteep * DENSE_EDGES > w:  # a slope: bound every pixel
                free = scratch[tid, 2]  # the spans' row: fixed-point heights, then pg
                zmax = _fixed_heights(zr, free)
                _look_right(free, c_dense, c_min, look)
                ncons, nhid = _link_row(zr, sr, same, look, free, y, zmax, eye_sep, mu)
            else:
                ncons, nhid = _link_sparse(zr, sr, same, scratch[tid], edges[tid], y, zbound,
                                           eye_sep, mu)
        _colour_row(out[y], same, pattern[y % ph], nc)
        counts[y, 0] = ncons
        counts[y, 1] = nhid
