"""Render workers: one update (a whole frame, or a band of its hololines), in its own process.

A worker connects a DEALER to the broker's backend (``service/net/broker.py``), says
``READY`` (and again every worker heartbeat while idle, ``BUSY`` every heartbeat
while it renders, so the broker tells a dead or stopped worker from a busy one
within three heartbeats), and answers each job with the arrays of its rows (all of them for a
whole-frame job, the default) and the render's stats.  A job is a JSON header plus
the scene's buffers (``docs/protocol.md`` array rules: JSON and raw buffers only)::

    {"job": 12, "band": 1, "attempt": 0, "rows": [60, 120], "t": 0.25,
     "refresh_hz": 60, "display": {...}, "render": {...}, "viewer": {...} | null,
     "scene": {...inline scene with $array references...}}

Bands: rows ``r0:r1`` of a display render as a display ``r1 - r0`` rows high with
the scene moved up by ``r0 * s + (h' - h) / 2`` (``s`` the pixel size, ``h`` and
``h'`` the heights), which puts exactly those hololines on it: the projection is
parallel, so a translation moves the picture without changing it.  With a viewer
pose the viewer is moved down instead (exact unless the viewer rotates between
the difference steps).

Run: ``python -m service.net.worker --connect tcp://HOST:5557 [--curve-keys DIR]``.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from typing import Any

import numpy as np
import zmq

from service.display import DisplaySettings
from service.galilean.fixed_point import FixedPoint, bit_budget
from service.galilean.galpixmap import FIELDS, Galpixmap, build
from service.galilean.motion_field import RenderedUpdate, render_with_motion
from service.lod.state import LodState
from service.net import protocol, wire
from service.net.settings_wire import display_from_wire, render_from_wire
from service.process import setup_frame_process
from service.render.pipeline import Renderer, StageClock
from service.render.scene import (
    Light,
    MotionState,
    Scene,
    SceneObject,
    Transform,
    quaternion_matrix,
)

#: an idle worker's message to the broker (with ``{"pid", "jobs", "heartbeat_s"}``).
READY = b"READY"
#: a rendering worker's heartbeat to the broker (it is alive, its job still running).
BUSY = b"BUSY"


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
    with its four difference renders; ``galpixmap``; ``total``), ``polygons``
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
    from service.render.frame import Frame

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


def handle_job(renderer: Renderer, body: list[Any]) -> list[Any]:
    """Job frames (header, buffers) -> reply frames (header, buffers)."""
    try:
        job = protocol.parse_reply(body)
        arrays = job.pop("arrays", [])
        spec = wire.resolve(job.pop("scene"), arrays if isinstance(arrays, list) else [])
        out, stats = render_job(renderer, job, wire.scene_from_wire(spec))
        names = list(out)
        head = {
            "job": job["job"],
            "band": job.get("band", 0),
            "attempt": job.get("attempt", 0),
            "ok": True,
            "pid": os.getpid(),
            "stats": {**stats, "pid": os.getpid()},
        }
        return wire.encode(head, [out[n] for n in names], names)
    except Exception as exc:  # noqa: BLE001 - a bad job must not kill the worker
        head = {"job": None, "ok": False, "error": f"{type(exc).__name__}: {exc}"}
        try:
            head["job"], head["band"] = json.loads(bytes(body[0]))["job"], None
        except (ValueError, KeyError, IndexError, TypeError):
            pass
        return wire.encode(head, [])


class Worker:
    """The worker loop: READY, then jobs, until stopped or the deadline.

    A job renders on a thread of its own while the loop sends ``BUSY`` every
    :data:`~service.net.protocol.WORKER_HEARTBEAT_S` (the socket stays on the loop's
    thread), so a long render is told from a stopped process.

    Parameters
    ----------
    address : str
        The broker's backend address.
    curve_keys : str, optional
        ``holo-service-keys`` directory (CurveZMQ client).
    """

    def __init__(self, address: str, curve_keys: str | None = None) -> None:
        from service.net.client import _curve_client

        self.ctx = zmq.Context()
        self.sock = self.ctx.socket(zmq.DEALER)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.setsockopt(zmq.HEARTBEAT_IVL, 1000)
        self.sock.setsockopt(zmq.HEARTBEAT_TIMEOUT, 3000)
        _curve_client(self.sock, curve_keys)
        self.sock.connect(address)
        self.renderer = StatsRenderer()
        self.jobs = 0
        self._render = ThreadPoolExecutor(1, thread_name_prefix="render")

    def _ready(self) -> None:
        info = {"pid": os.getpid(), "jobs": self.jobs, "heartbeat_s": protocol.WORKER_HEARTBEAT_S}
        wire.send(self.sock, [b"", READY, json.dumps(info).encode()], 1000)

    def _answer(self, body: list[Any]) -> list[Any]:
        """Render a job on the render thread, sending ``BUSY`` every heartbeat meanwhile."""
        job = self._render.submit(handle_job, self.renderer, body)
        while True:
            try:
                return job.result(protocol.WORKER_HEARTBEAT_S)
            except TimeoutError:
                wire.send(self.sock, [b"", BUSY], 1000)

    def run(self, stop_after_s: float | None = None, parent: int | None = None) -> None:
        """Serve jobs; sends READY every worker heartbeat while idle.

        Stops after ``stop_after_s`` or when process ``parent`` is no longer its parent.
        """
        end = None if stop_after_s is None else time.monotonic() + stop_after_s
        beat = protocol.WORKER_HEARTBEAT_S
        self._ready()
        last = time.monotonic()
        while (end is None or time.monotonic() < end) and (
            parent is None or os.getppid() == parent
        ):
            if not self.sock.poll(int(beat * 1000)):
                if time.monotonic() - last >= beat:
                    self._ready()
                    last = time.monotonic()
                continue
            frames = self.sock.recv_multipart(copy=False)
            envelope, body = split_job(frames)
            if body is None:
                continue
            reply = self._answer(body)
            self.jobs += 1
            wire.send(self.sock, [b"", *envelope, *reply], 5000)
            last = time.monotonic()

    def close(self) -> None:
        """Stop the render thread; close the socket and the context."""
        self._render.shutdown(wait=False)
        self.sock.close(0)
        self.ctx.term()


def split_job(frames: list[Any]) -> tuple[list[bytes], list[Any] | None]:
    """``[b"", client, b"", header, *buffers]`` -> (``[client, b""]``, body)."""
    if len(frames) < 4 or len(frames[0]) or len(frames[2]):
        return [], None
    return [bytes(frames[1]), b""], [f.buffer for f in frames[3:]]


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m service.net.worker``."""
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # see service.commands.holo_service.main
    setup_frame_process()  # heap reuse and one BLAS thread (service.process)
    ap = argparse.ArgumentParser(prog="holo-service-worker")
    ap.add_argument("--connect", default="tcp://127.0.0.1:5557")
    ap.add_argument("--curve-keys", default=None)
    ap.add_argument("--warm-up", action="store_true", help="compile the kernels before READY")
    ap.add_argument("--parent", type=int, default=None, help="exit when this process is gone")
    ap.add_argument(
        "--nice",
        type=int,
        default=5,
        help="lower the worker's CPU priority: renders are elastic, refreshes are "
        "not (the service's refresh thread and the device drivers come first)",
    )
    args = ap.parse_args(argv)
    if args.nice > 0:
        os.nice(args.nice)
    worker = Worker(args.connect, args.curve_keys)
    from service.numba_patches import locked_cache_saves

    locked_cache_saves()  # a service's background compile may write the same cache
    if args.warm_up:
        from service.render.pipeline import warm_up

        warm_up()
    try:
        worker.run(parent=args.parent)
    except KeyboardInterrupt:
        pass
    finally:
        worker.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
