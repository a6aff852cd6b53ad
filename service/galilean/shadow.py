"""Shadow rendering for local updates (seed 002, section 4.2): depth only.

A local update re-renders a few (first-class) objects into a Flinders Street
buffer; objects that may obscure them (second class) only have to take part in
the z-test, so that a grafted object never paints over something in front of it.
Their pixels stay debris, so their colour, lighting and motion are never needed:
:func:`shadow_depth` projects, culls and z-buffers them (the renderer's own scan
conversion, :func:`service.render.raster.zbuffer_kernel`, so they cover exactly the
pixels a full render would) and stops there.  :func:`shadow_into` then marks every
pixel of a first-class render that a second-class object is nearer at as debris
with the obscurer's depth and the debris colour (black, the clear frame's).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from service.display import DisplaySettings
from service.render.cull import CullSettings, cull, zone_mask
from service.render.depth_sort import NO_TIE_SOURCE, average_z, sort_polygons, triangle_order
from service.render.projection import project
from service.render.raster import zbuffer_kernel
from service.render.scene import MotionState, Scene, Transform
from service.scene_motion import scene_at

#: Colour of shadow-rendered pixels (they are debris: never grafted, never shown).
DEBRIS_COLOUR = (0, 0, 0)


def shadow_depth(
    scene: Scene,
    objects: Sequence[int],
    display: DisplaySettings,
    t: float = 0.0,
    cull_settings: CullSettings | None = None,
    viewer: Transform | None = None,
    viewer_motion: MotionState | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Depth-only render of some of a scene's objects at time ``t``.

    No lighting, colour or motion: projection, culling, depth sort (only for the
    z-buffer's drawing order, as the renderer does) and the z-buffer.

    Parameters
    ----------
    scene : Scene
        Objects with their motion states, at time 0.
    objects : sequence of int
        Indices of the objects to shadow-render.
    display : DisplaySettings
        The render's display (with any out-of-view margin already added).
    t : float
        Render time in seconds (as :func:`~service.galilean.motion_field.render_with_motion`).
    cull_settings : CullSettings, optional
        As the full render's ``RenderSettings.cull``.
    viewer, viewer_motion : optional
        The viewer's pose and motion at time 0.

    Returns
    -------
    depth : ndarray, shape (Z, R, C), float32
        Nearest shadow-rendered depth, +inf where none.
    obj : ndarray, shape (Z, R, C), int32
        Scene index of the object there, -1 where none.
    """
    keep_obj = [int(i) for i in objects]
    shape = (display.zones, display.rows, display.cols)
    depth = np.full(shape, np.inf, np.float32)
    tri = np.full(shape, -1, np.int32)
    if not keep_obj:
        return depth, tri
    sub = _subscene(scene, keep_obj)
    moved = sub if t == 0.0 and viewer is None else scene_at(sub, t, viewer, viewer_motion)
    arrays = moved.flatten()
    if arrays.triangles.shape[0] == 0:
        return depth, tri
    proj = project(arrays.vertices, display)
    keep, _ = cull(arrays.normals, display, cull_settings)
    draw = zone_mask(
        arrays.triangle_polygon, arrays.normals, arrays.polygon_closed, display, cull_settings
    )
    order = triangle_order(
        sort_polygons(average_z(arrays.vertices, arrays.polygons, arrays.counts), keep),
        arrays.triangle_polygon,
    )
    zbuffer_kernel(proj, arrays.triangles, np.ascontiguousarray(order), draw, tri, depth,
                   NO_TIE_SOURCE)  # drawn in the depth order: no key
    owner = np.asarray(keep_obj, np.int32)[arrays.polygon_object[arrays.triangle_polygon]]
    # one gather: triangle -1 (empty) reads the appended -1
    return depth, np.append(owner, np.int32(-1))[tri]


#: Sub-scenes by (id of the scene's object list, object indices), so that their
#: flattening keeps its static parts (triangulation, polygon lists) between calls.
_SUBSCENES: dict[tuple, Scene] = {}


def _subscene(scene: Scene, keep: list[int]) -> Scene:
    """A scene of ``keep``'s objects, reused between calls (static parts cached).

    The objects are set afresh every call; the flattening's own key (meshes and
    materials) decides whether its cached static parts still hold.
    """
    key = (id(scene.objects), tuple(keep))
    sub = _SUBSCENES.get(key)
    if sub is None:
        if len(_SUBSCENES) >= 16:
            _SUBSCENES.pop(next(iter(_SUBSCENES)))
        sub = _SUBSCENES[key] = Scene([], [], scene.ambient)
    sub.objects = [scene.objects[i] for i in keep]
    sub.lights = list(scene.lights)
    sub.ambient = scene.ambient
    return sub


def shadow_into(
    colour: np.ndarray,
    depth: np.ndarray,
    obj: np.ndarray,
    shadow: np.ndarray,
    shadow_obj: np.ndarray,
) -> np.ndarray:
    """Put a shadow render in front of a first-class render, in place.

    Where the shadow is strictly nearer (a tie goes to the first-class object),
    the pixel takes the shadow's depth and object and the debris colour.

    Parameters
    ----------
    colour : ndarray, shape (Z, R, C, 3), uint8
    depth : ndarray, shape (Z, R, C), float32
    obj : ndarray, shape (Z, R, C), int32
        The first-class render, changed in place.
    shadow, shadow_obj : ndarray, shape (Z, R, C)
        From :func:`shadow_depth`.

    Returns
    -------
    ndarray, shape (Z, R, C), bool
        The shadowed pixels (to be made debris).
    """
    near = shadow < depth
    colour[near] = DEBRIS_COLOUR
    depth[near] = shadow[near]
    obj[near] = shadow_obj[near]
    return near
