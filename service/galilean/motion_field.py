"""Apparent motion from the renderer (seed 002, section 3.2).

Every vertex's apparent (display) velocity, acceleration and jerk come from its
object's motion state and the viewer's
(:func:`service.scene_motion.motion_derivatives`: exact derivatives of the placed
scene, objects' and viewer's motion alike), projected (:func:`vertex_motion`).
Units are pixels (x, y) and depth units (z) per refresh^n.
:func:`vertex_derivatives` (five-point central differences of projections at ``t +
k h``) is the numerical way, kept for billboard clouds and as the tests' reference.

The display's projection is affine (a sheared parallel projection, see
:mod:`service.display`), and a rigid motion keeps a surface point at fixed
barycentric coordinates in its triangle, so a pixel's apparent derivatives are
*exactly* the barycentric interpolation of its triangle's vertex derivatives
(section 3.2's "linear interpolation across the polygon").  The barycentrics are
those of the pixel centre in the projected triangle the visibility buffer names.

Colour derivatives (``dRGB/dt`` and ``d2RGB/dt2`` per refresh, encoded as dA, dB,
dC and d2A, equations 17-18, in 0..255 units) come for flat light from the chain
rule through the light model (:func:`service.render.light.polygon_motion_tables`),
for per-vertex and per-point light from shading the same visibility with the scene
at ``t -+ h`` (:func:`colour_derivatives`).
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
from service.render.occlusion import Visibility
from service.render.pipeline import Renderer, RenderSettings
from service.render.projection import project
from service.render.scene import MotionState, Scene, SceneArrays, Transform, flatten
from service.scene_motion import (
    advance_transform,
    motion_derivatives,
    placements,
    scene_at,
    view_lights,
)

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
    derivatives : ndarray, shape (D, 3, Z, R, C), float32
        Velocity, acceleration (and, D = 3, jerk) of x, y (px) and depth per
        refresh^n; zero where nothing is seen.
    dcolour : ndarray, shape (4, Z, R, C), float32 or None
        dA, dB, dC, d2A per refresh; zero where no triangle is seen.
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


def interpolate(
    tri_map: np.ndarray, triangles: np.ndarray, proj: np.ndarray, vd: np.ndarray
) -> np.ndarray:
    """Per-pixel derivatives by barycentric interpolation of vertex derivatives.

    Along a row a triangle's barycentrics, and so each interpolated derivative,
    are affine in the column: ``A + B x`` (``x`` the pixel centre).  A row sets up
    ``A`` and ``B`` for its nine derivatives once per run of a triangle, and a pixel
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
    _motion_pixels(tri_map, geometry, by_vertex(vd), none,
                   out.reshape(9, n), np.empty((0, 3), np.uint8), np.empty((4, 0), np.float32),
                   np.empty(n, np.int32))
    return out


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


def vertex_object(scene: Scene) -> np.ndarray:
    """Object index of every vertex of the flattened scene, shape (V,), int64."""
    return np.repeat(np.arange(len(scene.objects), dtype=np.int64),
                     [o.mesh.n_vertices for o in scene.objects])


def vertex_motion(vertices: np.ndarray, owner: np.ndarray, rates: tuple[np.ndarray, np.ndarray],
                  display: DisplaySettings) -> np.ndarray:
    """Apparent derivatives 1..3 of every vertex in every zone, from the objects' motion.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
        The flattened scene's vertices at the render time (the viewer's frame).
    owner : ndarray, shape (V,), int64
        Object of each vertex (:func:`vertex_object`).
    rates : (K (3, O + 1, 3, 3), e (3, O + 1, 3))
        :func:`service.scene_motion.motion_derivatives`, per refresh^n.
    display : DisplaySettings

    Returns
    -------
    ndarray, shape (3, Z, V, 3)
        Column, row (px) and depth per refresh^n: the projection is affine, so these
        are :func:`service.render.projection.project` of the world derivatives
        without its offsets.
    """
    return by_order(_vertex_rates(vertices, owner, rates, display))


def _vertex_rates(vertices: np.ndarray, owner: np.ndarray, rates: tuple[np.ndarray, np.ndarray],
                  display: DisplaySettings) -> np.ndarray:
    """:func:`vertex_motion` as :func:`_motion_pixels` reads it, (Z, V, 9) (:func:`by_vertex`)."""
    zv9 = np.empty((display.zones, vertices.shape[0], 9))
    _vertex_motion(np.ascontiguousarray(vertices, np.float64), owner, rates[0], rates[1],
                   display.shears(), display.pixel_size, zv9)
    return zv9


