"""Apparent motion from the renderer (seed 002, section 3.2).

Every vertex's apparent (display) position is differentiated in time with central
differences of the projected positions at ``t + k h`` (k = -2..2, h a fraction of
a refresh), which includes the objects' and the viewer's motion alike.  Units are
pixels (x, y) and depth units (z) per refresh^n.

The display's projection is affine (a sheared parallel projection, see
:mod:`service.display`), and a rigid motion keeps a surface point at fixed
barycentric coordinates in its triangle, so a pixel's apparent derivatives are
*exactly* the barycentric interpolation of its triangle's vertex derivatives
(section 3.2's "linear interpolation across the polygon").  The barycentrics are
those of the pixel centre in the projected triangle the visibility buffer names.

Colour derivatives come from shading the same visibility with the scene at
``t -+ h``: ``dRGB/dt`` and ``d2RGB/dt2`` per refresh, encoded as dA, dB, dC and
d2A (equations 17-18) in 0..255 units.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numba as nb
import numpy as np

from service.billboard_render import draw_billboards, quad_points
from service.display import DisplaySettings
from service.galilean.galpixmap import RGB_TO_ABC
from service.render.frame import Frame
from service.render.light import polygon_motion_tables, shade, shade_linear
from service.render.pipeline import Renderer, RenderSettings
from service.render.projection import project
from service.render.scene import MotionState, Scene, Transform, flatten
from service.scene_motion import advance_transform, placements, scene_at, view_lights

#: Five-point central-difference weights of the 1st and 2nd derivative, offsets -2..2
#: (the 3rd uses ``(p2 - 2 p1 + 2 m1 - m2) / 2``).
STENCIL = np.array([[1, -8, 0, 8, -1], [-1, 16, -30, 16, -1]], np.float64) / 12.0


@dataclass
class RenderedUpdate:
    """A render with everything the Galilean stage needs.

    Attributes
    ----------
    frame : Frame
        Colour (Z, R, C, 3) uint8 and depth (Z, R, C).
    derivatives : ndarray, shape (3, 3, Z, R, C), float32
        Velocity, acceleration, jerk of x, y (px) and depth per refresh^n.
    dcolour : ndarray, shape (4, Z, R, C), float32 or None
        dA, dB, dC, d2A per refresh.
    obj : ndarray, shape (Z, R, C), int32
        Object index per pixel (-1 empty).
    viewer_motion : MotionState
        The viewer motion baked into ``derivatives``.
    points : ndarray, shape (N, 2), optional
        Control points (projected vertices, all zones) in px at the render time.
    point_derivs : ndarray, shape (3, N, 2), optional
        Their apparent velocity, acceleration and jerk per refresh^n.
    """

    frame: Frame
    derivatives: np.ndarray
    dcolour: np.ndarray | None
    obj: np.ndarray
    viewer_motion: MotionState
    points: np.ndarray | None = None
    point_derivs: np.ndarray | None = None


def vertex_derivatives(projections: np.ndarray, h: float) -> np.ndarray:
    """Derivatives 1..3 from projections at offsets -2h..2h.

    Parameters
    ----------
    projections : ndarray, shape (5, Z, V, 3)
        Projected positions at ``t - 2h, t - h, t, t + h, t + 2h``.
    h : float
        Step in refreshes.

    Returns
    -------
    ndarray, shape (3, Z, V, 3)
        Per refresh, per refresh^2, per refresh^3.
    """
    p = np.asarray(projections, np.float64)
    d1 = _weighted(STENCIL[0], p) / h
    d2 = _weighted(STENCIL[1], p) / h**2
    d3 = (p[4] - 2 * p[3] + 2 * p[1] - p[0]) / (2 * h**3)
    return np.stack([d1, d2, d3])


def _weighted(weights: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``sum_k weights[k] p[k]`` over the leading axis, in element-wise numpy.

    Not ``np.tensordot``: that is a BLAS matrix-vector product, which OpenBLAS
    runs on its own threads for a large scene; those threads then spin for up to
    0.1 s waiting for more work (OpenBLAS's thread timeout), on the cores the
    renderer's and the Galilean stage's numba threads need next.  Beside a 100k
    triangle render that made the following G(2) refresh take 1.7x its CPU time.
    """
    out = weights[0] * p[0]
    for k in range(1, len(weights)):
        if weights[k] != 0.0:
            out += weights[k] * p[k]
    return out


