"""Render jobs: one render of a scene snapshot, as the engine and the workers make it.

A job is the dict the render thread aims (:meth:`service.engine.scheduler.Scheduler.aim`):
``t`` (seconds after the snapshot), ``refresh_hz``, ``display`` and ``render`` (wire
form, :mod:`service.net.settings_wire`), ``viewer``, ``order`` and ``rows`` (a band,
or the whole frame).  :func:`render_job` renders it in this process, into the arrays
a worker sends back (``docs/protocol.md`` 1.5); :func:`stitch` joins band replies
into the render and galpixmap the refresh thread grafts.  The engine renders in
process with these functions and the worker processes (:mod:`service.net.worker`)
run the same ones, so a render is the same wherever it is made.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Any

import numpy as np

from service.display import DisplaySettings
from service.galilean.fixed_point import FixedPoint, bit_budget
from service.galilean.galpixmap import FIELDS, Galpixmap, build
from service.galilean.motion_field import RenderedUpdate, render_with_motion
from service.lod.state import LodState
from service.net import wire
from service.net.settings_wire import display_from_wire, render_from_wire
from service.render.frame import Frame
from service.render.pipeline import Renderer, StageClock
from service.render.scene import (
    Light,
    MotionState,
    Scene,
    SceneObject,
    Transform,
    quaternion_matrix,
)


def _shift_scene(scene: Scene, dy: float) -> Scene:
    shift = np.array([0.0, dy, 0.0])
    objects = [
        SceneObject(
            o.mesh,
            o.material,
            Transform(o.transform.position + shift, o.transform.orientation, o.transform.scale),
            o.motion,
            o.name,
        )
        for o in scene.objects
    ]
    lights = [
        Light(
            lt.kind, lt.vector + shift if lt.kind == "point" else lt.vector, lt.colour, lt.intensity
        )
        for lt in scene.lights
    ]
    boards = [replace(b, transform=Transform(b.transform.position + shift,
                                             b.transform.orientation, b.transform.scale))
              for b in scene.billboards]
    return Scene(objects, lights, scene.ambient, billboards=boards)


def band_setup(
    scene: Scene, display: DisplaySettings, rows: tuple[int, int], viewer: Transform | None
) -> tuple[Scene, DisplaySettings, Transform | None]:
    """The scene, display and viewer that render hololines ``rows[0]:rows[1]``."""
    r0, r1 = rows
    if (r0, r1) == (0, display.rows):
        return scene, display, viewer
    band = DisplaySettings(display.zones, display.angle_deg, display.cols, r1 - r0, display.width)
    dy = r0 * display.pixel_size + (band.height - display.height) / 2
    if viewer is None:
        return _shift_scene(scene, dy), band, None
    down = quaternion_matrix(viewer.orientation) @ np.array([0.0, dy, 0.0])
    return scene, band, Transform(viewer.position - down, viewer.orientation, viewer.scale)


def viewer_from(spec: dict[str, Any] | None) -> tuple[Transform | None, MotionState | None]:
    """Viewer pose and motion from ``{"position", "orientation", "velocity", ...}``."""
    if spec is None:
        return None, None
    pose = Transform(np.asarray(spec["position"], float), np.asarray(spec["orientation"], float))
    motion = MotionState(**{k: np.asarray(spec[k], float) for k in wire.MOTION_FIELDS})
    return pose, motion


class StatsRenderer(Renderer):
    """A :class:`Renderer` that keeps its last visibility pass's timings and counts.

    ``render_with_motion`` runs one visibility pass per render; its per-stage
    milliseconds and polygon counts go into the render reply's stats.
    """

    def __init__(self) -> None:
        super().__init__()
        # a chain not cached yet is built in the background: no render waits for it
        self.lod = LodState(background=True)
        self.last_ms: dict[str, float] = {}
        self.last_counts: dict[str, int] = {}
        self.last_inconsistent = 0  # run-length points out of sort order (for --quality auto)

    def visibility(self, arrays, display, settings, clock=None):  # noqa: ANN001, ANN201
        """As :meth:`Renderer.visibility`, noting per-stage ms and polygon counts."""
        ms: dict[str, float] = {}
        out = super().visibility(arrays, display, settings, clock or StageClock(ms))
        self.last_ms = ms
        self.last_counts = {k: int(v) for k, v in out[1].items()}
        self.last_inconsistent = int(out[0].stats.get("inconsistent_pixels", 0))
        return out


def render_band(renderer: Renderer, job: dict[str, Any], scene: Scene) -> dict[str, np.ndarray]:
    """Render one job's band and build its galpixmap (see :func:`render_job`)."""
    return render_job(renderer, job, scene)[0]


