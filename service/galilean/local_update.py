"""Local updates (seed 002, section 4.2).

* A **Flinders Street buffer** is a galpixmap that starts as clear-frame debris
  (debris, depth +inf) and receives only the objects scheduled for re-rendering
  (first class); objects that may obscure them (second class) are
  **shadow-rendered**: they take part in the z-test but their pixels stay debris,
  so a grafted object never paints over something in front of it.
* :func:`graft` puts the buffer's galpixels into the Galilean map at the
  rendezvous refresh, ignoring its debris; galpixels of the re-rendered objects
  the new render no longer covers become debris (they are stale).
* :func:`render_local` renders the scheduled objects one by one within a time
  budget; what is finished by the deadline is what gets grafted, and the rest is
  reported back (the stage raises an ``incomplete_update`` event).
* A **use-by date**: an object rotated more than 45 degrees since its render has an
  image the parabolic (G(2)) extrapolation no longer describes; it is due for a
  priority re-render (:func:`expired`).
* An **error estimate** per object: the distance between its control points as
  the stage displays them (the galpixel arithmetic from the last render) and
  where they truly are (:func:`object_errors`); :func:`priority` orders
  re-renders: expired objects first, then largest error first.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from service.display import DisplaySettings
from service.galilean.fixed_point import FixedPoint, points_fixed, propagate_points
from service.galilean.galpixmap import (
    PIXEL_FIELDS,
    PLANE_FIELDS,
    GalileanError,
    Galpixmap,
    build,
)
from service.galilean.motion_field import RenderedUpdate, render_with_motion
from service.galilean.shadow import shadow_depth, shadow_into
from service.render.pipeline import Renderer, RenderSettings
from service.render.scene import MotionState, Scene
from service.scene_motion import rotation_angle

#: Default use-by limit: the paper's rule of thumb for parabolic extrapolation.
USE_BY_DEG = 45.0


def graft(main: Galpixmap, buffer: Galpixmap, objects: Sequence[int]) -> dict:
    """Graft a Flinders Street buffer into the Galilean map, in place.

    Parameters
    ----------
    main : Galpixmap
    buffer : Galpixmap
        Same shape and order; debris pixels are ignored.
    objects : sequence of int
        The objects the buffer re-renders.

    Returns
    -------
    dict
        ``grafted`` pixels and ``stale`` pixels of those objects turned to debris.
    """
    take = buffer.debris == 0
    stale = np.isin(main.obj, np.asarray(objects, np.int32)) & ~take & (main.debris == 0)
    main.debris[stale] = 1
    for name in PLANE_FIELDS:
        dst, src = getattr(main, name), getattr(buffer, name)
        dst[:, take] = src[:, take]
    for name in PIXEL_FIELDS:
        getattr(main, name)[take] = getattr(buffer, name)[take]
    return {"grafted": int(take.sum()), "stale": int(stale.sum())}


def obscurers(
    scene: Scene, objects: Sequence[int], proj: np.ndarray, vertex_object: np.ndarray
) -> list[int]:
    """Second-class objects: others whose screen box overlaps a first-class one's and are nearer.

    Parameters
    ----------
    scene : Scene
    objects : sequence of int
        First-class objects.
    proj : ndarray, shape (Z, V, 3)
        Projected vertices (see :func:`service.scene_motion.control_points`).
    vertex_object : ndarray, shape (V,)

    Returns
    -------
    list of int
    """
    boxes = {}
    for i in range(len(scene.objects)):
        p = proj[:, vertex_object == i]
        boxes[i] = (p[..., 0].min(), p[..., 0].max(), p[..., 1].min(), p[..., 1].max(),
                    p[..., 2].min(), p[..., 2].max()) if p.size else None
    out = []
    for i, b in boxes.items():
        if i in objects or b is None:
            continue
        for j in objects:
            o = boxes.get(j)
            overlap = o and b[0] <= o[1] and o[0] <= b[1] and b[2] <= o[3] and o[2] <= b[3]
            if overlap and b[4] < o[5]:
                out.append(i)
                break
    return out


def _subscene(scene: Scene, keep: list[int]) -> Scene:
    """Objects ``keep`` of the scene, with all its billboard clouds.

    The clouds may hide them; their pixels carry no object, so a Flinders Street
    buffer keeps them as shadow.
    """
    return Scene([scene.objects[i] for i in keep], list(scene.lights), scene.ambient,
                 billboards=list(scene.billboards))


def flinders_buffer(
    rendered: RenderedUpdate, first: Sequence[int], order: int, fixed: FixedPoint,
    margin: int = 0, colour_motion: bool = True,
) -> Galpixmap:
    """A render as a Flinders Street buffer: debris wherever no first-class object was drawn.

    Shadow-rendered (second-class) pixels keep their depth but are debris.
    """
    gp, _ = build(rendered.frame.colour, rendered.frame.depth, order, fixed, rendered.derivatives,
                  rendered.dcolour if colour_motion else None, rendered.obj, margin)
    gp.debris[~np.isin(gp.obj, np.asarray(first, np.int32))] = 1
    return gp


def merge(buffers: list[Galpixmap]) -> Galpixmap:
    """Z-merge Flinders Street buffers (debris included, so shadows still hide)."""
    out = buffers[0].copy()
    for b in buffers[1:]:
        near = b.depth < out.depth
        for name in PLANE_FIELDS:
            getattr(out, name)[:, near] = getattr(b, name)[:, near]
        for name in PIXEL_FIELDS:
            getattr(out, name)[near] = getattr(b, name)[near]
    return out


@dataclass
class LocalRender:
    """What :func:`render_local` produced by its deadline."""

    buffer: Galpixmap
    finished: list[int]
    unfinished: list[int]
    shadowed: list[int]
    ms: float


def render_local(
    renderer: Renderer, scene: Scene, display: DisplaySettings, objects: Sequence[int],
    t: float, refresh_hz: float, order: int, fixed: FixedPoint, budget_ms: float = np.inf,
    settings: RenderSettings | None = None, margin: int = 0,
    clock: Callable[[], float] | None = None, control: tuple | None = None,
    shadow: str = "depth",
) -> LocalRender:
    """Render ``objects`` (in the given priority order) into a Flinders Street buffer.

    Each object is rendered with its obscurers shadow-rendered; objects not started
    before ``budget_ms`` has elapsed (by ``clock``, milliseconds) are left unfinished.
    ``control`` is ``(proj, vertex_object)`` at time ``t`` for the obscurer test.
    ``shadow="depth"`` renders the object alone and its obscurers depth only
    (:mod:`.shadow`); ``"full"`` renders them together through the full renderer
    (colour, light and motion of the obscurers computed and thrown away).  The
    grafted pixels are the same; on an exact depth tie between the object and an
    obscurer the depth path gives the pixel to the object, the full render to the
    triangle it draws first.
    """
    if shadow not in ("depth", "full"):
        raise ValueError(f"shadow must be 'depth' or 'full', got {shadow!r}")
    clock = clock or (lambda: time.perf_counter() * 1e3)
    start = clock()
    buffers, finished, unfinished, shadowed = [], [], [], set()
    for i in objects:
        if clock() - start > budget_ms:
            unfinished.append(int(i))
            continue
        second = obscurers(scene, [i], *control) if control is not None else \
            [k for k in range(len(scene.objects)) if k != i]
        keep = sorted({int(i), *second}) if shadow == "full" else [int(i)]
        sub = render_with_motion(renderer, _subscene(scene, keep), display, t, refresh_hz, settings,
                                 order=order)
        sub.obj = np.where(sub.obj >= 0, np.asarray(keep, np.int32)[np.maximum(sub.obj, 0)], -1)
        if shadow == "depth" and second:
            cs = (settings or RenderSettings()).cull
            sd, so = shadow_depth(scene, second, display, t, cs)
            shadow_into(sub.frame.colour, sub.frame.depth, sub.obj, sd, so)
        buffers.append(flinders_buffer(sub, [i], order, fixed, margin))
        finished.append(int(i))
        shadowed.update(second)
    if not buffers:
        z, r, c = display.zones, display.rows + 2 * margin, display.cols + 2 * margin
        buffers.append(Galpixmap.empty(order, fixed, (z, r, c)))
    return LocalRender(merge(buffers), finished, unfinished, sorted(shadowed), clock() - start)


def expired(scene: Scene, since_s: Sequence[float], limit_deg: float = USE_BY_DEG) -> list[int]:
    """Objects whose image is past its use-by date (rotated beyond ``limit_deg``).

    Parameters
    ----------
    scene : Scene
        The scene at the time the objects were last rendered.
    since_s : sequence of float
        Seconds since each object's render.
    limit_deg : float

    Returns
    -------
    list of int
    """
    lim = np.radians(limit_deg)
    return [i for i, o in enumerate(scene.objects) if rotation_angle(o.motion, since_s[i]) > lim]


def use_by_refreshes(scene: Scene, refresh_hz: float, limit_deg: float = USE_BY_DEG,
                     horizon: int = 100000) -> np.ndarray:
    """Refreshes after a render until each object's use-by date (``horizon`` if never)."""
    out = np.full(len(scene.objects), horizon, np.int64)
    lim = np.radians(limit_deg)
    for i, o in enumerate(scene.objects):
        for n in range(1, horizon):
            if rotation_angle(o.motion, n / refresh_hz) > lim:
                out[i] = n
                break
            if not np.any(o.motion.angular_velocity) and not np.any(o.motion.angular_acceleration):
                break
    return out


