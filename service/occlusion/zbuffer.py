"""Occlusion by a z-buffer per view zone (numba kernel, zones in parallel)."""

from __future__ import annotations

import numpy as np

from service.display import DisplaySettings
from service.occlusion import Visibility
from service.raster import zbuffer_kernel
from service.scene import SceneArrays


def zbuffer(
    scene: SceneArrays, proj: np.ndarray, display: DisplaySettings, order: np.ndarray
) -> Visibility:
    """Z-buffer every zone.

    Parameters
    ----------
    scene : SceneArrays
    proj : ndarray, shape (Z, V, 3)
        From :func:`service.projection.project`.
    display : DisplaySettings
    order : ndarray, shape (N,), int64
        Triangles to draw (culled ones left out); nearest first saves writes.

    Returns
    -------
    Visibility
        Ties in depth go to the triangle drawn first.
    """
    vis = Visibility.empty(display.zones, display.rows, display.cols)
    zbuffer_kernel(proj, scene.triangles, np.ascontiguousarray(order), vis.triangle, vis.depth)
    return vis
