"""The viewer's pose and motion (:class:`ViewerTracker`): set by ``set_viewer`` or tracked.

Tracked poses come from the devices' stream (a tracker's
:class:`~drivers.events.PoseEvent`), filtered for velocity and acceleration; the
view zone the viewer's eye is in follows the newest pose.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from drivers.filters import AlphaBetaSettings, make_filter
from service.base.errors import HoloError
from service.display import DisplaySettings
from service.net import wire
from service.render.mesh import Mesh
from service.render.scene import MotionState, SceneObject, Transform, euler_quaternion

#: ``set_viewer`` keys of a pose (the other form names ``devices``).
VIEWER_POSE_FIELDS = ("position", "orientation", *wire.MOTION_FIELDS)


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
    return SceneObject(Mesh.from_triangles(np.eye(3), [[0, 1, 2]]))