def project_motion(vertices: np.ndarray, display: DisplaySettings,
                   h: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`~service.render.projection.project` at the five times and :func:`vertex_derivatives`.

    One pass over the vertices, the same values bit for bit.

    Parameters
    ----------
    vertices : ndarray, shape (5, V, 3)
        World vertices at ``t - 2h .. t + 2h``.
    display : DisplaySettings
    h : float
        Step in refreshes.

    Returns
    -------
    projections : ndarray, shape (5, Z, V, 3)
    derivatives : ndarray, shape (3, Z, V, 3)
    """
    n = vertices.shape[1]
    proj = np.empty((5, display.zones, n, 3))
    vd = np.empty((3, display.zones, n, 3))
    _project_motion(np.ascontiguousarray(vertices, np.float64), display.shears(),
                    (display.pixel_size, display.width / 2, display.height / 2),
                    STENCIL, (h, h**2, 2 * h**3), proj, vd)
    return proj, vd


@nb.njit(cache=True, nogil=True, parallel=True)
def _project_motion(vertices: np.ndarray, shears: np.ndarray, grid: tuple, stencil: np.ndarray,
                    steps: tuple, proj: np.ndarray, vd: np.ndarray) -> None:
    """:func:`project_motion` into ``proj`` (5, Z, V, 3) and ``vd`` (3, Z, V, 3).

    ``grid`` is ``(pixel size, half width, half height)``, ``steps`` ``(h, h^2,
    2 h^3)``; each value is found as :func:`service.render.projection.project` and
    :func:`vertex_derivatives` find it, operation by operation.  Zones differ only
    in the column: a vertex's row and depth, and their derivatives, are found once
    and copied.  Vertices in parallel.
    """
    s, half_width, half_height = grid
    zones = shears.shape[0]
    for v in nb.prange(vertices.shape[1]):
        for i in range(5):
            x, y, z = vertices[i, v, 0], vertices[i, v, 1], vertices[i, v, 2]
            row = (half_height - y) / s
            for k in range(zones):
                proj[i, k, v, 0] = (x - z * shears[k] + half_width) / s
                proj[i, k, v, 1] = row
                proj[i, k, v, 2] = -z
        for k in range(zones):
            _stencil(proj, k, v, 0, stencil, steps, vd, k + 1)
        _stencil(proj, 0, v, 1, stencil, steps, vd, zones)
        _stencil(proj, 0, v, 2, stencil, steps, vd, zones)


@nb.njit(cache=True, nogil=True, inline="always")
def _stencil(proj: np.ndarray, k: int, v: int, d: int, stencil: np.ndarray, steps: tuple,
             vd: np.ndarray, k_end: int) -> None:
    """:func:`vertex_derivatives` of ``proj[:, k, v, d]`` into ``vd[:, k:k_end, v, d]``."""
    w1, w2 = stencil[0], stencil[1]
    p0, p1, p2 = proj[0, k, v, d], proj[1, k, v, d], proj[2, k, v, d]
    p3, p4 = proj[3, k, v, d], proj[4, k, v, d]
    a = w1[0] * p0
    a += w1[1] * p1
    a += w1[3] * p3  # w1[2] is 0: vertex_derivatives skips it too
    a += w1[4] * p4
    b = w2[0] * p0
    b += w2[1] * p1
    b += w2[2] * p2
    b += w2[3] * p3
    b += w2[4] * p4
    c = (p4 - 2 * p3 + 2 * p1 - p0) / steps[2]
    for kk in range(k, k_end):
        vd[0, kk, v, d] = a / steps[0]
        vd[1, kk, v, d] = b / steps[1]
        vd[2, kk, v, d] = c


def interpolate(
    tri_map: np.ndarray, triangles: np.ndarray, proj: np.ndarray, vd: np.ndarray
) -> np.ndarray:
    """Per-pixel derivatives by barycentric interpolation of vertex derivatives.

    Along a row a triangle's barycentrics, and so each interpolated derivative,
    are affine in the column: ``A + B x`` (``x`` the pixel centre).  A row sets up
    ``A`` and ``B`` for its nine derivatives where the triangle changes, and a pixel
    then costs nine multiply-adds.  Rows run in parallel.  This is
    :func:`_motion_pixels` (which :func:`render_with_motion` runs) without the maps
    other than the derivatives.

    Parameters
    ----------
    tri_map : ndarray, shape (Z, R, C), int32
        Triangle seen at each pixel, -1 empty.
    triangles : ndarray, shape (T, 3), int64
    proj : ndarray, shape (Z, V, 3)
        Projection at the render time.
    vd : ndarray, shape (3, Z, V, 3)
        Vertex derivatives.

    Returns
    -------
    ndarray, shape (3, 3, Z, R, C), float32
        Zero where empty; a degenerate (zero-area) triangle gets its vertices' mean.
    """
    tri_map = np.ascontiguousarray(tri_map, np.int32)
    out = np.empty((3, 3, *tri_map.shape), np.float32)
    n = tri_map.size
    none = (np.zeros((0, 0, 3), np.uint8), np.zeros((0, 0, 4), np.float32), np.zeros(3, np.uint8))
    geometry = (np.ascontiguousarray(triangles, np.int64),
                np.zeros(triangles.shape[0], np.int64), np.zeros(1, np.int64),
                np.ascontiguousarray(proj, np.float64))
    _motion_pixels(tri_map, geometry, np.ascontiguousarray(vd, np.float64), none,
                   out.reshape(9, n), np.empty((0, 3), np.uint8), np.empty((4, 0), np.float32),
                   np.empty(n, np.int32))
    return out


@nb.njit(cache=True, nogil=True, inline="always")
def _row_setup(tri: np.ndarray, proj: np.ndarray, vd: np.ndarray, y: float,
               coef: np.ndarray) -> None:
    """``coef`` (2, 9): A and B of ``A + B x`` for each derivative, along row ``y``."""
    i0, i1, i2 = tri[0], tri[1], tri[2]
    ax, ay = proj[i0, 0], proj[i0, 1]
    ex, ey = proj[i1, 0] - ax, proj[i1, 1] - ay  # b - a
    fx, fy = proj[i2, 0] - ax, proj[i2, 1] - ay  # c - a
    det = ex * fy - fx * ey
    # w1 = u1 + s1 x, w2 = u2 + s2 x on this row
    u1 = u2 = 1.0 / 3.0
    s1 = s2 = 0.0
    if det != 0.0:
        py = y - ay
        s1, u1 = fy / det, (-ax * fy - fx * py) / det
        s2, u2 = -ey / det, (ex * py + ax * ey) / det
    for k in range(3):
        for d in range(3):
            v0 = vd[k, i0, d]
            d1, d2 = vd[k, i1, d] - v0, vd[k, i2, d] - v0
            coef[0, 3 * k + d] = v0 + u1 * d1 + u2 * d2
            coef[1, 3 * k + d] = s1 * d1 + s2 * d2


@nb.njit(cache=True, nogil=True, parallel=True)
def _colour_derivatives(
    m: np.ndarray, c0: np.ndarray, p: np.ndarray, h: float, weights: np.ndarray, out: np.ndarray
) -> None:
    """:func:`colour_derivatives` on flat (N, 3) frames into ``out`` (4, N)."""
    s1, s2 = 255.0 / (2.0 * h), 255.0 / (h * h)
    for i in nb.prange(m.shape[0]):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += weights[j, k] * (np.float64(p[i, k]) - np.float64(m[i, k]))
            out[j, i] = acc * s1
        acc = 0.0
        for k in range(3):
            acc += weights[0, k] * (np.float64(p[i, k]) - 2.0 * np.float64(c0[i, k])
                                    + np.float64(m[i, k]))
        out[3, i] = acc * s2


def colour_derivatives(
    frames: list[np.ndarray], h: float
) -> np.ndarray:
    """dA, dB, dC, d2A per refresh from linear colour at ``t - h, t, t + h``.

    Central differences (equations 17-18's A, B, C of the colour's first
    derivative, and A of its second), in float64, one pass over the pixels.

    Parameters
    ----------
    frames : list of 3 ndarrays, shape (Z, R, C, 3), float in [0, 1]
    h : float
        Step in refreshes.

    Returns
    -------
    ndarray, shape (4, Z, R, C), float32
        In 0..255 units.
    """
    shape = np.shape(frames[1])[:-1]
    if len(frames) != 3 or any(np.shape(f) != (*shape, 3) for f in frames):
        raise ValueError(f"colour_derivatives needs 3 frames of one (..., 3) shape, got "
                         f"{[np.shape(f) for f in frames]}")
    flat = [np.ascontiguousarray(f).reshape(-1, 3) for f in frames]
    out = np.empty((4, *shape), np.float32)
    _colour_derivatives(*flat, float(h), RGB_TO_ABC, out.reshape(4, -1))
    return out


@nb.njit(cache=True, nogil=True, parallel=True)
def _motion_pixels(
    tri_map: np.ndarray, geometry: tuple, vd: np.ndarray, tables: tuple,
    der: np.ndarray, colour: np.ndarray, dcol: np.ndarray, obj: np.ndarray,
) -> None:
    """Every per-pixel map of an update in one pass over the visibility buffer.

    Motion derivatives as :func:`interpolate` finds them (the same arithmetic), the
    object each pixel shows, and, from per-polygon tables, the colour and its
    derivatives (a copy per pixel: flat light is the same over a polygon).

    Parameters
    ----------
    tri_map : ndarray, shape (Z, R, C), int32
    geometry : tuple
        ``(triangles (T, 3), triangle_polygon (T,), polygon_object (P,), proj (Z, V,
        3))`` at the render time.
    vd : ndarray, shape (3, Z, V, 3)
        Vertex derivatives.
    tables : tuple
        ``(table (Z, P, 3) uint8, dtable (Z, P, 4) float32, background (3,) uint8)``
        (:func:`service.render.light.polygon_motion_tables`).
    der : ndarray, shape (9, Z*R*C), float32
        Out: the derivatives (zero where empty).
    colour : ndarray, shape (Z*R*C, 3) or (0, 3), uint8
        Out, unless it has no rows: colour (the background where empty).
    dcol : ndarray, shape (4, Z*R*C) or (4, 0), float32
        Out, unless it has no columns: colour derivatives (zero where empty).
    obj : ndarray, shape (Z*R*C,), int32
        Out: object index (-1 where empty).
    """
    triangles, tri_poly, poly_obj, proj = geometry
    table, dtable, bg = tables
    paint, dpaint = colour.shape[0] > 0, dcol.shape[1] > 0
    nz, nr, nc = tri_map.shape
    for zr in nb.prange(nz * nr):
        z, r = zr // nr, zr % nr
        y, base = r + 0.5, zr * nc
        coef = np.empty((2, 9))  # A, B per derivative (k, d)
        last, c = -1, 0
        while c < nc:
            t = tri_map[z, r, c]
            if t < 0:  # a run of empty pixels, written map by map
                end = c + 1
                while end < nc and tri_map[z, r, end] < 0:
                    end += 1
                _write_empty(base + c, base + end, bg, der, colour, dcol, obj)
                c = end
                continue
            if t != last:
                last = t
                _row_setup(triangles[t], proj[z], vd[:, z], y, coef)
            i, x = base + c, c + 0.5
            for j in range(9):
                der[j, i] = coef[0, j] + coef[1, j] * x
            p = tri_poly[t]
            obj[i] = poly_obj[p]
            if paint:
                colour[i, 0], colour[i, 1], colour[i, 2] = table[z, p, 0], table[z, p, 1], \
                    table[z, p, 2]
            if dpaint:
                for j in range(4):
                    dcol[j, i] = dtable[z, p, j]
            c += 1


@nb.njit(cache=True, nogil=True, inline="always")
def _write_empty(
    i0: int, i1: int, bg: np.ndarray, der: np.ndarray, colour: np.ndarray, dcol: np.ndarray,
    obj: np.ndarray,
) -> None:
    """:func:`_motion_pixels`' empty pixels ``i0..i1-1``: map by map, each loop in order."""
    for j in range(9):
        der[j, i0:i1] = 0.0
    obj[i0:i1] = -1
    if colour.shape[0] > 0 and bg[0] == bg[1] == bg[2]:  # one byte value: a fill
        colour.reshape(-1)[3 * i0 : 3 * i1] = bg[0]
    else:
        for i in range(i0, min(i1, colour.shape[0])):
            colour[i, 0], colour[i, 1], colour[i, 2] = bg[0], bg[1], bg[2]
    for j in range(dcol.shape[0] if dcol.shape[1] > 0 else 0):
        dcol[j, i0:i1] = 0.0


def render_with_motion(
    renderer: Renderer,
    scene: Scene,
    display: DisplaySettings,
    t: float,
    refresh_hz: float,
    settings: RenderSettings | None = None,
    viewer: Transform | None = None,
    viewer_motion: MotionState | None = None,
    colour_motion: bool = True,
    h: float = 0.25,
) -> RenderedUpdate:
    """Render the scene at time ``t`` (seconds after its state) with per-pixel motion.

    One visibility pass, at ``t``; the scene is only placed (not rendered) at the
    other four times, for the vertex derivatives.  With flat (``polygon``) light,
    light at ``t - h, t, t + h`` is one pass over the polygons shown
    (:func:`service.render.light.polygon_motion_tables`), and one pass over the pixels
    (:func:`_motion_pixels`) writes colour, colour derivatives, motion derivatives
    and the object map.  Per-vertex and per-point light shade the pixels at the
    three times (:func:`service.render.light.shade_linear`).

    Parameters
    ----------
    renderer : Renderer
    scene : Scene
        Objects with their motion states, at time 0.
    display : DisplaySettings
    t : float
        Render time in seconds.
    refresh_hz : float
        Refresh rate: derivatives are per refresh period ``1 / refresh_hz``.
    settings : RenderSettings, optional
    viewer, viewer_motion : optional
        The viewer's pose and motion at time 0 (None: fixed at the identity).
    colour_motion : bool
        Also compute colour derivatives.
    h : float
        Difference step in refreshes.

    Returns
    -------
    RenderedUpdate
    """
    settings = settings or RenderSettings()
    stats: dict = {"t": t}
    lod = settings.lod is not None and settings.lod.enabled
    if lod:  # each object at its level of detail
        scene, stats["lod"] = renderer.lod.apply(scene, display, settings.lod, False,
                                                  settings.method, settings.light.evaluation)
    t0 = time.perf_counter()
    period = 1.0 / refresh_hz
    dts = [t + k * h * period for k in (-2, -1, 0, 1, 2)]
    pos, quat = placements(scene, dts, viewer, viewer_motion)
    arrays = [flatten(scene, quat[i], pos[i]) for i in range(5)]
    projs, vd = project_motion(np.stack([a.vertices for a in arrays]), display, h)
    now = arrays[2]
    lights = [scene.lights] * 5 if viewer is None else [
        view_lights(scene.lights, advance_transform(viewer, viewer_motion or MotionState(), dt))
        for dt in dts]
    vis, _, _ = renderer.visibility(now, display, settings)
    boards = None
    if scene.billboards:  # into the same depth buffer, as Renderer.render draws them
        clouds = [scene_at(scene, dt, viewer, viewer_motion).billboards for dt in dts]
        boards = draw_billboards(clouds[2], display, vis, settings.method, lights[2],
                                 scene.ambient, settings.light)
        stats["billboards"] = boards.stats
    tri_map = np.ascontiguousarray(vis.triangle, np.int32)
    zrc = tri_map.shape
    der = np.empty((3, 3, *zrc), np.float32)
    obj = np.empty(zrc, np.int32)
    flat = settings.light.evaluation == "polygon"
    times = (1, 2, 3) if colour_motion else (2,)
    if flat:
        colour = np.empty((*zrc, 3), np.uint8)
        dcol = np.empty((4, *zrc), np.float32) if colour_motion else None
        tables = polygon_motion_tables(
            [arrays[i] for i in times], vis, display, [lights[i] for i in times],
            scene.ambient, settings.light, (255.0 / (2.0 * h), 255.0 / (h * h)),
            RGB_TO_ABC)
    else:
        colour = shade(now, projs[2], vis, display, lights[2], scene.ambient,
                       settings.light)  # quantised exactly as Renderer.render does
        dcol = colour_derivatives(
            [shade_linear(arrays[i], projs[i], vis, display, lights[i], scene.ambient,
                          settings.light) for i in (1, 2, 3)],
            h) if colour_motion else None
        tables = (np.zeros((0, 0, 3), np.uint8), np.zeros((0, 0, 4), np.float32),
                  np.zeros(3, np.uint8))
    n = tri_map.size
    _motion_pixels(
        tri_map, (now.triangles, now.triangle_polygon, now.polygon_object,
                  np.ascontiguousarray(projs[2])),
        np.ascontiguousarray(vd), tables, der.reshape(9, n),
        colour.reshape(n, 3) if flat else np.empty((0, 3), np.uint8),
        dcol.reshape(4, n) if flat and dcol is not None else np.empty((4, 0), np.float32),
        obj.reshape(n))
    if boards is not None:  # billboard pixels: their colour, moving with their quads
        boards.paint(colour)
        corners = [project(quad_points(c), display) for c in clouds]
        boards.write_motion(vertex_derivatives(np.stack(corners), h), der)
    if lod:  # the LOD time budget's cost model learns from this render's cost
        renderer.lod.observe(now.triangles.shape[0], (time.perf_counter() - t0) * 1e3)
    frame = Frame(colour=colour, depth=vis.depth, stats=stats)
    points = projs[2][..., :2].reshape(-1, 2)
    pder = vd[..., :2].reshape(3, -1, 2)
    return RenderedUpdate(frame, der, dcol, obj, viewer_motion or MotionState(), points, pder)
