"""The service's refresh thread: the engine's, publishing on the frame stream.

:class:`ServiceRefresh` is :class:`service.engine.refresh.RefreshLoop` with the
service's transport: the viewer's pose from a ``holo-devices`` stream
(``set_viewer devices``), frames published on the PUB frame stream, heartbeats
while there is no frame.
"""

from __future__ import annotations

from typing import Any

from drivers.subscriber import DeviceSubscriber
from service.engine.refresh import RefreshLoop
from service.engine.state import Settings
from service.net.state import ServiceState


class ServiceRefresh(RefreshLoop):
    """The refresh thread of a :class:`ServiceState`."""

    def __init__(self, st: ServiceState) -> None:
        super().__init__(st)
        self.st: ServiceState = st
        self.sub = None
        self.sub_address: str | None = None
        self.input: dict[str, Any] | None = None

    def latch(self, settings: Settings) -> None:
        """Take the newest pose from the devices' stream (if any) and pick the zone."""
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

        if self.sub is not None:
            self.sub.close()
        self.sub = None if address is None else DeviceSubscriber(address, context=self.st.ctx)
        self.sub_address = address
        self.input = None

    def publish(self, r: Any, made: dict[str, Any], settings: Settings) -> None:
        """Publish a frame on the frame stream (its header: ``docs/protocol.md`` 3)."""
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

    def idle(self) -> None:
        """No frame yet: a heartbeat on the frame stream."""
        self.st.stream.heartbeat()

    def close(self) -> None:
        """Close the devices' subscriber."""
        if self.sub is not None:
            self.sub.close()
