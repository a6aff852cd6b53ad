"""Occlusion by run-length "linerow" arrays, the thesis's method (seed 000, ch. 2).

Polygons are drawn nearest first (one average-z sort for every zone).  For each
zone, each hololine (row) keeps the stretches already filled as a sorted list of
``[min, max]`` step intervals: even indices hold minima, odd indices maxima, unused
entries hold a sentinel larger than any step (the thesis's 2000).  A point is
*occluded* in a zone if its step already lies in a filled stretch; otherwise it is
drawn and the list is updated.  ``occluded()`` handles the thesis's cases:

* the linerow is empty: the point makes its own line;
* step before the first entry: extends the first line or makes its own line;
* step inside a line (the lower reference index is even): occluded;
* ends or starts a line (equals a reference entry): occluded;
* fills the gap between two lines: the two lines merge;
* extends a line by one stepspace at either end;
* otherwise makes its own line (entries shift right by two).

A *tracker* index per zone remembers where the last search ended so the next point
of the same linerow does not cycle from the start; it is reset for each new
linerow (each new span here).

Steps.  The thesis's step was the z-intercept of the zone's view vector, whose
spacing (the *stepspace*) it had to find by experiment.  Here each zone is a sheared
parallel projection onto the pixel grid, so the step is simply the pixel column in
that zone's image and the stepspace is exactly 1.

The method never compares depths: a point is hidden only because a polygon earlier
in the sort already drew there.  That is wrong when the average-z order is wrong
(cyclic overlap, interpenetration).  The kernel therefore also checks, for every
occluded point, whether it is in fact *nearer* than what was drawn; such pixels are
counted as ``inconsistent_pixels`` so the pipeline can fall back to the z-buffer.

Tie rule of the repair (``repair=True``).  A hidden point replaces what was drawn
when it is strictly nearer (``d < depth``), exactly the z-buffer's test, so an exact
depth tie keeps the surface drawn first in the sort, as the z-buffer and the ray
caster do: with the same order the repaired buffers equal the z-buffer's bit for
bit.  Only the *count* ignores points nearer by less than ``DEPTH_EPS`` (float noise
where coplanar surfaces meet), so a noise-level difference is repaired but does not
make the frame "inconsistent".
"""

from __future__ import annotations

import numba as nb
import numpy as np

from service.display import DisplaySettings
from service.render.occlusion import Visibility
from service.render.raster import row_span, triangle_setup
from service.render.scene import SceneArrays

SENTINEL = 1 << 30  # the thesis used 2000: larger than any step
DEPTH_EPS = 1e-6  # world units; nearer than this is not "inconsistent"


def occluded(row: list[int], step: int, stepspace: int = 1, tracker: int = 0) -> tuple[bool, int]:
    """The thesis's occluded() function on one linerow, written for reading.

    Parameters
    ----------
    row : list of int
        The linerow: ``[min0, max0, min1, max1, ..., SENTINEL, ...]``, updated in
        place (it must have room for two more entries).
    step : int
        The point's step value.
    stepspace : int
        Distance between consecutive steps.
    tracker : int
        Index to start the search at (0 for a new linerow).

    Returns
    -------
    occluded : bool
    tracker : int
        Where the next search on this linerow should start.
    """
    if row[0] == SENTINEL:  # empty linerow
        row[0] = row[1] = step
        return False, 0
    if step <= row[0]:
        if step == row[0]:
            return True, 0
        if step == row[0] - stepspace:  # extends the first line downward
            row[0] = step
        else:  # makes its own line before all others
            row[2:] = row[:-2]
            row[0] = row[1] = step
        return False, 0
    ref1 = tracker if row[tracker] <= step else 0
    while row[ref1 + 1] <= step:  # cycle to the reference entries
        ref1 += 1
    ref2 = ref1 + 1
    if ref1 % 2 == 0 or step == row[ref1] or step == row[ref2]:
        return True, ref1  # in a line, or ends/starts one
    low, high = row[ref1] + stepspace == step, row[ref2] - stepspace == step
    if low and high:  # fills the gap: the two lines merge
        row[ref1:-2] = row[ref1 + 2 :]
        row[-2:] = [SENTINEL, SENTINEL]
        return False, ref1 - 1
    if low or high:  # extends a line
        row[ref1 if low else ref2] = step
        return False, ref1 if low else ref2
    row[ref2 + 2 :] = row[ref2:-2]  # makes its own line
    row[ref2] = row[ref2 + 1] = step
    return False, ref2 + 1


