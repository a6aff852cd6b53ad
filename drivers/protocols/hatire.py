"""Hatire: opentrack's Arduino head-tracker protocol (decoder and encoders, pure).

Link: 115200 baud, 8N1, no flow control by default (any rate works; it is set on the
port, not here).

Frame (30 bytes, struct ``<HH6fH``; ``>HH6fH`` when big-endian is chosen)::

    offset  size  field
    0       2     header   AA AA
    2       2     code     uint16
    4       4     yaw      float32, degrees
    8       4     pitch    float32, degrees
    12      4     roll     float32, degrees
    16      4     x        float32, device units
    20      4     y        float32
    24      4     z        float32
    28      2     trailer  55 55

Codes:

* 0-999: pose frames; the code is a frame counter that wraps 999 -> 0.
* 1000-1999: undefined; the frame is counted and reported as an ``error`` status.
* 2000 info, 3000 init, 5000 start, 9000 error (and any other code >= 2000): text
  frames; bytes 4-27 hold up to 24 bytes of ASCII text, NUL-padded.  9000 is reported
  as an ``error`` status, the others as ``info``.  3000 and 5000 restart the counter
  check.

Value ranges: angles are expected within +/- ``angle_limit`` degrees (default 180) and
finite; frames outside are still delivered as poses, counted in
``stats.out_of_range`` and reported once per run as an ``error`` status
(``reason: "out_of_range"``).  Positions are not range-checked.

Host to device: single-byte commands, configurable (:class:`HatireCommands`); the
defaults are ``S`` start, ``s`` stop, ``R`` reset.

Resync: the decoder scans for ``AA AA``.  A candidate whose byte 28-29 are not
``55 55`` is not a frame: if another header starts inside it (4 to 29 bytes in)
the candidate is a truncated frame (``truncated`` status, bytes discarded), otherwise
one byte is dropped and the scan goes on from the next byte, so an intact frame that
follows or overlaps garbage is never lost.  Discarded bytes form runs; each run is
reported by one ``resync`` status (``details.discarded``) when the next frame is
found, however the input was chunked.  A counter that does not advance by one (mod
1000) gives a ``counter_gap`` status (``details.missing``).  ``flush`` reports an
unfinished frame at the end of input as ``truncated``.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from drivers.events import DecoderStats, Event, PoseEvent, StatusEvent
from drivers.protocols.resync import SyncScan
from service.base.errors import ProtocolError

FRAME_LEN = 30
HEADER = b"\xaa\xaa"
TRAILER = b"\x55\x55"
COUNTER_MODULO = 1000
TEXT_LEN = 24
#: code -> (status event, meaning) for text frames.
TEXT_CODES = {2000: ("info", "info"), 3000: ("info", "init"), 5000: ("info", "start"),
              9000: ("error", "error")}
#: text codes that restart the counter check.
RESTART_CODES = frozenset({3000, 5000})
BYTE_ORDERS = {"little": "<", "big": ">"}
MIN_TRUNCATED = 4


@dataclass(frozen=True)
class HatireCommands:
    """Host-to-device command bytes (each a single character, configurable)."""

    start: bytes = b"S"
    stop: bytes = b"s"
    reset: bytes = b"R"

    def __post_init__(self) -> None:
        for name in ("start", "stop", "reset"):
            if len(getattr(self, name)) != 1:
                raise ProtocolError(f"Hatire command {name!r} must be one byte")


def _struct(byte_order: str) -> struct.Struct:
    try:
        return struct.Struct(BYTE_ORDERS[byte_order] + "HH6fH")
    except KeyError:
        raise ProtocolError(f"byte_order must be 'little' or 'big', not {byte_order!r}") from None


def encode_pose(code: int, yaw: float, pitch: float, roll: float, x: float = 0.0,
                y: float = 0.0, z: float = 0.0, byte_order: str = "little") -> bytes:
    """Build one pose frame.

    Parameters
    ----------
    code : int
        Frame counter 0-999 (taken mod 1000).
    yaw, pitch, roll : float
        Degrees.
    x, y, z : float
        Position, device units.
    byte_order : {"little", "big"}
        Byte order of the code and floats.

    Returns
    -------
    bytes
        30 bytes.
    """
    return _struct(byte_order).pack(0xAAAA, code % COUNTER_MODULO, yaw, pitch, roll,
                                    x, y, z, 0x5555)


def encode_text(code: int, text: str, byte_order: str = "little") -> bytes:
    """Build a text frame (code >= 2000; text is ASCII, cut to 24 bytes, NUL-padded)."""
    if code < 2000 or code > 0xFFFF:
        raise ProtocolError(f"text frames need a code in 2000..65535, not {code}")
    raw = text.encode("ascii", "replace")[:TEXT_LEN].ljust(TEXT_LEN, b"\0")
    code_b = code.to_bytes(2, byte_order)
    return HEADER + code_b + raw + TRAILER


def encode_command(name: str, commands: HatireCommands | None = None) -> bytes:
    """The host command byte for ``name`` (``"start"``, ``"stop"`` or ``"reset"``)."""
    cmds = commands or HatireCommands()
    if name not in ("start", "stop", "reset"):
        raise ProtocolError(f"unknown Hatire command {name!r}")
    return getattr(cmds, name)


class HatireDecoder:
    """Incremental Hatire decoder (see the module docstring for the rules).

    Parameters
    ----------
    byte_order : {"little", "big"}
        Byte order of the code and floats.
    angle_limit : float
        Angles beyond +/- this many degrees are reported as out of range.
    """

    device = "tracker"

    def __init__(self, byte_order: str = "little", angle_limit: float = 180.0) -> None:
        self._struct = _struct(byte_order)
        self._order = byte_order
        self.angle_limit = float(angle_limit)
        self.stats = DecoderStats()
        self._scan = SyncScan(HEADER, self.stats)
        self.reset()

    def reset(self) -> None:
        """Forget buffered bytes and counter state (stats are kept)."""
        self._buf = bytearray()
        self._scan.run = 0
        self._last_code: int | None = None
        self._in_range = True

    def feed(self, data: bytes, t_ns: int) -> list[Event]:
        """Decode what ``data`` completes; keep any partial frame for the next call."""
        self.stats.bytes_in += len(data)
        buf = self._buf
        buf += data
        events: list[Event] = []
        pos, n = 0, len(buf)
        while True:
            pos, found = self._scan.next_sync(buf, pos)
            j = pos
            if not found or n - j < FRAME_LEN:
                break
            if buf[j + 28] == 0x55 and buf[j + 29] == 0x55:
                self._frame(buf, j, t_ns, events)
                pos = j + FRAME_LEN
            elif n - j <= FRAME_LEN:
                break  # need one more byte to see whether a header starts at j + 29
            else:
                pos = self._bad_candidate(buf, j, t_ns, events)
        del buf[:pos]
        return events

    def flush(self, t_ns: int) -> list[Event]:
        """End of input: report leftover bytes (a torn frame) and pending garbage."""
        events: list[Event] = []
        left = len(self._buf)
        if left and self._buf.startswith(HEADER):
            self._end_garbage(t_ns, events)
            self._truncated(t_ns, events, left)
        else:
            self._scan.drop(left)
            self._end_garbage(t_ns, events)
        self._buf.clear()
        return events

    def _end_garbage(self, t_ns: int, events: list[Event]) -> None:
        if run := self._scan.end_run():
            events.append(StatusEvent(t_ns, "tracker", "resync", {"discarded": run}))

    def _truncated(self, t_ns: int, events: list[Event], size: int) -> None:
        self.stats.truncated += 1
        self.stats.bytes_discarded += size
        events.append(StatusEvent(t_ns, "tracker", "truncated", {"bytes": size}))

    def _bad_candidate(self, buf: bytearray, j: int, t_ns: int, events: list[Event]) -> int:
        nxt = buf.find(HEADER, j + 1, j + FRAME_LEN + 1)
        if nxt < 0 or nxt < j + MIN_TRUNCATED:
            self._scan.drop(1)
            return j + 1
        self._end_garbage(t_ns, events)
        self._truncated(t_ns, events, nxt - j)
        return nxt

    def _frame(self, buf: bytearray, j: int, t_ns: int, events: list[Event]) -> None:
        self._end_garbage(t_ns, events)
        self.stats.frames += 1
        _h, code, yaw, pitch, roll, x, y, z, _t = self._struct.unpack_from(buf, j)
        if code < COUNTER_MODULO:
            self._check_counter(code, t_ns, events)
            self._check_range(code, (yaw, pitch, roll), t_ns, events)
            events.append(PoseEvent(t_ns, yaw, pitch, roll, x, y, z, code))
        else:
            self._text(code, bytes(buf[j + 4:j + 28]), t_ns, events)

    def _check_counter(self, code: int, t_ns: int, events: list[Event]) -> None:
        last = self._last_code
        self._last_code = code
        if last is None or code == (last + 1) % COUNTER_MODULO:
            return
        self.stats.counter_gaps += 1
        missing = (code - last - 1) % COUNTER_MODULO
        events.append(StatusEvent(t_ns, "tracker", "counter_gap",
                                  {"expected": (last + 1) % COUNTER_MODULO, "got": code,
                                   "missing": missing}))

    def _check_range(self, code: int, angles: tuple[float, float, float], t_ns: int,
                     events: list[Event]) -> None:
        lim = self.angle_limit
        ok = all(math.isfinite(a) and -lim <= a <= lim for a in angles)
        if not ok:
            self.stats.out_of_range += 1
            if self._in_range:
                events.append(StatusEvent(t_ns, "tracker", "error",
                                          {"reason": "out_of_range", "seq": code,
                                           "angles": [repr(a) for a in angles]}))
        self._in_range = ok

    def _text(self, code: int, raw: bytes, t_ns: int, events: list[Event]) -> None:
        if code < 2000:
            events.append(StatusEvent(t_ns, "tracker", "error",
                                      {"reason": "unknown_code", "code": code}))
            return
        event, meaning = TEXT_CODES.get(code, ("info", "text"))
        if code in RESTART_CODES:
            self._last_code = None
        text = raw.split(b"\0", 1)[0].decode("ascii", "replace")
        events.append(StatusEvent(t_ns, "tracker", event,
                                  {"code": code, "meaning": meaning, "text": text}))
