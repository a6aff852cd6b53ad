"""Occlusion by a z-buffer per view zone (numba kernel, zones in parallel)."""

from __future__ import annotations

import numpy as np

from service.display import DisplaySettings
from service.occlusion import Visibility
from service.raster import zbuffer_kernel
from service.scene import SceneArrays


def zbuffer(
    scene: SceneArrays,
    proj: np.ndarray,
    display: DisplaySettings,
    order: np.ndarray,
    draw: np.ndarray | None = None,
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
    draw : ndarray, shape (Z, T), bool, optional
        Per zone, the triangles that may be drawn (default: all in ``order``); see
        :func:`service.cull.zone_mask`.

    Returns
    -------
    Visibility
        Ties in depth go to the triangle drawn first.
    """
    vis = Visibility.empty(display.zones, display.rows, display.cols)
    if draw is None:
        draw = np.ones((display.zones, scene.triangles.shape[0]), np.bool_)
    order = np.ascontiguousarray(order)
    zbuffer_kernel(proj, scene.triangles, order, draw, vis.triangle, vis.depth)
    return vis