def by_order(zv9: np.ndarray) -> np.ndarray:
    """Vertex derivatives (Z, V, 9) as :func:`_motion_pixels` reads them, as (3, Z, V, 3)."""
    return zv9.reshape(*zv9.shape[:2], 3, 3).transpose(2, 0, 1, 3)


def by_vertex(vd: np.ndarray) -> np.ndarray:
    """Vertex derivatives (3, Z, V, 3) -> (Z, V, 9): a vertex's nine side by side."""
    return np.ascontiguousarray(np.transpose(vd, (1, 2, 0, 3)), np.float64).reshape(
        vd.shape[1], vd.shape[2], 9)


@nb.njit(cache=True, nogil=True, parallel=True)
def _vertex_motion(vertices: np.ndarray, owner: np.ndarray, big_k: np.ndarray, e: np.ndarray,
                   shears: np.ndarray, s: float, vd: np.ndarray) -> None:
    """:func:`vertex_motion` into ``vd`` (Z, V, 9): ``K[n, o] @ x + e[n, o]``, projected.

    Derivative n of component c of vertex v in zone k is ``vd[k, v, 3 n + c]``.
    """
    zones = shears.shape[0]
    for v in nb.prange(vertices.shape[0]):
        o = owner[v]
        x, y, z = vertices[v, 0], vertices[v, 1], vertices[v, 2]
        for n in range(3):
            dx = big_k[n, o, 0, 0] * x + big_k[n, o, 0, 1] * y + big_k[n, o, 0, 2] * z + e[n, o, 0]
            dy = big_k[n, o, 1, 0] * x + big_k[n, o, 1, 1] * y + big_k[n, o, 1, 2] * z + e[n, o, 1]
            dz = big_k[n, o, 2, 0] * x + big_k[n, o, 2, 1] * y + big_k[n, o, 2, 2] * z + e[n, o, 2]
            for k in range(zones):
                vd[k, v, 3 * n] = (dx - dz * shears[k]) / s
                vd[k, v, 3 * n + 1] = -dy / s
                vd[k, v, 3 * n + 2] = -dz


