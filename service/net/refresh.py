"""The refresh thread (:class:`RefreshLoop`) and the viewer's pose (:class:`ViewerTracker`).

The refresh thread ticks at the refresh rate on an absolute schedule, hands finished
updates to the Galilean stage, takes the viewer's pose from the devices' stream,
refreshes and publishes the frame.  It never waits for a render; a render that misses
its rendezvous is counted (``incomplete_updates``).
"""

from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import Any

import numpy as np

from service.display import DisplaySettings
from service.errors import HoloError
from service.galilean import GalileanSettings, GalileanStage
from service.net import wire
from service.net.state import VIEWER_POSE_FIELDS, ServiceState, Settings
from service.scene import MotionState, Transform, euler_quaternion


def transform_of(position: np.ndarray, orientation: np.ndarray) -> Transform:
    """A viewer transform (helper for tests and the viewer tracker)."""
    return Transform(np.asarray(position, float), np.asarray(orientation, float))


class ViewerTracker:
    """The viewer's pose and motion: set by ``set_viewer`` or tracked from the devices.

    Tracked poses (device units, degrees) go through an alpha-beta filter for
    velocity and acceleration; positions are scaled by ``scale`` (default 0.001:
    millimetres to world units).  Renders see the viewer relative to the first
    tracked pose (the nominal viewing position); the zone is picked from the
    absolute position's angle ``atan2(x, z)`` across the viewing angle.
    """

    def __init__(self, scale: float = 0.001) -> None:
        from drivers.filters import AlphaBetaSettings, make_filter

        self.scale = scale
        self.position = np.zeros(3)
        self.orientation = np.array([1.0, 0.0, 0.0, 0.0])
        self.motion = MotionState()
        self.active = False
        self.poses = 0
        self.zone: int | None = None
        self.pose_info: dict[str, Any] = {"pose_n": None, "pose_t_ns": None, "pose_seq": None}
        self._origin: np.ndarray | None = None
        self._absolute = np.zeros(3)
        self._filter = make_filter("alpha-beta", AlphaBetaSettings(on_bad="skip"))

    def set_fields(self, req: dict[str, Any]) -> None:
        """Apply ``set_viewer`` fields (validated)."""
        if not any(k in req for k in VIEWER_POSE_FIELDS):
            return
        probe = wire.apply_fields(_probe_object(), req, "viewer")
        self.position = probe.transform.position
        self.orientation = probe.transform.orientation
        self.motion = probe.motion
        self._absolute = self.position
        self.active = True

    def on_pose(self, pose: Any, n: int) -> bool:
        """Take a tracker :class:`~drivers.events.PoseEvent`; True when it was usable."""
        sample = np.array([pose.x, pose.y, pose.z, pose.yaw, pose.pitch, pose.roll], float)
        if not np.all(np.isfinite(sample)):
            return False
        try:
            st = self._filter.update_ns(int(pose.t_ns), sample)
        except HoloError:
            return False
        if self._origin is None:
            self._origin = sample[:3] * self.scale
        yaw, pitch, roll = np.radians(st.position[3:6])
        self._absolute = sample[:3] * self.scale  # the zone follows the newest sample
        self.position = st.position[:3] * self.scale - self._origin
        self.orientation = euler_quaternion(yaw, pitch, roll)
        rates = np.radians(st.velocity[3:6])
        self.motion = MotionState(
            st.velocity[:3] * self.scale,
            st.acceleration[:3] * self.scale,
            np.array([rates[1], rates[0], rates[2]]),
        )
        self.active = True
        self.poses += 1
        self.pose_info = {"pose_n": int(n), "pose_t_ns": int(pose.t_ns), "pose_seq": pose.seq}
        return True

    def pick_zone(self, display: DisplaySettings, distance: float = 0.6) -> int | None:
        """The view zone the viewer's eye is in, or None without a viewer."""
        if not self.active:
            return None
        x, z = float(self._absolute[0]), float(self._absolute[2])
        theta = math.atan2(x, z if z > 1e-6 else distance)
        span = math.radians(display.angle_deg) or 1e-9
        self.zone = int(
            min(display.zones - 1, max(0, math.floor((theta / span + 0.5) * display.zones)))
        )
        return self.zone

    def render_spec(self) -> dict[str, Any] | None:
        """The viewer as a render job carries it (None: no viewer)."""
        if not self.active:
            return None
        return {
            "position": self.position.tolist(),
            "orientation": self.orientation.tolist(),
            **{k: getattr(self.motion, k).tolist() for k in wire.MOTION_FIELDS},
        }

    def as_dict(self) -> dict[str, Any]:
        """The pose in use (for the ``set_viewer`` reply)."""
        return self.render_spec() or {"position": None}


