"""The render pipeline's warm-up jobs (:mod:`service.warmup` runs them).

Mesh builders, each render method and light model through ``Renderer.render`` (as
``holo-render`` and the game call it) and ``render_with_motion`` (as the workers
do), and the depth-only shadow renders of local updates.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from service.builtin_scenes import SCENES
from service.galilean.galpixmap import RGB_TO_ABC
from service.galilean.motion_field import render_with_motion
from service.galilean.shadow import shadow_depth
from service.render.cull import cull_zones
from service.render.depth_sort import kept_triangles, tie_source
from service.render.light import LightSettings, polygon_motion_tables
from service.render.pipeline import Renderer, RenderSettings
from service.render.projection import project_tables
from service.render.raster import (
    BAND_SETUP,
    _zbuffer_band_zones,
    balanced_bands,
    shared_rows,
    vertex_tables,
)
from service.render.scene import SceneArrays
from service.scene_motion import motion_derivatives
from service.triangulate import ear_clip
from service.warmup_job import FIRST, HERE, Job, Kit


def _scenes(kit: Kit) -> None:
    """Mesh builders: corner normals and ear-clipping of polygons (all built-in scenes)."""
    for name in SCENES:
        kit.scene(name).flatten()
    ear_clip(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.5, 0.4], [0.0, 1.0]]))


def _render(method: str, model: str = "blinn", evaluation: str = "polygon",
            fallback: str = "frame", frames: bool = True, motion: bool = True) -> Callable:
    """A render job: frames and renders with motion.

    ``Renderer.render`` as holo-render and the game call it (light into uint8;
    ``frames``), and ``render_with_motion`` as the service's workers do (light into
    float32 too; ``motion``).
    """

    def job(kit: Kit) -> None:
        settings = RenderSettings(method=method, light=LightSettings(model, evaluation),
                                  painter_fallback=fallback)
        renderer = Renderer()
        for name in ("game", "cyclic"):  # cyclic: the painter's fallback too
            if frames:
                renderer.render(kit.scene(name), kit.display, settings)
            if motion:
                render_with_motion(renderer, kit.scene(name), kit.display, 0.1, 60.0, settings)

    return job


def _cull_sort(kit: Kit) -> None:
    """Stages 1-3 of the service's render: project (by vertex too), cull, depth keys.

    The first third of its first frame's path (see :func:`_visibility`), and the
    one-pass z-buffer's planning kernels (rows, vertex tables, bands) and its band
    of several zones (:func:`service.render.raster._zbuffer_band_zones` with its
    callees), called with the types :func:`service.render.raster.zbuffer_zones_kernel`
    calls them with, so that its own compile (the next job) finds them compiled:
    1.2 s and 6 s of CPU moved (docs/compile-time.md).
    """
    cull = RenderSettings().cull
    for name in ("game", "cyclic"):
        arrays = kit.scene(name).flatten()
        proj, xz, yd = project_tables(arrays.vertices, kit.display, True)
        keep, _, draw_t = cull_zones(arrays.normals, arrays.triangle_polygon,
                                     arrays.polygon_closed, kit.display, cull)
        order = np.ascontiguousarray(kept_triangles(arrays.triangle_polygon, keep))
        rows, cols = kit.display.rows, kit.display.cols
        extent = shared_rows(proj, arrays.triangles, order, rows)
        vertex_tables(proj)
        balanced_bands(extent[0], extent[1], rows, 2, cols // 64 + 1, BAND_SETUP)
    _band_zones(kit, arrays, (xz, yd), draw_t, order, extent)


def _band_zones(kit: Kit, arrays: SceneArrays, tables: tuple, draw_t: np.ndarray, order: np.ndarray,
                extent: tuple) -> None:
    """One band of every row of :func:`_cull_sort`'s last scene, as the z-buffer draws it.

    The arguments' types are those :func:`service.render.raster.zbuffer_zones_kernel`
    hands :func:`service.render.raster._zbuffer_band_zones` (as
    :func:`service.render.occlusion.zbuffer.zbuffer` calls it), ties decided by the key.
    """
    zrc = (kit.display.zones, kit.display.rows, kit.display.cols)
    key = tie_source(arrays.vertices, arrays.polygons, arrays.counts, arrays.triangle_polygon)
    marks = np.zeros((1, zrc[0], arrays.n_polygons), np.bool_)
    _zbuffer_band_zones(tables, arrays.triangles, order, draw_t, extent, 0, zrc[1] - 1,
                        np.empty(zrc, np.int32), np.empty(zrc, np.float32),
                        arrays.triangle_polygon, marks, 0, key)


def _visibility(kit: Kit) -> None:
    """Stages 1-4 of the service's render, without light: the z-buffer of its first frame.

    After :func:`_cull_sort` (whose kernels it loads), the one-pass z-buffer (the
    painter's fallback on the cyclic scene); ``render zbuffer`` (light and motion)
    then loads these.  Split in three so that no job compiles for more than the
    15 s budget (docs/compile-time.md).
    """
    renderer = Renderer()
    settings = RenderSettings(method="zbuffer", painter_fallback="frame")  # as _render's
    for name in ("game", "cyclic"):
        renderer.visibility(kit.scene(name).flatten(), kit.display, settings)


def _flat_light(kit: Kit) -> None:
    """Flat light and its time derivatives, as :func:`render_with_motion` computes them.

    :func:`service.render.light.polygon_motion_tables` of the game scene (its parallel
    kernel and the per-chunk body, about 10 s of CPU cold), after :func:`_visibility`
    (whose kernels it loads): in the next job, ``render zbuffer``, they made it 15 s.
    """
    scene = kit.scene("game")
    arrays = scene.flatten()
    settings = RenderSettings(method="zbuffer", painter_fallback="frame")  # as _render's
    vis, _, _ = Renderer().visibility(arrays, kit.display, settings)
    rates = motion_derivatives(scene, 0.1, 1.0 / 60.0)
    polygon_motion_tables(arrays, vis, kit.display, scene.lights, scene.ambient, settings.light,
                          rates, 255.0, RGB_TO_ABC)


def _shadows(kit: Kit) -> None:
    """Depth-only shadow renders (:mod:`service.galilean.shadow`): cull, sort, z-buffer.

    The local-update job reaches them too, but they are render kernels, not
    Galilean ones: compiled here, in the first process while the second one is
    still in its long service-refresh job, they leave that (longer) process
    sooner, which then loads them from the cache.  Called as ``render_local``
    calls it, so the signatures are the same.
    """
    scene = kit.scene()
    shadow_depth(scene, range(1, len(scene.objects)), kit.display, 0.1, RenderSettings().cull)


#: This subsystem's jobs, in order (:data:`service.warmup.JOBS` gathers them).
WARMUP_JOBS: dict[str, Job] = {
    "scenes: normals, triangulation": Job(_scenes, FIRST, first_frame=True),
    # the service's render first (its workers' path) in four jobs, each under 15 s:
    # cull and sort, the z-buffer, flat light tables, light and motion (2026-11-29); the
    # uint8 frames of holo-render and --local after, off a cold service's first frame
    "render: project, cull, sort": Job(_cull_sort, FIRST, service=True, first_frame=True),
    "render zbuffer: visibility": Job(_visibility, FIRST, service=True, first_frame=True),
    "render: flat light tables": Job(_flat_light, FIRST, service=True, first_frame=True),
    "render zbuffer": Job(_render("zbuffer", frames=False), FIRST, service=True,
                          first_frame=True),
    "render zbuffer, frames": Job(_render("zbuffer", motion=False), FIRST),
    "light ambient": Job(_render("zbuffer", "ambient"), FIRST),
    "light phong": Job(_render("zbuffer", "phong"), FIRST),
    # first of the HERE jobs: see _shadows
    "galilean: depth-only shadows": Job(_shadows, HERE),
    "render runlength": Job(_render("runlength"), HERE),
    "render runlength, pixel fallback": Job(_render("runlength", fallback="pixel"), HERE,
                                            after="render runlength"),
    "render bsp": Job(_render("bsp"), HERE),
    "render raycast": Job(_render("raycast"), HERE),
    "light vertex (Gouraud)": Job(_render("zbuffer", "blinn", "vertex"), HERE),
    "light point (per pixel)": Job(_render("zbuffer", "blinn", "point"), HERE),
}