def render_job(
    renderer: Renderer, job: dict[str, Any], scene: Scene
) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Render one job's rows (a band, or the whole frame) and build its galpixmap.

    The galpixmap uses order ``job["order"]``.  The stats are those of the render
    reply (``docs/protocol.md`` 1.5): ``ms`` per stage (``project``, ``cull``,
    ``sort``, ``occlusion`` of the visibility pass; ``motion``: the whole render
    with per-pixel motion; ``galpixmap``; ``total``), ``polygons``
    (``in``, ``culled``, ``kept``, ``drawn``), ``method`` and ``rows``; with billboard
    clouds in the scene ``billboards`` (how they were drawn: ``drawn_with``, ``note``).

    Returns
    -------
    dict of ndarray
        ``colour`` (Z, r, C, 3) uint8 and ``depth`` (Z, r, C) float32 of the render;
        ``gp_colour`` (3, Z, r, C) float32, ``gp_depth`` (Z, r, C), ``gp_frac``
        (2, Z, r, C) int16, ``gp_motion`` (2n, Z, r, C) int32, ``gp_zmotion``
        (n, Z, r, C), ``gp_dcolour`` (4 or 0, Z, r, C), ``gp_debris`` (Z, r, C) uint8,
        ``gp_obj`` (Z, r, C) int32; band 0 also ``points`` (N, 2) and
        ``point_derivs`` (3, N, 2).
    """
    display = display_from_wire(job["display"])
    viewer, motion = viewer_from(job.get("viewer"))
    rows = (int(job["rows"][0]), int(job["rows"][1]))
    scene, band, viewer = band_setup(scene, display, rows, viewer)
    t0 = time.perf_counter()
    up = render_with_motion(
        renderer,
        scene,
        band,
        float(job["t"]),
        float(job["refresh_hz"]),
        render_from_wire(job["render"]),
        viewer,
        motion,
        order=int(job.get("order", 2)),  # no jerk maps below G(3)
    )
    t1 = time.perf_counter()
    out = _job_arrays(up, display, int(job.get("order", 2)), rows)
    t2 = time.perf_counter()
    return out, _job_stats(renderer, up, job, rows, (t0, t1, t2))


def _job_arrays(
    up: RenderedUpdate, display: DisplaySettings, order: int, rows: tuple[int, int]
) -> dict[str, np.ndarray]:
    """The arrays of a job's reply: the render, its galpixmap and (band 0) the points.

    Returns
    -------
    dict of ndarray
        As :func:`render_job` returns them: ``colour`` (Z, r, C, 3), ``depth``
        (Z, r, C), ``gp_<field>`` for every galpixmap field, and for the band that
        starts at row 0 ``points`` (N, 2) and ``point_derivs`` (3, N, 2).
    """
    out = {"colour": up.frame.colour, "depth": up.frame.depth}
    gp = _galpixmap(up, display, order)
    out.update({f"gp_{k}": getattr(gp, k) for k in FIELDS})
    if rows[0] == 0 and up.points is not None:
        out["points"] = up.points
        out["point_derivs"] = up.point_derivs
    return out


def _job_stats(
    renderer: Renderer,
    up: RenderedUpdate,
    job: dict[str, Any],
    rows: tuple[int, int],
    times: tuple[float, float, float],
) -> dict[str, Any]:
    """The stats of a job's reply (see :func:`render_job`).

    ``times`` are the ``perf_counter`` readings before the render, after it and
    after the galpixmap.
    """
    t0, t1, t2 = times
    ms = dict(getattr(renderer, "last_ms", {}))
    ms.update(motion=(t1 - t0) * 1e3, galpixmap=(t2 - t1) * 1e3, total=(t2 - t0) * 1e3)
    stats = {
        "ms": {k: round(v, 3) for k, v in ms.items()},
        "polygons": dict(getattr(renderer, "last_counts", {})),
        "method": job["render"]["method"],
        "rows": list(rows),
        "inconsistent_pixels": int(getattr(renderer, "last_inconsistent", 0)),
    }
    for key in ("lod", "billboards"):  # billboards: how they were drawn (docs/simplify.md)
        if key in up.frame.stats:
            stats[key] = up.frame.stats[key]
    return stats


def _galpixmap(up: RenderedUpdate, display: DisplaySettings, order: int) -> Galpixmap:
    """The band's galpixmap, with the fixed-point format of the whole display's stage."""
    fixed = FixedPoint.for_order(bit_budget(max(display.cols, display.rows), 16, 16), order)
    gp, _info = build(
        up.frame.colour, up.frame.depth, order, fixed, up.derivatives, up.dcolour, up.obj, 0
    )
    return gp


def stitch(
    bands: list[dict[str, np.ndarray]], viewer_motion: MotionState, fixed: FixedPoint, order: int
) -> tuple[RenderedUpdate, Galpixmap]:
    """Join band replies (in row order): the render (frame, control points) and its galpixmap.

    Every array is joined along its row axis (-2 for the galpixmap fields, 1 for the
    frame's colour and depth).
    """
    def join(key: str, axis: int) -> np.ndarray:
        parts = [b[key] for b in bands]
        return parts[0] if len(parts) == 1 else np.concatenate(parts, axis=axis)

    first = bands[0]
    frame = Frame(join("colour", 1), join("depth", 1))
    rendered = RenderedUpdate(
        frame, None, None, None, viewer_motion, first.get("points"), first.get("point_derivs")
    )
    fields = {k: np.array(join(f"gp_{k}", -2)) for k in FIELDS}
    return rendered, Galpixmap(order, fixed, **fields)
