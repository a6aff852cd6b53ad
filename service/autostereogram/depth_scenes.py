"""Depth maps that show where SIRD methods differ (tests, ``holo-bench sird``, the README).

Every map is a distance behind the display plane with ``near = 0`` and ``far = 1``
(so ``z = 1 - depth``), ``+inf`` where empty.
"""

from __future__ import annotations

import numpy as np


def sphere(cols: int, rows: int) -> np.ndarray:
    """A sphere facing the viewer: nearest point at depth 0, rim at 1, empty around it.

    Returns
    -------
    ndarray, shape (rows, cols), float32
    """
    yy, xx = np.mgrid[0:rows, 0:cols]
    r = 0.35 * min(cols, rows)
    q = r * r - (xx - cols / 2) ** 2 - (yy - rows / 2) ** 2
    d = np.full((rows, cols), np.inf, np.float32)
    inside = q > 0
    d[inside] = (r - np.sqrt(q[inside])) / r
    return d


def seed_slope(cols: int, rows: int, rise_px: int) -> np.ndarray:
    """The seed's streak case, repeated: ``z`` climbs 0 -> 1 over ``rise_px`` pixels.

    Pass ``rise_px = s(0) - s(1)`` so the separation shrinks one pixel per pixel; ``z``
    then holds 1 as long and drops to 0.

    Returns
    -------
    ndarray, shape (rows, cols), float32
    """
    x = np.arange(cols)
    z = np.clip((x % (2 * rise_px)) / rise_px, 0.0, 1.0)
    return np.tile((1.0 - z).astype(np.float32), (rows, 1))


def steps(cols: int, rows: int, levels: int = 4) -> np.ndarray:
    """Flat vertical bands at ``levels`` depths, nearest in the middle (depth edges).

    Returns
    -------
    ndarray, shape (rows, cols), float32
    """
    band = np.minimum(np.arange(cols) * (2 * levels) // cols, 2 * levels - 1)
    level = np.minimum(band, 2 * levels - 1 - band)
    return np.tile((1.0 - level / max(1, levels - 1)).astype(np.float32), (rows, 1))
