"""The display window of a galpixel map: the rows inside the margin copied out.

:func:`show_bands` (rows split between threads) copies each displayed pixel's
colour and depth (scaled by ``zs``) and its debris flag; :func:`show_row` is the
one row copy it uses, and :func:`service.galilean.finish.finish` too, which folds
the display copy into its second pass.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from service.galilean.fixed_point import Z_EMPTY
from service.galilean.propagate import u64


@nb.njit(cache=True, inline="always")
def show_row(
    c0: np.ndarray,
    c1: np.ndarray,
    c2: np.ndarray,
    dep: np.ndarray,
    deb: np.ndarray,
    p0: int,
    n: int,
    out_colour: np.ndarray,
    out_depth: np.ndarray,
    out_debris: np.ndarray,
    o0: int,
    zs: float,
) -> None:
    """Display copy of ``n`` pixels from flat index ``p0`` to output pixel ``o0``.

    Depth goes out as float32 depth units (``zs`` = 2^-fz per fixed-point unit).
    """
    for i in range(n):
        p, o, o3 = u64(p0 + i), u64(o0 + i), u64(3 * (o0 + i))
        out_colour[o3] = np.uint8(min(max(c0[p] + 0.5, 0.0), 255.0))
        out_colour[o3 + np.uint64(1)] = np.uint8(min(max(c1[p] + 0.5, 0.0), 255.0))
        out_colour[o3 + np.uint64(2)] = np.uint8(min(max(c2[p] + 0.5, 0.0), 255.0))
        out_depth[o] = np.inf if dep[p] == Z_EMPTY else dep[p] * zs
        out_debris[o] = deb[p] == 1


def debris_words(debris: np.ndarray) -> np.ndarray:
    """A (Z, H, W) uint8 debris plane's first ``8 (N // 8)`` bytes as uint64 words (a view)."""
    flat_ = debris.reshape(-1)
    return flat_[: flat_.size // 8 * 8].view(np.uint64)


@nb.njit(cache=True, nogil=True, parallel=True)
def show_bands(
    m: tuple,
    shape: tuple,
    margin: int,
    out_colour: np.ndarray,
    out_depth: np.ndarray,
    out_debris: np.ndarray,
    zs: float,
) -> None:
    """Display copy of a map (:func:`planes`, no expansion); outputs flattened too.

    The displayed rows are split between threads (``nb.prange``).  ``zs`` is the
    depth unit (2^-fz) the displayed float32 depth is scaled by.
    """
    nz, h, w = shape
    hh, ww = h - 2 * margin, w - 2 * margin
    (c0, c1, c2), dep, deb = m[0], m[1], m[6]
    for k in nb.prange(nz * hh):
        z, rr = k // hh, k % hh
        show_row(c0, c1, c2, dep, deb, (z * h + rr + margin) * w + margin, ww,
                 out_colour, out_depth, out_debris, k * ww, zs)


