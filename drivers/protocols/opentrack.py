"""opentrack's "UDP over network" poses (decoder and encoder, pure).

opentrack (the head-tracking program: webcam face trackers, phones, IMUs) sends one
UDP datagram per pose from its "UDP over network" output, default port 4242.  A
datagram is exactly 48 bytes: six doubles in the sender's byte order (little-endian
on every platform opentrack runs on; struct ``<6d``)::

    offset  size  field
    0       8     x      float64, centimetres
    8       8     y      float64, centimetres
    16      8     z      float64, centimetres
    24      8     yaw    float64, degrees
    32      8     pitch  float64, degrees
    40      8     roll   float64, degrees

(opentrack's ``proto-udp`` writes its ``double[6]`` head pose as it is, in the order of
its ``Axis`` enum ``TX, TY, TZ, Yaw, Pitch, Roll``; its own UDP input tracker reads the
same 48 bytes and ignores a pose holding a NaN.)

Axes.  opentrack's: x to the user's right, y up, z backward (away from the screen,
toward the user); yaw positive turning right, pitch positive looking down, roll
positive tilting left (its FreeTrack output negates yaw and pitch to get FreeTrack's
"yaw left, pitch up" and keeps roll: ``proto-ft``).  Ours (README, *The display
model*; the native protocol's): x right, y up, z toward the viewer, millimetres, and
``R = Ry(yaw) Rx(pitch) Rz(roll)`` by the right-hand rule, so yaw positive turns left
and pitch positive looks up.  :data:`TO_DISPLAY` is the one table between them:
positions times 10 (cm to mm), yaw and pitch negated, roll kept.  A sender whose
axis looks mirrored is fixed where opentrack users fix it: opentrack's Options,
Output, "invert".

Datagrams: every :meth:`OpentrackDecoder.feed` call is **one datagram** (the UDP
reader hands them over one by one and a session log keeps one record per datagram),
unlike the serial decoders, which take any chunking.  A datagram that is not 48
bytes, or that holds a NaN or infinity, or an angle beyond +/- ``angle_limit``
degrees, or a position beyond +/- ``position_limit_cm``, is counted (``bad_size``
and ``bytes_discarded``; ``out_of_range``) and dropped: it never becomes a pose.
(An empty datagram is not seen at all: a reader cannot tell it from none.)
Each run of such datagrams is reported once, by an ``error`` status (``reason``:
``wrong_size``, ``not_finite`` or ``out_of_range``), when it starts.

opentrack sends no frame counter: ``seq`` is the datagram's number since the decoder
was reset (0, 1, 2, ...; dropped datagrams take their number too, so a jump in the
poses' ``seq`` shows what was dropped).
"""

from __future__ import annotations

import math
import struct
from typing import Any

from drivers.events import DecoderStats, Event, PoseEvent, StatusEvent

#: opentrack's default "UDP over network" port.
DEFAULT_PORT = 4242
#: The URL scheme of an opentrack UDP listener: ``opentrack-udp://HOST:PORT``.
URL_SCHEME = "opentrack-udp"
_POSE = struct.Struct("<6d")
#: Bytes in one datagram.
DATAGRAM_LEN = _POSE.size
#: opentrack's order of the six doubles.
FIELDS = ("x", "y", "z", "yaw", "pitch", "roll")
#: opentrack value -> ours: each field's factor (cm -> mm; yaw and pitch mirrored).
TO_DISPLAY = {"x": 10.0, "y": 10.0, "z": 10.0, "yaw": -1.0, "pitch": -1.0, "roll": 1.0}
_FACTORS = tuple(TO_DISPLAY[f] for f in FIELDS)
#: Default limits of a valid pose: degrees, centimetres.
ANGLE_LIMIT = 180.0
POSITION_LIMIT_CM = 500.0
SEQ_MODULO = 1 << 32


def encode_pose(x: float, y: float, z: float, yaw: float, pitch: float, roll: float) -> bytes:
    """One opentrack datagram from a pose in **our** axes and units.

    Parameters
    ----------
    x, y, z : float
        Position, millimetres, display axes (x right, y up, z toward the viewer).
    yaw, pitch, roll : float
        Degrees, right-hand rule about y, x and z.

    Returns
    -------
    bytes
        48 bytes: opentrack's ``x, y, z`` (cm), ``yaw, pitch, roll`` (degrees).
    """
    ours = (x, y, z, yaw, pitch, roll)
    return _POSE.pack(*(v / f for v, f in zip(ours, _FACTORS, strict=True)))


def encode_raw(x: float, y: float, z: float, yaw: float, pitch: float, roll: float) -> bytes:
    """One datagram of values already in opentrack's axes and units (as it sends them)."""
    return _POSE.pack(x, y, z, yaw, pitch, roll)


class OpentrackDecoder:
    """Decoder of opentrack UDP datagrams, one per :meth:`feed` (see the module docstring).

    Parameters
    ----------
    angle_limit : float
        Largest valid ``|yaw|``, ``|pitch|``, ``|roll|``, degrees.
    position_limit_cm : float
        Largest valid ``|x|``, ``|y|``, ``|z|``, centimetres (as opentrack sends them).
    """

    device = "tracker"

    def __init__(self, angle_limit: float = ANGLE_LIMIT,
                 position_limit_cm: float = POSITION_LIMIT_CM) -> None:
        self.angle_limit = float(angle_limit)
        self.position_limit_cm = float(position_limit_cm)
        self.stats = DecoderStats()
        self.reset()

    def reset(self) -> None:
        """Start numbering datagrams from 0 again; re-arm the bad-run reports."""
        self._seq = 0
        self._bad: str | None = None

    def feed(self, data: bytes, t_ns: int) -> list[Event]:
        """Decode one datagram received at ``t_ns``: a pose, a status, or nothing."""
        if not data:  # a reader cannot tell an empty datagram from none: neither is one
            return []
        st = self.stats
        st.bytes_in += len(data)
        seq = self._seq
        self._seq = (seq + 1) % SEQ_MODULO
        if len(data) != DATAGRAM_LEN:
            st.bad_size += 1
            st.bytes_discarded += len(data)
            return self._bad_run("wrong_size", t_ns, seq,
                                 {"bytes": len(data), "expected": DATAGRAM_LEN})
        st.frames += 1
        values = _POSE.unpack(data)
        problem = self._check(values)
        if problem:
            st.out_of_range += 1
            return self._bad_run(problem, t_ns, seq, {"values": [repr(v) for v in values]})
        self._bad = None
        x, y, z, yaw, pitch, roll = (v * f for v, f in zip(values, _FACTORS, strict=True))
        return [PoseEvent(t_ns, yaw, pitch, roll, x, y, z, seq)]

    def flush(self, t_ns: int) -> list[Event]:
        """Nothing is ever left over between datagrams."""
        return []

    def _check(self, values: tuple[float, ...]) -> str | None:
        if not all(map(math.isfinite, values)):
            return "not_finite"
        lim_p, lim_a = self.position_limit_cm, self.angle_limit
        if any(abs(v) > lim_p for v in values[:3]) or any(abs(v) > lim_a for v in values[3:]):
            return "out_of_range"
        return None

    def _bad_run(self, reason: str, t_ns: int, seq: int, details: dict[str, Any]) -> list[Event]:
        """An ``error`` status for the first bad datagram of a run (of one reason)."""
        if self._bad == reason:
            return []
        if self._bad is None:
            self.stats.resyncs += 1
        self._bad = reason
        return [StatusEvent(t_ns, "tracker", "error", {"reason": reason, "seq": seq, **details})]
