"""Simulated head tracker speaking Hatire, the native protocol or opentrack's UDP poses.

:class:`TrackerSim` samples a motion at ``rate_hz`` and encodes each sample as a
frame; :meth:`TrackerSim.frames` yields ``(t_seconds, frame_bytes)``.  It also
answers host commands (:meth:`TrackerSim.receive`): Hatire single characters
(start / stop / reset, configurable) or native command frames.  A reset restarts the
counter and sends an ``init`` text frame (Hatire code 3000, native info text);
a start sends a ``start`` text frame (Hatire 5000).  ``streaming`` is what an
endpoint runner checks before sending the next frame; ``received`` counts the
commands acted on.  :meth:`TrackerSim.power_cycle` is what a device unplugged and
plugged back in does: one that waits for a start command waits again.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from functools import partial

from drivers.protocols import hatire, native, opentrack
from service.base.errors import SettingsError
from sim_devices.motion import Motion, Sway

PROTOCOLS = ("hatire", "native", "opentrack")
#: default serial rate per protocol (8N1; opentrack's datagrams are not paced).
DEFAULT_BAUD = {"hatire": 115200, "native": 115200, "opentrack": 115200}


class TrackerSim:
    """A tracker that turns a motion into frames.

    Parameters
    ----------
    protocol : {"hatire", "native", "opentrack"}
        Byte protocol (opentrack: one datagram per pose, our axes mapped to its).
    motion : Motion or None
        Head motion (default :class:`~sim_devices.motion.Sway`).
    rate_hz : float
        Frames per second (> 0).
    byte_order : {"little", "big"}
        Hatire byte order.
    commands : HatireCommands or None
        Hatire host command bytes.
    autostart : bool
        Stream from the start (True) or wait for a start command.
    """

    def __init__(self, protocol: str = "hatire", motion: Motion | None = None,
                 rate_hz: float = 60.0, byte_order: str = "little",
                 commands: hatire.HatireCommands | None = None,
                 autostart: bool = True) -> None:
        if protocol not in PROTOCOLS:
            raise SettingsError(f"tracker protocol must be one of {PROTOCOLS}")
        if rate_hz <= 0:
            raise SettingsError("rate_hz must be > 0")
        self.protocol = protocol
        self.motion = motion or Sway()
        self.rate_hz = rate_hz
        self.byte_order = byte_order
        self.commands = commands or hatire.HatireCommands()
        self.autostart = autostart
        self.streaming = autostart
        self.received = dict.fromkeys(("start", "stop", "reset"), 0)
        self.seq = 0
        self._framer = native.NativeFramer()
        self._hatire_cmds = {self.commands.start: "start", self.commands.stop: "stop",
                             self.commands.reset: "reset"}
        self._on_command = {"start": self._start, "stop": self._stop, "reset": self._reset}

    @property
    def baud(self) -> int:
        """The protocol's default serial rate."""
        return DEFAULT_BAUD[self.protocol]

    def encode(self, t: float) -> bytes:
        """The next frame for time ``t`` (advances the counter)."""
        p = self.motion.pose(t)
        seq = self.seq
        self.seq += 1
        if self.protocol == "hatire":
            return hatire.encode_pose(seq, p.yaw, p.pitch, p.roll, p.x, p.y, p.z,
                                      self.byte_order)
        if self.protocol == "opentrack":
            return opentrack.encode_pose(p.x, p.y, p.z, p.yaw, p.pitch, p.roll)
        quat = native.quat_from_euler(p.yaw, p.pitch, p.roll)
        return native.encode_pose(seq, round(t * 1e6), (p.x, p.y, p.z), quat)

    def frames(self, seconds: float | None = None) -> Iterator[tuple[float, Callable[[], bytes]]]:
        """``(t, make_frame)`` at ``rate_hz`` from t = 0, for ``seconds`` (None: forever).

        ``make_frame()`` encodes the frame when called, so host commands handled
        before it (a reset) take effect on it.
        """
        k = 0
        while seconds is None or k / self.rate_hz < seconds:
            t = k / self.rate_hz
            yield t, partial(self.encode, t)
            k += 1

    def receive(self, data: bytes, t: float = 0.0) -> bytes:
        """Act on host bytes; return the immediate reply (text frames or b"")."""
        if self.protocol == "hatire":
            names = [self._hatire_cmds.get(bytes((b,))) for b in data]
        else:
            names = [native.MSG_TYPES[f.type][0] for f in self._framer.feed(data)
                     if isinstance(f, native.Frame)]
        replies = []
        for name in names:
            if name in self._on_command:
                self.received[name] += 1
                replies.append(self._on_command[name](t))
        return b"".join(replies)

    def power_cycle(self) -> None:
        """Back to the power-on state: streaming only if ``autostart``.

        The frame counter goes on, so a fault ledger's sequence numbers stay unique.
        """
        self.streaming = self.autostart

    def _text(self, code: int, text: str, t: float) -> bytes:
        if self.protocol == "opentrack":  # no text, no commands: never reached by a host
            return b""
        if self.protocol == "hatire":
            return hatire.encode_text(code, text, self.byte_order)
        return native.encode_text(self.seq, round(t * 1e6), text)

    def _start(self, t: float) -> bytes:
        self.streaming = True
        return self._text(5000, "start", t)

    def _stop(self, t: float) -> bytes:
        self.streaming = False
        return b""

    def _reset(self, t: float) -> bytes:
        self.seq = 0
        return self._text(3000, "init", t)
