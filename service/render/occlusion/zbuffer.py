"""Occlusion by a z-buffer per view zone (numba kernels).

The default path draws every zone in one pass over the triangles
(:func:`service.render.raster.zbuffer_zones_kernel`, a band of rows per thread, cut where the
threads get equal work): a triangle's
rows, depths and corner order are the same in every zone, so that work is shared.  A
projection whose rows or depths differ between zones (not one
:func:`service.render.projection.project` makes) takes the per-zone kernel; both give
bit-identical buffers.

Given the depth order's source (:func:`service.render.depth_sort.tie_source`), both break
ties in depth inside the depth test as the depth order would, so the triangles need
no sort: the pipeline draws them in index order (a full sort of a million triangles
cost more than a third of the frame).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from service.display import DisplaySettings
from service.render.depth_sort import NO_TIE_SOURCE
from service.render.occlusion import Visibility
from service.render.raster import no_bands, zbuffer_kernel, zbuffer_zones_kernel
from service.render.scene import SceneArrays


def rows_shared(proj: np.ndarray) -> bool:
    """Whether every zone of ``proj`` (Z, V, 3) puts each vertex on the same row and depth.

    True for every projection :func:`service.render.projection.project` makes (zones differ
    only by a shear in x) of finite vertices; the one-pass kernel reads rows and
    depths from zone 0.  A NaN never equals itself, so a projection holding one is
    not shared (as ``np.array_equal`` says).
    """
    return bool(_rows_shared(proj))


@nb.njit(cache=True, nogil=True)
def _rows_shared(proj: np.ndarray) -> bool:
    """Numba body of :func:`rows_shared`: no temporary arrays, stops at the first miss."""
    for z in range(proj.shape[0]):
        for v in range(proj.shape[1]):
            if proj[z, v, 1] != proj[0, v, 1] or proj[z, v, 2] != proj[0, v, 2]:
                return False
    return True


def zbuffer(
    scene: SceneArrays,
    proj: np.ndarray,
    display: DisplaySettings,
    order: np.ndarray,
    draw: np.ndarray | None = None,
    shared: bool = True,
    tri_out: np.ndarray | None = None,
    item: np.ndarray | None = None,
    n_items: int = 0,
    draw_t: np.ndarray | None = None,
    tables: tuple[np.ndarray, np.ndarray] | None = None,
    key: tuple | None = None,
) -> Visibility:
    """Z-buffer every zone.

    Parameters
    ----------
    scene : SceneArrays
    proj : ndarray, shape (Z, V, 3)
        From :func:`service.render.projection.project`.
    display : DisplaySettings
    order : ndarray, shape (N,), int64
        Triangles to draw (culled ones left out), in any order with ``key``; without
        it, in the depth order (ties go to the triangle drawn first).
    draw : ndarray, shape (Z, T), bool, optional
        Per zone, the triangles that may be drawn (default: all in ``order``); see
        :func:`service.render.cull.zone_mask`.
    shared : bool
        Draw all zones in one pass (default); False runs the per-zone kernel (the
        reference the one-pass kernel is tested against).
    tri_out : ndarray, shape (Z, R, C), int32, optional
        Buffer to reuse for ``Visibility.triangle`` (contents ignored): a renderer
        that keeps it between frames saves the page faults of a fresh one.
    item : ndarray, shape (T,), optional
        Item of each triangle (e.g. ``SceneArrays.triangle_polygon``), each below
        ``n_items``: the one-pass kernel then also fills ``Visibility.shown``
        (:func:`service.render.light.mark_shown`, at a fraction of its cost); the per-zone
        kernel leaves it None.
    n_items : int
    draw_t : ndarray, shape (T, Z), bool, optional
        ``draw`` by triangle (:func:`service.render.cull.zone_mask` with ``by_triangle``),
        the layout the one-pass kernel reads; given, it replaces ``draw``.
    tables : tuple of ndarray, optional
        ``(xz, yd)`` of :func:`service.render.projection.project_tables` for this ``proj``:
        its rows and depths are shared by construction, so the one-pass kernel runs
        without :func:`rows_shared`'s check and reads these instead of laying the
        projection out by vertex itself (0.03 ms of a 5-zone game frame).
    key : tuple of ndarray, optional
        :func:`service.render.depth_sort.tie_source` of the scene: ties in depth go
        as the depth order has them, the order found only where a tie happens.

    Returns
    -------
    Visibility
        Ties in depth go to the triangle earlier in the depth order (with ``key``),
        else to the triangle drawn first: the same pixels when ``order`` is that order.
    """
    zrc = (display.zones, display.rows, display.cols)
    order = np.ascontiguousarray(order)
    key = NO_TIE_SOURCE if key is None else key
    if draw_t is not None:
        draw = draw_t.T
    elif draw is None:
        draw = np.ones((display.zones, scene.triangles.shape[0]), np.bool_)
    usable = tri_out is not None and tri_out.shape == zrc and tri_out.dtype == np.int32
    tri = tri_out if usable and tri_out.flags.c_contiguous else np.empty(zrc, np.int32)
    if not (shared and (tables is not None or rows_shared(proj))):
        vis = Visibility(tri, np.full(zrc, np.inf, np.float32))
        vis.triangle.fill(-1)
        draw = np.ascontiguousarray(draw)
        zbuffer_kernel(proj, scene.triangles, order, draw, vis.triangle, vis.depth, key)
        return vis
    vis = Visibility(tri, np.empty(zrc, np.float32))
    if item is None:
        item, n_items = np.zeros(0, np.int64), 0
    vis.shown = np.zeros((display.zones, n_items), np.bool_)
    xz, yd = tables if tables is not None else (np.empty((0, display.zones)), np.empty((0, 2)))
    zbuffer_zones_kernel(
        proj, scene.triangles, order, np.ascontiguousarray(draw.T), no_bands(), vis.triangle,
        vis.depth, item, vis.shown, xz, yd, nb.get_num_threads(), key,
    )
    if n_items == 0:
        vis.shown = None
    return vis