def render_use_by(scene: Scene, refresh_hz: float, n_prop: int,
                  viewer: MotionState | None = None, limit_deg: float = USE_BY_DEG) -> int:
    """The use-by date of a global render of ``scene``, in refreshes after its graft.

    The last refresh, at most ``n_prop`` (the rated propagation time), at which no
    object, nor the viewer, has turned more than ``limit_deg`` since the render:
    past that, parabolic extrapolation of the turn breaks down (section 4.1) and
    the Galilean stage holds the render instead (``GalileanStage.update``'s
    ``use_by``).  Objects that do not turn cost one check each.
    """
    lim = np.radians(limit_deg)
    motions = [o.motion for o in scene.objects] + ([viewer] if viewer is not None else [])
    turning = [m for m in motions
               if np.any(m.angular_velocity) or np.any(m.angular_acceleration)]
    for k in range(1, n_prop + 1):
        if any(rotation_angle(m, k / refresh_hz) > lim for m in turning):
            return k - 1
    return n_prop


def object_errors(
    points: np.ndarray, derivs: np.ndarray, truth: np.ndarray, owner: np.ndarray, steps: int,
    fixed: FixedPoint, order: int, n_objects: int,
) -> np.ndarray:
    """Per-object error: displayed versus true control points, ``steps`` after the render.

    Parameters
    ----------
    points : ndarray, shape (N, 2)
        Control points' display positions at the render (px).
    derivs : ndarray, shape (3, N, 2)
        Their apparent velocity, acceleration, jerk per refresh^n.
    truth : ndarray, shape (N, 2)
        Their exact positions now.
    owner : ndarray, shape (N,)
        Object of each point.
    steps : int
        Refreshes since the render.
    fixed : FixedPoint
    order : int
    n_objects : int

    Returns
    -------
    ndarray, shape (n_objects,)
        Largest displayed-vs-true distance per object in px (0 without points).

    Raises
    ------
    GalileanError
        If an array's shape does not fit ``points`` (the message names it).
    """
    check_points(points, derivs)
    n = len(points)
    for name, arr, shape in (("truth", truth, np.shape(points)), ("owner", owner, (n,))):
        if np.shape(arr) != shape:
            raise GalileanError(f"{name} must have shape {shape}, got {np.shape(arr)}")
    x, v, a, j = points_fixed(points, derivs, fixed, order)
    shown = propagate_points(x, v, a, j, order, fixed.fp, fixed.fm, steps)[-1] / 2.0**fixed.fp
    dist = np.linalg.norm(shown - truth, axis=-1)
    out = np.zeros(n_objects)
    np.maximum.at(out, owner, dist)
    return out


def priority(
    errors: np.ndarray, expired_objects: Sequence[int], min_error: float = 0.5
) -> list[int]:
    """Re-render order: expired objects first, then errors above ``min_error`` px, largest first."""
    exp = [int(i) for i in expired_objects]
    rest = [int(i) for i in np.argsort(-errors, kind="stable") if errors[i] > min_error
            and int(i) not in exp]
    return exp + rest


def check_points(points: np.ndarray | None, derivs: np.ndarray | None) -> None:
    """Raise :class:`GalileanError` unless points are (N, D) and derivs (3, N, D), D 1 or 2."""
    if points is None and derivs is None:
        return
    p, d = np.shape(points), np.shape(derivs)
    if len(p) != 2 or p[1] not in (1, 2):
        raise GalileanError(f"points must have shape (N, 2) (or (N, 1)), got {p}")
    if d != (3, *p):
        raise GalileanError(f"point_derivs must have shape {(3, *p)}, got {d}")
