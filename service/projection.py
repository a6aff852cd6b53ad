"""Stage 1: transform and projection for every view zone.

See :mod:`service.display` for the projection each zone uses.
"""

from __future__ import annotations

import numpy as np

from service.display import DisplaySettings


def project(vertices: np.ndarray, display: DisplaySettings) -> np.ndarray:
    """Project world vertices into every zone's pixel grid.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
        World coordinates.
    display : DisplaySettings

    Returns
    -------
    ndarray, shape (Z, V, 3), float64
        ``[..., 0]`` column coordinate sx, ``[..., 1]`` row coordinate sy (pixel
        centres at integer + 0.5), ``[..., 2]`` depth = -z.
    """
    s = display.pixel_size
    shear = display.shears()[:, None]  # (Z, 1)
    x, y, z = vertices[:, 0], vertices[:, 1], vertices[:, 2]
    out = np.empty((display.zones, vertices.shape[0], 3))
    out[:, :, 0] = (x[None, :] - z[None, :] * shear + display.width / 2) / s
    out[:, :, 1] = (display.height / 2 - y)[None, :] / s
    out[:, :, 2] = -z[None, :]
    return out


def unproject(
    zone: int, cols: np.ndarray, rows: np.ndarray, depth: np.ndarray, display: DisplaySettings
) -> np.ndarray:
    """World points seen at pixel centres of one zone at the given depths.

    Parameters
    ----------
    zone : int
    cols, rows : ndarray, shape (N,)
        Integer pixel indices.
    depth : ndarray, shape (N,)
        Depth (-z) of the surface at each pixel.
    display : DisplaySettings

    Returns
    -------
    ndarray, shape (N, 3)
    """
    s = display.pixel_size
    z = -np.asarray(depth, np.float64)
    xp = (np.asarray(cols) + 0.5) * s - display.width / 2
    y = display.height / 2 - (np.asarray(rows) + 0.5) * s
    return np.stack([xp + z * display.shears()[zone], y, z], axis=1)
