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

from dataclasses import dataclass

import numba as nb
import numpy as np

from service.display import DisplaySettings
from service.frame import Frame
from service.galilean.galpixmap import RGB_TO_ABC
from service.light import shade, shade_linear
from service.occlusion import Visibility
from service.pipeline import Renderer, RenderSettings
from service.projection import project
from service.scene import MotionState, Scene, Transform
from service.scene_motion import scene_at

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
    d1 = np.tensordot(STENCIL[0], p, axes=1) / h
    d2 = np.tensordot(STENCIL[1], p, axes=1) / h**2
    d3 = (p[4] - 2 * p[3] + 2 * p[1] - p[0]) / (2 * h**3)
    return np.stack([d1, d2, d3])


@nb.njit(cache=True)
def interpolate(
    tri_map: np.ndarray, triangles: np.ndarray, proj: np.ndarray, vd: np.ndarray
) -> np.ndarray:
    """Per-pixel derivatives by barycentric interpolation of vertex derivatives.

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
        Zero where empty.
    """
    nz, nr, nc = tri_map.shape
    out = np.zeros((3, 3, nz, nr, nc), np.float32)
    for z in range(nz):
        for r in range(nr):
            for c in range(nc):
                t = tri_map[z, r, c]
                if t < 0:
                    continue
                i0, i1, i2 = triangles[t, 0], triangles[t, 1], triangles[t, 2]
                ax, ay = proj[z, i0, 0], proj[z, i0, 1]
                bx, by = proj[z, i1, 0], proj[z, i1, 1]
                cx, cy = proj[z, i2, 0], proj[z, i2, 1]
                det = (bx - ax) * (cy - ay) - (cx - ax) * (by - ay)
                w1 = w2 = 1.0 / 3.0
                if det != 0.0:
                    x, y = c + 0.5, r + 0.5
                    w1 = ((x - ax) * (cy - ay) - (cx - ax) * (y - ay)) / det
                    w2 = ((bx - ax) * (y - ay) - (x - ax) * (by - ay)) / det
                w0 = 1.0 - w1 - w2
                for k in range(3):
                    for d in range(3):
                        out[k, d, z, r, c] = (w0 * vd[k, z, i0, d] + w1 * vd[k, z, i1, d]
                                              + w2 * vd[k, z, i2, d])
    return out


def colour_derivatives(
    frames: list[np.ndarray], h: float
) -> np.ndarray:
    """dA, dB, dC, d2A per refresh from linear colour at ``t - h, t, t + h``.

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
    m, c0, p = (np.asarray(f, np.float64) * 255.0 for f in frames)
    d1 = (p - m) / (2 * h)
    d2 = (p - 2 * c0 + m) / h**2
    abc = d1 @ RGB_TO_ABC.T
    d2a = d2 @ RGB_TO_ABC[0]
    return np.concatenate([np.moveaxis(abc, -1, 0), d2a[None]]).astype(np.float32)


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
        Also compute colour derivatives (two extra shading passes).
    h : float
        Difference step in refreshes.

    Returns
    -------
    RenderedUpdate
    """
    settings = settings or RenderSettings()
    period = 1.0 / refresh_hz
    scenes = [scene_at(scene, t + k * h * period, viewer, viewer_motion) for k in (-2, -1, 0, 1, 2)]
    arrays = [s.flatten() for s in scenes]
    projs = np.stack([project(a.vertices, display) for a in arrays])
    vis, _, _ = renderer.visibility(arrays[2], display, settings)
    lin = [shade_linear(arrays[i], projs[i], vis, display, scenes[i].lights, scenes[i].ambient,
                        settings.light) for i in (1, 2, 3)]
    colour = shade(arrays[2], projs[2], vis, display, scenes[2].lights, scenes[2].ambient,
                   settings.light)  # quantised exactly as Renderer.render does
    vd = vertex_derivatives(projs, h)
    der = interpolate(np.ascontiguousarray(vis.triangle, np.int32), arrays[2].triangles,
                      np.ascontiguousarray(projs[2]), np.ascontiguousarray(vd))
    dcol = colour_derivatives(lin, h) if colour_motion else None
    obj = _object_map(vis, arrays[2].triangle_polygon, arrays[2].polygon_object)
    frame = Frame(colour=colour, depth=vis.depth, stats={"t": t})
    points = projs[2][..., :2].reshape(-1, 2)
    pder = vd[..., :2].reshape(3, -1, 2)
    return RenderedUpdate(frame, der, dcol, obj, viewer_motion or MotionState(), points, pder)


def _object_map(vis: Visibility, tri_poly: np.ndarray, poly_obj: np.ndarray) -> np.ndarray:
    """Object index per pixel (Z, R, C) int32, -1 where empty."""
    t = vis.triangle
    obj = poly_obj[tri_poly[np.maximum(t, 0)]] if tri_poly.size else np.zeros(t.shape, np.int64)
    return np.where(t >= 0, obj, -1).astype(np.int32)
