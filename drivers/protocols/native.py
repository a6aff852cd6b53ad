"""Holo native tracker protocol (framing, decoder, encoders; pure, no port access).

Full spec: ``docs/native-protocol.md``.  Frame layout (all multi-byte fields
little-endian)::

    offset  size  field
    0       2     sync     A5 5A
    2       1     version  0x01
    3       1     type     see MSG_TYPES
    4       1     length   N, payload bytes (0..255; fixed or bounded per type)
    5       N     payload
    5+N     2     crc      CRC-16/CCITT-FALSE over bytes 2 .. 4+N (version..payload)

Pose payload (type 0x01, N = 40): ``uint32 seq`` (wraps at 2**32), ``uint64 t_us``
(device clock, microseconds), ``float32 x, y, z`` (millimetres),
``float32 qw, qx, qy, qz`` (unit quaternion, tolerance 1e-3).  Text payload (0x02
info, 0x03 error, N = 12..255): ``uint32 seq``, ``uint64 t_us``, UTF-8 text.  Host
commands (0x10 start, 0x11 stop, 0x12 reset) have N = 0.

Orientation convention: x right, y up, z towards the viewer; the rotation is
``R = Ry(yaw) @ Rx(pitch) @ Rz(roll)`` (right-hand rule, degrees in events).

Resync: a candidate ``A5 5A`` with a bad version, type or length, or a failed CRC,
drops one byte and the scan continues from the next byte, so no intact frame is lost.
A CRC failure gives a ``crc_error`` status; each run of dropped bytes one ``resync``
status when the next good frame arrives; a sequence jump a ``counter_gap`` status.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from drivers.events import DecoderStats, Event, PoseEvent, StatusEvent
from drivers.protocols.crc import crc16_ccitt
from drivers.protocols.resync import SyncScan
from service.base.errors import ProtocolError

SYNC = b"\xa5\x5a"
VERSION = 1
HEADER_LEN = 5
CRC_LEN = 2
SEQ_MODULO = 1 << 32
POSE = 0x01
INFO = 0x02
ERROR = 0x03
START, STOP, RESET = 0x10, 0x11, 0x12
#: type -> (name, min payload length, max payload length)
MSG_TYPES = {POSE: ("pose", 40, 40), INFO: ("info", 12, 255), ERROR: ("error", 12, 255),
             START: ("start", 0, 0), STOP: ("stop", 0, 0), RESET: ("reset", 0, 0)}
COMMANDS = {"start": START, "stop": STOP, "reset": RESET}
_POSE = struct.Struct("<IQ3f4f")
_TEXT_HEAD = struct.Struct("<IQ")
_CRC = struct.Struct("<H")
QUAT_TOLERANCE = 1e-3


@dataclass(frozen=True, slots=True)
class Frame:
    """One framed message: its type byte and payload (CRC already checked)."""

    type: int
    payload: bytes


def quat_from_euler(yaw: float, pitch: float, roll: float) -> tuple[float, float, float, float]:
    """Quaternion ``(w, x, y, z)`` of ``Ry(yaw) Rx(pitch) Rz(roll)``; angles in degrees."""
    hy, hp, hr = (math.radians(a) / 2 for a in (yaw, pitch, roll))
    cy, sy, cp, sp, cr, sr = (math.cos(hy), math.sin(hy), math.cos(hp), math.sin(hp),
                              math.cos(hr), math.sin(hr))
    # q = qy * qx * qz
    w = cy * cp * cr + sy * sp * sr
    x = cy * sp * cr + sy * cp * sr
    y = sy * cp * cr - cy * sp * sr
    z = cy * cp * sr - sy * sp * cr
    return (w, x, y, z)


def euler_from_quat(q: tuple[float, float, float, float]) -> tuple[float, float, float]:
    """Inverse of :func:`quat_from_euler`: (yaw, pitch, roll) in degrees, pitch in [-90, 90]."""
    w, x, y, z = q
    r02 = 2 * (x * z + w * y)
    r22 = 1 - 2 * (x * x + y * y)
    r12 = 2 * (y * z - w * x)
    r10 = 2 * (x * y + w * z)
    r11 = 1 - 2 * (x * x + z * z)
    pitch = math.asin(max(-1.0, min(1.0, -r12)))
    return (math.degrees(math.atan2(r02, r22)), math.degrees(pitch),
            math.degrees(math.atan2(r10, r11)))


def encode_frame(msg_type: int, payload: bytes = b"") -> bytes:
    """Frame ``payload`` as message ``msg_type`` (checks the per-type length)."""
    try:
        _name, lo, hi = MSG_TYPES[msg_type]
    except KeyError:
        raise ProtocolError(f"unknown native message type 0x{msg_type:02x}") from None
    if not lo <= len(payload) <= hi:
        raise ProtocolError(f"type 0x{msg_type:02x} payload must be {lo}..{hi} bytes")
    body = bytes((VERSION, msg_type, len(payload))) + payload
    return SYNC + body + _CRC.pack(crc16_ccitt(body))


def encode_pose(seq: int, t_us: int, position: tuple[float, float, float],
                quat: tuple[float, float, float, float]) -> bytes:
    """A pose frame (47 bytes); ``seq`` wraps at 2**32, ``t_us`` at 2**64."""
    payload = _POSE.pack(seq % SEQ_MODULO, t_us % (1 << 64), *position, *quat)
    return encode_frame(POSE, payload)


def encode_text(seq: int, t_us: int, text: str, error: bool = False) -> bytes:
    """An info (or error) text frame; text is UTF-8, cut to 243 bytes."""
    raw = text.encode("utf-8")[:255 - _TEXT_HEAD.size]
    payload = _TEXT_HEAD.pack(seq % SEQ_MODULO, t_us % (1 << 64)) + raw
    return encode_frame(ERROR if error else INFO, payload)


def encode_command(name: str) -> bytes:
    """A host command frame: ``"start"``, ``"stop"`` or ``"reset"``."""
    try:
        return encode_frame(COMMANDS[name])
    except KeyError:
        raise ProtocolError(f"unknown native command {name!r}") from None


class NativeFramer:
    """Splits a byte stream into CRC-checked :class:`Frame` objects, resyncing.

    Used by :class:`NativeDecoder` (device to host) and by the simulator (host
    commands).  ``on_crc_error`` and ``on_garbage_end`` hooks are plain counters
    here; the decoder turns them into events.
    """

    def __init__(self) -> None:
        self.stats = DecoderStats()
        self._buf = bytearray()
        self._scan = SyncScan(SYNC, self.stats)

    def reset(self) -> None:
        """Forget buffered bytes."""
        self._buf.clear()
        self._scan.run = 0

    def feed(self, data: bytes) -> list[Frame | tuple[str, int]]:
        """Return frames and markers ``("garbage", n)`` / ``("crc", type)`` in order."""
        self.stats.bytes_in += len(data)
        buf = self._buf
        buf += data
        out: list[Frame | tuple[str, int]] = []
        pos, n = 0, len(buf)
        while True:
            pos, found = self._scan.next_sync(buf, pos)
            if not found:
                break
            j = pos
            step = self._candidate(buf, j, n, out)
            if step == 0:
                break
            pos = j + step
        del buf[:pos]
        return out

    def _candidate(self, buf: bytearray, j: int, n: int, out: list) -> int:
        if n - j < HEADER_LEN:
            return 0
        spec = MSG_TYPES.get(buf[j + 3])
        length = buf[j + 4]
        if buf[j + 2] != VERSION or spec is None or not spec[1] <= length <= spec[2]:
            self._scan.drop(1)
            return 1
        end = j + HEADER_LEN + length
        if n < end + CRC_LEN:
            return 0
        if crc16_ccitt(memoryview(buf)[j + 2:end]) != _CRC.unpack_from(buf, end)[0]:
            self.stats.crc_errors += 1
            self._flush_garbage(out)
            out.append(("crc", buf[j + 3]))
            self._scan.drop(1)
            return 1
        self._flush_garbage(out)
        self.stats.frames += 1
        out.append(Frame(buf[j + 3], bytes(buf[j + HEADER_LEN:end])))
        return end + CRC_LEN - j

    def _flush_garbage(self, out: list) -> None:
        if run := self._scan.end_run():
            out.append(("garbage", run))

    def flush(self) -> list[Frame | tuple[str, int]]:
        """End of input: an unfinished frame becomes ``("truncated", n)``.

        Its bytes run to the next sync (or the end); what follows is scanned again, so
        a whole frame behind a bogus length field is still delivered.
        """
        out: list[Frame | tuple[str, int]] = []
        buf = self._buf
        while buf:
            if not buf.startswith(SYNC):
                self._scan.drop(len(buf))
                buf.clear()
                break
            nxt = buf.find(SYNC, 1)
            size = len(buf) if nxt < 0 else nxt
            self._flush_garbage(out)
            self.stats.truncated += 1
            self.stats.bytes_discarded += size
            out.append(("truncated", size))
            del buf[:size]
            out += self.feed(b"")
        self._flush_garbage(out)
        return out


class NativeDecoder:
    """Incremental native-protocol decoder producing events (see module docstring)."""

    device = "tracker"

    def __init__(self) -> None:
        self._framer = NativeFramer()
        self.stats = self._framer.stats
        self._last_seq: int | None = None
        self._in_range = True

    def reset(self) -> None:
        """Forget buffered bytes and sequence state (stats are kept)."""
        self._framer.reset()
        self._last_seq = None
        self._in_range = True

    def feed(self, data: bytes, t_ns: int) -> list[Event]:
        """Decode what ``data`` completes; keep any partial frame for the next call."""
        return self._events(self._framer.feed(data), t_ns)

    def flush(self, t_ns: int) -> list[Event]:
        """End of input: report a torn final frame and pending garbage."""
        return self._events(self._framer.flush(), t_ns)

    def _events(self, items: list, t_ns: int) -> list[Event]:
        events: list[Event] = []
        for item in items:
            if isinstance(item, Frame):
                self._frame(item, t_ns, events)
            else:
                events.append(_marker_event(item, t_ns))
        return events

    def _frame(self, frame: Frame, t_ns: int, events: list[Event]) -> None:
        if frame.type == POSE:
            seq, t_us, x, y, z, *quat = _POSE.unpack(frame.payload)
            self._check_seq(seq, t_ns, events)
            self._check_quat(seq, quat, t_ns, events)
            yaw, pitch, roll = euler_from_quat(tuple(quat))
            events.append(PoseEvent(t_ns, yaw, pitch, roll, x, y, z, seq,
                                    tuple(quat), t_us))
        elif frame.type in (INFO, ERROR):
            seq, t_us = _TEXT_HEAD.unpack_from(frame.payload)
            text = frame.payload[_TEXT_HEAD.size:].decode("utf-8", "replace")
            events.append(StatusEvent(t_ns, "tracker", MSG_TYPES[frame.type][0],
                                      {"seq": seq, "device_t_us": t_us, "text": text}))
        else:
            events.append(StatusEvent(t_ns, "tracker", "error",
                                      {"reason": "host_command_from_device",
                                       "type": frame.type}))

    def _check_seq(self, seq: int, t_ns: int, events: list[Event]) -> None:
        last = self._last_seq
        self._last_seq = seq
        if last is None or seq == (last + 1) % SEQ_MODULO:
            return
        self.stats.counter_gaps += 1
        events.append(StatusEvent(t_ns, "tracker", "counter_gap",
                                  {"expected": (last + 1) % SEQ_MODULO, "got": seq,
                                   "missing": (seq - last - 1) % SEQ_MODULO}))

    def _check_quat(self, seq: int, quat: list[float], t_ns: int,
                    events: list[Event]) -> None:
        norm = math.sqrt(sum(c * c for c in quat))
        ok = math.isfinite(norm) and abs(norm - 1.0) <= QUAT_TOLERANCE
        if not ok:
            self.stats.out_of_range += 1
            if self._in_range:
                events.append(StatusEvent(t_ns, "tracker", "error",
                                          {"reason": "out_of_range", "seq": seq,
                                           "quat_norm": repr(norm)}))
        self._in_range = ok


_MARKERS = {"garbage": ("resync", "discarded"), "crc": ("crc_error", "type"),
            "truncated": ("truncated", "bytes")}


def _marker_event(item: tuple[str, int], t_ns: int) -> StatusEvent:
    event, key = _MARKERS[item[0]]
    return StatusEvent(t_ns, "tracker", event, {key: item[1]})