@nb.njit(cache=True, nogil=True, inline="always")
def _occluded(row: np.ndarray, step: int, tracker: int) -> tuple[bool, int]:
    """Numba twin of :func:`occluded` with stepspace 1; ``row`` shape (cap,)."""
    if row[0] == SENTINEL:
        row[0] = step
        row[1] = step
        return False, 0
    if step <= row[0]:
        if step == row[0]:
            return True, 0
        if step == row[0] - 1:
            row[0] = step
        else:
            row[2:] = row[:-2].copy()
            row[0] = step
            row[1] = step
        return False, 0
    ref1 = tracker if row[tracker] <= step else 0
    while row[ref1 + 1] <= step:
        ref1 += 1
    ref2 = ref1 + 1
    if ref1 % 2 == 0 or step == row[ref1] or step == row[ref2]:
        return True, ref1
    low = row[ref1] + 1 == step
    high = row[ref2] - 1 == step
    if low and high:
        row[ref1:-2] = row[ref1 + 2 :].copy()
        row[-2] = SENTINEL
        row[-1] = SENTINEL
        return False, ref1 - 1
    if low:
        row[ref1] = step
        return False, ref1
    if high:
        row[ref2] = step
        return False, ref2
    n = ref2
    while row[n] != SENTINEL:  # shift only the used part
        n += 1
    for i in range(n + 1, ref2 + 1, -1):
        row[i] = row[i - 2]
    row[ref2] = step
    row[ref2 + 1] = step
    return False, ref2 + 1


@nb.njit(cache=True, nogil=True, parallel=True)
def runlength_kernel(
    proj: np.ndarray,
    tris: np.ndarray,
    order: np.ndarray,
    draw: np.ndarray,
    tri_out: np.ndarray,
    depth_out: np.ndarray,
    inconsistent: np.ndarray,
    repair: bool,
) -> None:
    """Draw triangles nearest first, hiding points with the linerow arrays.

    Parameters
    ----------
    proj : ndarray, shape (Z, V, 3)
    tris : ndarray, shape (T, 3)
    order : ndarray, shape (N,)
        Nearest first.
    draw : ndarray, shape (Z, T), bool
        Per zone, whether a triangle may be drawn at all.
    tri_out : ndarray, shape (Z, R, C), int32, filled with -1
    depth_out : ndarray, shape (Z, R, C), float32, filled with +inf
    inconsistent : ndarray, shape (Z,), int64
        Out: per zone, occluded points that were nearer than the drawn surface.
    repair : bool
        Draw hidden points that are strictly nearer than what was drawn (a z-test on
        just the points the sort got wrong; the z-buffer's tie rule).
    """
    zones, rows, cols = tri_out.shape
    cap = cols + 4
    for z in nb.prange(zones):
        lines = np.full((rows, cap), SENTINEL, np.int64)
        pz = proj[z]
        bad = 0
        for t in order:
            if not draw[z, t]:
                continue
            st = triangle_setup(pz[tris[t, 0]], pz[tris[t, 1]], pz[tris[t, 2]], rows)
            if not st[0]:
                continue
            for r in range(st[1], st[2] + 1):
                c0, c1 = row_span(st[3], st[4], st[5], st[6], st[7], st[8], r, cols)
                tracker = 0
                y = r + 0.5
                for c in range(c0, c1 + 1):
                    hidden, tracker = _occluded(lines[r], c, tracker)
                    d = st[9] + st[10] * (c + 0.5) + st[11] * y
                    if hidden:
                        if d < depth_out[z, r, c] - DEPTH_EPS:
                            bad += 1
                        if repair and d < depth_out[z, r, c]:  # the z-buffer's tie rule
                            depth_out[z, r, c] = d
                            tri_out[z, r, c] = t
                    else:
                        depth_out[z, r, c] = d
                        tri_out[z, r, c] = t
        inconsistent[z] = bad


def runlength(
    scene: SceneArrays,
    proj: np.ndarray,
    display: DisplaySettings,
    order: np.ndarray,
    repair: bool = False,
    draw: np.ndarray | None = None,
) -> Visibility:
    """Run-length occlusion for every zone.

    Parameters
    ----------
    scene : SceneArrays
    proj : ndarray, shape (Z, V, 3)
    display : DisplaySettings
    order : ndarray, shape (N,), int64
        Triangles nearest first (from the average-z sort).
    repair : bool
        Also draw the hidden points that were nearer than what the sort put first,
        which makes the frame equal to the z-buffer's at the cost of one depth
        comparison per hidden point.
    draw : ndarray, shape (Z, T), bool, optional
        Per zone, the triangles that may be drawn (default: all in ``order``).

    Returns
    -------
    Visibility
        ``stats["inconsistent_pixels"]`` counts hidden points that were nearer than
        the surface drawn: where the sort, not the scene, decided.
    """
    vis = Visibility.empty(display.zones, display.rows, display.cols)
    bad = np.zeros(display.zones, np.int64)
    if draw is None:
        draw = np.ones((display.zones, scene.triangles.shape[0]), np.bool_)
    runlength_kernel(
        proj,
        scene.triangles,
        np.ascontiguousarray(order),
        draw,
        vis.triangle,
        vis.depth,
        bad,
        repair,
    )
    vis.stats["inconsistent_pixels"] = int(bad.sum())
    vis.stats["inconsistent_by_zone"] = bad.tolist()
    if repair and bad.any():
        vis.stats["fallback"] = "pixel"
    return vis
