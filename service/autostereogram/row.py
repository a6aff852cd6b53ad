"""The seed's software SIRD algorithm (AbSIRD), exactly, one kernel over all rows.

For each row, with ``RandW = s(0)`` and ``h(x) = s(0) - s(z(x))``:

1. the right-most repetition is drawn from the pattern, right to left::

       for x = W-1 down to W-RandW:  out[x] = pattern[(x - h(x)) mod Wp]

2. the rest, right to left, copies the pixel one separation to the right::

       for x = W-1-RandW down to 0:  out[x] = out[x + RandW - h(x)]   (= out[x + s(z(x))])

Every pixel of the second loop is one constraint ``out[x] == out[x + s(x)]``, kept
exactly; there is no hidden-surface removal.  Where ``h`` falls by one pixel per
pixel (the seed's ``dz/dx = -1`` slope) ``x + RandW - h(x)`` stays put and the row
repeats one source pixel: the seed's streaks.

Speed: separations come from a vectorised pass
(:func:`service.autostereogram.geometry.separation_rows`); the copy loop reads four
sources before it writes them (when every source lies ``s(1) >= 4`` pixels to the
right they are final), which lets the CPU overlap the loads.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from service.autostereogram.geometry import separation, separation_rows
from service.numba_subroutine import subroutine


@subroutine(nrt=True)
def copy_chain(o: np.ndarray, srow: np.ndarray, start: int, nc: int, unroll: bool) -> None:
    """``o[x] = o[x + srow[x]]`` for x = start down to 0; ``o`` is one row, (W * nc,) uint8.

    ``unroll`` (grey only) reads four sources before writing them: it needs every
    ``srow[x] >= 4``.
    """
    x = start
    if nc == 1 and unroll:
        while x >= 3:
            v0 = o[x + srow[x]]
            v1 = o[x - 1 + srow[x - 1]]
            v2 = o[x - 2 + srow[x - 2]]
            v3 = o[x - 3 + srow[x - 3]]
            o[x] = v0
            o[x - 1] = v1
            o[x - 2] = v2
            o[x - 3] = v3
            x -= 4
        while x >= 0:
            o[x] = o[x + srow[x]]
            x -= 1
    while x >= 0:
        d = x * nc
        src = (x + srow[x]) * nc
        for c in range(nc):
            o[d + c] = o[src + c]
        x -= 1


@nb.njit(cache=True, parallel=True, nogil=True)
def row_kernel(depth: np.ndarray, far: float, inv_range: float, eye_sep: float, mu: float,
               pattern: np.ndarray, out: np.ndarray, sep: np.ndarray,
               counts: np.ndarray) -> None:
    """Draw a SIRD with the seed's two loops, rows in parallel.

    Parameters
    ----------
    depth : ndarray, shape (H, W), float32
        Depth map (``+inf`` empty).
    far, inv_range : float
        Far plane and ``1 / (far - near)``.
    eye_sep, mu : float
        ``E`` in pixels and the depth of field.
    pattern : ndarray, shape (Hp, Wp, C), uint8
    out : ndarray, shape (H, W * C), uint8
        Written (the (H, W, C) image seen flat per row).
    sep : ndarray, shape (H, W), int32
        Scratch: ``s(z)`` per pixel.
    counts : ndarray, shape (H, 3), int64
        Written per row: constraints, hidden (0), NaN depths.
    """
    h, w = depth.shape
    ph, pw, nc = pattern.shape
    randw = separation_rows(depth, far, inv_range, eye_sep, mu, sep, counts)
    unroll = separation(1.0, eye_sep, mu) >= 4
    for y in nb.prange(h):
        srow = sep[y]
        prow = pattern[y % ph]
        o = out[y]
        q = (w - 1 - randw) % pw  # (x - RandW) mod Wp, stepped down with x
        for x in range(w - 1, w - 1 - randw, -1):
            u = q + srow[x]  # (x - h(x)) mod Wp without a division per pixel
            while u >= pw:
                u -= pw
            for c in range(nc):
                o[x * nc + c] = prow[u, c]
            q = q - 1 if q > 0 else pw - 1
        copy_chain(o, srow, w - 1 - randw, nc, unroll)
        counts[y, 0] = w - randw