@nb.njit(cache=True, nogil=True, parallel=True)
def _motion_pixels(
    tri_map: np.ndarray, geometry: tuple, vd: np.ndarray, tables: tuple,
    der: np.ndarray, colour: np.ndarray, dcol: np.ndarray, obj: np.ndarray,
) -> None:
    """Every per-pixel map of an update in one pass over the visibility buffer.

    A row is taken run by run (a run: pixels showing one triangle, or none).  In a
    triangle's run the barycentrics, and so each interpolated derivative, are
    affine in the column: ``A + B x`` (``x`` the pixel centre), set up once per run
    and written plane by plane.  Also the object each pixel shows and, from
    per-polygon tables, the colour and its derivatives (a copy per pixel: flat light
    is the same over a polygon).  Empty pixels get the object -1, the background
    colour and zero derivatives (written run by run, plane by plane: 0.29 ms less
    than zeroed maps on the game scene, 0.28 ms more than leaving them unwritten,
    which readers of the whole maps do not allow).

    Parameters
    ----------
    tri_map : ndarray, shape (Z, R, C), int32
    geometry : tuple
        ``(triangles (T, 3), triangle_polygon (T,), polygon_object (P,), proj (Z, V,
        3))`` at the render time.
    vd : ndarray, shape (Z, V, 9)
        Vertex derivatives (:func:`by_vertex`).
    tables : tuple
        ``(table (Z, P, 3) uint8, dtable (Z, P, 4) float32, background (3,) uint8)``
        (:func:`service.render.light.polygon_motion_tables`).
    der : ndarray, shape (3 D, Z*R*C), float32
        Out: the first D derivatives (D = 1..3), plane ``3 k + c`` the (k+1)-th of
        component c (x, y, depth), zero where empty.
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
    planes = der.shape[0]
    nz, nr, nc = tri_map.shape
    n = np.uint64(obj.shape[0])
    tri, derf, colf, dcolf = tri_map.reshape(-1), der.reshape(-1), colour.reshape(-1), \
        dcol.reshape(-1)
    one, three = np.uint64(1), np.uint64(3)
    b0, b1, b2 = bg[0], bg[1], bg[2]
    grey = b0 == b1 and b1 == b2
    for zr in nb.prange(nz * nr):  # flat indices are unsigned: no wraparound checks
        z = zr // nr
        y, base = zr % nr + 0.5, np.uint64(zr * nc)
        i0, row_end = base, base + np.uint64(nc)
        while i0 < row_end:
            t = tri[i0]
            i1 = i0 + one
            while i1 < row_end and tri[i1] == t:
                i1 += one
            if t < 0:  # zeros plane by plane: cheaper here than a zeroed allocation
                for i in range(i0, i1):
                    obj[i] = -1
                for j in range(planes):
                    off = np.uint64(j) * n
                    for i in range(off + i0, off + i1):
                        derf[i] = 0.0
                if dpaint:
                    for j in range(4):
                        off = np.uint64(j) * n
                        for i in range(off + i0, off + i1):
                            dcolf[i] = 0.0
                if paint and grey:  # one byte value: a fill
                    for i in range(three * i0, three * i1):
                        colf[i] = b0
                elif paint:
                    for i in range(i0, i1):
                        colf[three * i] = b0
                        colf[three * i + one] = b1
                        colf[three * i + np.uint64(2)] = b2
                i0 = i1
                continue
            ta, tb, tc = triangles[t, 0], triangles[t, 1], triangles[t, 2]
            ax, ay = proj[z, ta, 0], proj[z, ta, 1]
            ex, ey = proj[z, tb, 0] - ax, proj[z, tb, 1] - ay  # b - a
            fx, fy = proj[z, tc, 0] - ax, proj[z, tc, 1] - ay  # c - a
            det = ex * fy - fx * ey
            # w1 = u1 + s1 x, w2 = u2 + s2 x on this row
            u1 = u2 = 1.0 / 3.0
            s1 = s2 = 0.0
            if det != 0.0:
                py = y - ay
                s1, u1 = fy / det, (-ax * fy - fx * py) / det
                s2, u2 = -ey / det, (ex * py + ax * ey) / det
            x0 = np.float64(i0 - base) + 0.5
            p = tri_poly[t]
            single = i1 == i0 + one  # most runs: loops of one cost more than the writes
            for j in range(planes):
                v0 = vd[z, ta, j]
                d1, d2 = vd[z, tb, j] - v0, vd[z, tc, j] - v0
                ca, cb = v0 + u1 * d1 + u2 * d2, s1 * d1 + s2 * d2
                off, x = np.uint64(j) * n, x0
                if single:
                    derf[off + i0] = ca + cb * x
                    continue
                for i in range(i0, i1):
                    derf[off + i] = ca + cb * x
                    x += 1.0
            o = poly_obj[p]
            if single:
                obj[i0] = o
                if paint:
                    colf[three * i0] = table[z, p, 0]
                    colf[three * i0 + one] = table[z, p, 1]
                    colf[three * i0 + np.uint64(2)] = table[z, p, 2]
                if dpaint:
                    for j in range(4):
                        dcolf[np.uint64(j) * n + i0] = dtable[z, p, j]
                i0 = i1
                continue
            for i in range(i0, i1):
                obj[i] = o
            if paint:
                c0, c1, c2 = table[z, p, 0], table[z, p, 1], table[z, p, 2]
                for i in range(i0, i1):
                    colf[three * i] = c0
                    colf[three * i + one] = c1
                    colf[three * i + np.uint64(2)] = c2
            if dpaint:
                for j in range(4):
                    dv, off = dtable[z, p, j], np.uint64(j) * n
                    for i in range(i0, i1):
                        dcolf[off + i] = dv
            i0 = i1


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
    order: int = 3,
) -> RenderedUpdate:
    """Render the scene at time ``t`` (seconds after its state) with per-pixel motion.

    One flatten and one visibility pass, at ``t``.  Every vertex's apparent
    velocity, acceleration and jerk come from its object's motion state and the
    viewer's (:func:`service.scene_motion.motion_derivatives`, :func:`vertex_motion`).
    With flat (``polygon``) light one pass over the polygons shown gives their
    colour and its first and second time derivatives by the chain rule
    (:func:`service.render.light.polygon_motion_tables`), and one pass over the
    pixels (:func:`_motion_pixels`) writes colour, colour derivatives, motion
    derivatives and the object map.  Per-vertex and per-point light shade the
    pixels at ``t - h, t, t + h`` (the scene placed at each) and take central
    differences (:func:`colour_derivatives`); billboard clouds (no motion of their
    own, only the viewer's) are differentiated from their corners at ``t - 2h ..
    t + 2h``.

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
        Difference step in refreshes (per-vertex and per-point light, billboards).
    order : int
        The Galilean order the update is for: the jerk maps are made only for 3
        (or with billboard clouds in the scene).

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
    pos, quat = placements(scene, [t], viewer, viewer_motion)
    now = flatten(scene, quat[0], pos[0])
    rates = motion_derivatives(scene, t, period, viewer, viewer_motion)
    vis, _, proj = renderer.visibility(now, display, settings)
    zv9 = _vertex_rates(now.vertices, vertex_object(scene), rates, display)
    pose = None if viewer is None else advance_transform(viewer, viewer_motion or MotionState(), t)
    lights = scene.lights if pose is None else view_lights(scene.lights, pose)
    boards = None
    if scene.billboards:  # into the same depth buffer, as Renderer.render draws them
        dts = [t + k * h * period for k in (-2, -1, 0, 1, 2)]
        clouds = [scene_at(scene, dt, viewer, viewer_motion).billboards for dt in dts]
        boards = draw_billboards(clouds[2], display, vis, settings.method, lights,
                                 scene.ambient, settings.light)
        stats["billboards"] = boards.stats
    tri_map = np.ascontiguousarray(vis.triangle, np.int32)
    zrc = tri_map.shape
    kd = 3 if order >= 3 or boards is not None else 2
    der = np.empty((kd, 3, *zrc), np.float32)
    obj = np.empty(zrc, np.int32)
    flat = settings.light.evaluation == "polygon"
    if flat:
        colour = np.empty((*zrc, 3), np.uint8)
        dcol = np.empty((4, *zrc), np.float32) if colour_motion else None
        tables = polygon_motion_tables(now, vis, display, lights, scene.ambient, settings.light,
                                       rates if colour_motion else None, 255.0, RGB_TO_ABC)
    else:
        colour = shade(now, proj, vis, display, lights, scene.ambient, settings.light)
        dcol = _shaded_colour_motion(scene, now, proj, vis, display, (t, h, period),
                                     (viewer, viewer_motion), settings) if colour_motion else None
        tables = (np.zeros((0, 0, 3), np.uint8), np.zeros((0, 0, 4), np.float32),
                  np.zeros(3, np.uint8))
    n = tri_map.size
    _motion_pixels(
        tri_map, (now.triangles, now.triangle_polygon, now.polygon_object, proj),
        zv9, tables, der.reshape(3 * kd, n),
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
    points = proj[..., :2].reshape(-1, 2)
    pder = by_order(zv9)[..., :2].reshape(3, -1, 2)
    return RenderedUpdate(frame, der, dcol, obj, viewer_motion or MotionState(), points, pder)


def _shaded_colour_motion(
    scene: Scene, now: SceneArrays, proj: np.ndarray, vis: Visibility, display: DisplaySettings,
    times: tuple[float, float, float], view: tuple, settings: RenderSettings,
) -> np.ndarray:
    """Colour derivatives of per-vertex or per-point light: the scene shaded at ``t -+ h``.

    ``times`` is ``(t, h, period)``: the render time (s), the step in refreshes and
    the refresh period (s); ``view`` is ``(viewer, viewer_motion)``; ``now`` and
    ``proj`` are the scene at ``t`` and its projection.  Returns (4, Z, R, C) float32.
    """
    t, h, period = times
    viewer, motion = view
    dts = (t - h * period, t, t + h * period)
    pos, quat = placements(scene, [dts[0], dts[2]], viewer, motion)
    lin = []
    for i, dt in enumerate(dts):
        arrays = now if i == 1 else flatten(scene, quat[i // 2], pos[i // 2])
        lights = scene.lights if viewer is None else view_lights(
            scene.lights, advance_transform(viewer, motion or MotionState(), dt))
        lin.append(shade_linear(arrays, proj if i == 1 else project(arrays.vertices, display),
                                vis, display, lights, scene.ambient, settings.light))
    return colour_derivatives(lin, h)