def _probe_object() -> Any:
    from service.mesh import Mesh
    from service.scene import SceneObject

    return SceneObject(Mesh.from_triangles(np.eye(3), [[0, 1, 2]]))


def _sird_output(settings: Settings) -> Any:
    """The ``autostereogram`` encoding's state for these settings, or None when it is off."""
    if "autostereogram" not in settings.encodings:
        return None
    from service.autostereogram.output import SirdOutput

    d = settings.display
    return SirdOutput(d.cols, d.rows, d.width, settings.sird_method, settings.sird_eye_sep)



def stage_settings(settings: Settings) -> GalileanSettings:
    """The service's Galilean stage.

    It holds (``GalileanSettings.hold``, the default): a render is propagated for
    at most ``n_prop`` refreshes; past that, until the next render comes, each
    frame shows the last render as it was (header ``held``), never a smear
    extrapolated past the rating.
    """
    return GalileanSettings(order=settings.galpixel_order, refresh_hz=settings.refresh_hz)


class RefreshLoop:
    """The refresh thread: stage, devices, publishing, at a fixed rate."""

    def __init__(self, st: ServiceState) -> None:
        self.st = st
        self.stage: GalileanStage | None = None
        self.generation = -1
        #: the newest scene load the stage knows of, and the one the shown render is of
        self.scene_load = 0
        self.shown_scene = 0
        self.sub = None
        self.sub_address: str | None = None
        #: rendezvous -> (render id, t_render_ns, scene load)
        self.due: dict[int, tuple[int, int, int]] = {}
        self.render_id = -1
        self.t_render_ns = 0
        self.since = 0
        self.prepared: tuple[Any, dict[str, Any]] | None = None
        #: ticks skipped before the coming one (their periods count towards a use-by)
        self.missed = 0
        self.input: dict[str, Any] | None = None
        self.sird = None  # service.autostereogram.SirdOutput while that encoding is on

    def _restart(self, settings: Settings) -> None:
        self.stage = GalileanStage(settings.display, stage_settings(settings))
        self.generation = settings.generation
        self.sird = _sird_output(settings)
        self.due.clear()
        self.render_id, self.since = -1, 0
        self.prepared = None

    def run(self) -> None:
        """Tick until the service stops."""
        st = self.st
        next_t = time.monotonic()
        try:
            while not st.stop.is_set():
                settings = st.state.settings
                if settings.generation != self.generation:
                    self._restart(settings)
                period = 1.0 / settings.refresh_hz
                st.clock = (  # the refresh computed now is shown at the next tick
                    self.stage.index,
                    next_t + period,
                    self.generation,
                    self.stage.fixed,
                    settings.galpixel_order,
                )
                try:
                    self._tick(settings)
                except Exception as exc:  # a bug must not stop the display: log, restart
                    st.counters.n["refresh_errors"] += 1
                    st.last_refresh_error = f"{type(exc).__name__}: {exc}"
                    self._restart(settings)
                next_t = self._wait(next_t + period, period)
        finally:
            if self.sub is not None:
                self.sub.close()

    def _wait(self, next_t: float, period: float) -> float:
        """Sleep until ``next_t``; past a whole period late, skip the missed ticks."""
        now = time.monotonic()
        if now - next_t > period:
            missed = math.floor((now - next_t) / period)
            self.st.counters.n["refresh_overruns"] += missed
            self.missed += missed
            next_t += missed * period
        if next_t > now:
            self.st.stop.wait(next_t - now)
        self.st.counters.tick_late_ms.append((time.monotonic() - next_t) * 1e3)
        return next_t

    def _tick(self, settings: Settings) -> None:
        """Publish the frame prepared last tick, then prepare the next one.

        The pose is latched at the start of the tick and the frame goes out at once
        (as a display scans out at vsync what was computed before it); the refresh
        for the next tick is computed afterwards, so its cost and jitter do not sit
        between the newest pose and the published frame.
        """
        st, c = self.st, self.st.counters
        self._devices(settings)  # latch: the newest pose picks the zone
        if st.state.scene_load > self.scene_load:
            self._new_scene(st.state.scene_load)
        if self.prepared is not None:
            self._publish(*self.prepared, settings)
        else:
            st.stream.heartbeat()
        t0 = time.perf_counter()
        self._submit()
        r = self.stage.refresh(1 + self.missed)
        self.missed = 0
        c.n["refreshes"] += 1
        c.n["held_refreshes"] += r.flags["held"]
        c.held = r.flags["held"]
        c.refresh_t.append(time.monotonic())
        if r.flags["updated"] and r.index in self.due:
            self.render_id, self.t_render_ns, self.shown_scene = self.due.pop(r.index)
            self.since = 0
            c.n["updates"] += 1
            c.update_t.append(time.monotonic())
        else:
            self.since += 1
        c.n["incomplete_updates"] += sum(
            e.get("kind") == "incomplete_update" for e in r.flags["events"]
        )
        ms = (time.perf_counter() - t0) * 1e3
        c.refresh_ms.append(ms)
        if self.sird is not None:  # the SIRD of the zone the newest pose picked (or the centre)
            zone = self.st.state.viewer.zone
            sird = self.sird.frame(r.depth[r.depth.shape[0] // 2 if zone is None else zone])
            r = replace(r, flags={**r.flags, "autostereogram": sird})
            c.sird_ms.append(self.sird.last_ms)
        if self.render_id >= 0:
            self.prepared = (
                r,
                {
                    "render_id": self.render_id,
                    "since_render": self.since,
                    "t_render_ns": self.t_render_ns,
                    "scene": self.shown_scene,
                    "ms": ms,
                },
            )

    def _submit(self) -> None:
        st = self.st
        while st.updates:
            up = st.updates.popleft()
            if up.generation != self.generation:
                continue
            rd = up.rendered
            if up.scene_load > self.scene_load:  # loaded after this tick's check
                self._new_scene(up.scene_load)
            elif up.scene_load < self.scene_load:  # rendered from a scene replaced since
                continue
            # no guard reset on object updates: a changed motion is what the order
            # guard is for; a new scene resets it (new_scene), as a new object does
            # (another count of control points)
            ok = self.stage.submit(
                up.buffer,
                up.rendezvous,
                None,
                True,
                (),
                rd.points,
                rd.point_derivs,
                rd.viewer_motion,
                up.use_by,
            )
            if ok:
                self.due[up.rendezvous] = (up.render_id, up.t_render_ns, up.scene_load)
            else:
                st.counters.n["late_refused"] += 1
                st.counters.n["incomplete_updates"] += 1

    def _new_scene(self, loaded: int) -> None:
        """A scene load: a discontinuity for the stage (``docs/protocol.md`` 2).

        The stage forgets the old scene's galpixels and pending grafts and shows
        nothing until the new scene's first render is grafted; until then no frame
        is published (heartbeats only), so no frame shows the old scene after it.
        """
        self.stage.new_scene()
        self.scene_load = loaded
        self.due.clear()
        self.render_id, self.since = -1, 0
        self.prepared = None

    def _devices(self, settings: Settings) -> None:
        state = self.st.state
        if state.devices != self.sub_address:
            self._connect(state.devices)
        if self.sub is None:
            state.viewer.pick_zone(settings.display)
            return
        self.sub.poll(0)
        pose = self.sub.pose
        if self.sub.state_known:
            self.input = {
                "seq": self.sub.seq,
                "dials": list(self.sub.dials),
                "buttons": list(self.sub.buttons),
            }
        with state.lock:
            if pose is not None and self.sub.pose_count != state.viewer.pose_info["pose_n"]:
                if state.viewer.on_pose(pose, self.sub.pose_count):
                    self.stage.viewer(state.viewer.motion)
            state.viewer.pick_zone(settings.display)

    def _connect(self, address: str | None) -> None:
        from drivers.subscriber import DeviceSubscriber

        if self.sub is not None:
            self.sub.close()
        self.sub = None if address is None else DeviceSubscriber(address, context=self.st.ctx)
        self.sub_address = address
        self.input = None

    def _publish(self, r: Any, made: dict[str, Any], settings: Settings) -> None:
        names = list(settings.encodings)
        viewer = self.st.state.viewer
        header = {
            "refresh": r.index,
            **made,
            "updated": bool(r.flags["updated"]),
            "refresh_hz": settings.refresh_hz,
            "zone": viewer.zone,
            **viewer.pose_info,
            "input": self.input,
            "events": r.flags["events"],
            "age": r.flags["age"],
            "held": bool(r.flags["held"]),
            "use_by": int(r.flags["use_by"]),
            "order": int(r.flags["order"]),
        }
        arrays = [r.flags[n] if n == "autostereogram" else getattr(r, n) for n in names]
        self.st.stream.publish(header, arrays, names)
