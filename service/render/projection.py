"""Stage 1: transform and projection for every view zone.

See :mod:`service.display` for the projection each zone uses.
"""

from __future__ import annotations

import numba as nb
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
    return project_tables(vertices, display, tables=False)[0]


def project_tables(
    vertices: np.ndarray, display: DisplaySettings, tables: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`project`, and the same values by vertex, as the one-pass z-buffer reads them.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
    display : DisplaySettings
    tables : bool
        Fill the tables (with several zones only: one zone's z-buffer reads the
        projection as it is, so its tables are always empty).

    Returns
    -------
    proj : ndarray, shape (Z, V, 3), float64
        :func:`project`'s result.
    xz : ndarray, shape (V, Z), or (0, Z) when not filled
        Each vertex's column in every zone, side by side
        (:func:`service.render.raster.vertex_tables`).
    yd : ndarray, shape (V, 2), or (0, 2) when not filled
        Each vertex's row and depth, shared by every zone by construction (the
        z-buffer given them need not check :func:`service.render.occlusion.zbuffer.rows_shared`).
    """
    zones, n = display.zones, vertices.shape[0]
    out = np.empty((zones, n, 3))
    m = n if tables and zones > 1 else 0
    xz, yd = np.empty((m, zones)), np.empty((m, 2))
    _project_kernel(
        np.ascontiguousarray(vertices, np.float64),
        display.shears(),
        display.pixel_size,
        display.width / 2,
        display.height / 2,
        out,
        xz,
        yd,
    )
    return out, xz, yd


@nb.njit(cache=True, nogil=True)
def _project_kernel(
    vertices: np.ndarray,
    shears: np.ndarray,
    s: float,
    half_width: float,
    half_height: float,
    out: np.ndarray,
    xz: np.ndarray,
    yd: np.ndarray,
) -> None:
    """Fill ``out`` (Z, V, 3) from ``vertices`` (V, 3) and ``shears`` (Z,) (see :func:`project`).

    Written out per element with numpy's evaluation order, so the values equal
    ``((x - z * shear) + half_width) / s`` etc. bit for bit.  Zones differ only in
    the column: each vertex's row and depth are computed once and copied.  ``xz``
    (V, Z) and ``yd`` (V, 2) get the same values by vertex, unless they have no rows.
    """
    by_vertex = xz.shape[0] > 0
    for v in range(vertices.shape[0]):
        x, y, z = vertices[v, 0], vertices[v, 1], vertices[v, 2]
        row = (half_height - y) / s
        for k in range(shears.shape[0]):
            col = (x - z * shears[k] + half_width) / s
            out[k, v, 0] = col
            out[k, v, 1] = row
            out[k, v, 2] = -z
            if by_vertex:
                xz[v, k] = col
        if by_vertex:
            yd[v, 0] = row
            yd[v, 1] = -z


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
