"""Device events: what the decoders produce and what the drivers publish and record.

Every event is a frozen dataclass carrying the receive time ``t_ns`` (nanoseconds in
the :func:`time.monotonic_ns` domain, exactly as given to ``Decoder.feed``), the
device it came from (``"tracker"`` or ``"dials"``) and its kind.  ``to_dict`` /
``to_json`` produce the dump schema::

    {"t": <seconds since start, float>, "device": "tracker" | "dials",
     "kind": "pose" | "dial" | "button" | "status", ...}

with, per kind,

========  ===============================================================
pose      ``yaw, pitch, roll`` (degrees), ``x, y, z`` (device units, mm for
          the native protocol and opentrack), ``seq`` (frame counter); optional ``quat``
          ``[w, x, y, z]`` and ``device_t_us`` when the protocol sends them
dial      ``index`` (0-7), ``delta`` (counts since the last report),
          ``value`` (absolute counts, unwrapped across the 16-bit wrap),
          ``turns`` (``value`` / counts per turn; the count per turn is a
          setting of whoever prints or publishes, default
          :data:`DEFAULT_COUNTS_PER_TURN`)
button    ``index`` (0-31), ``pressed`` (true / false)
status    ``event`` (one of :data:`STATUS_EVENTS`), ``details`` (an object)
========  ===============================================================

"Start" is the ``t0_ns`` the caller passes (the session start); it defaults to 0.
:func:`event_from_dict` reads the schema back (for replay).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from service.base.errors import ProtocolError

#: Allowed values of :attr:`StatusEvent.event`.
STATUS_EVENTS = frozenset(
    {"counter_gap", "resync", "truncated", "crc_error", "reconnect", "info", "error"}
)
#: Allowed device names.
DEVICES = frozenset({"tracker", "dials"})
NS_PER_S = 1_000_000_000
#: Dial counts per turn of the SGI box (VRPN's value).
DEFAULT_COUNTS_PER_TURN = 200


class _Dumped:
    """The dump schema, written once for every event class (a mixin, no state).

    A dict is ``{"t": seconds since t0_ns, "device", "kind", **payload}``; the
    subclasses give ``device``, ``kind`` and ``payload(counts_per_turn)``.
    """

    __slots__ = ()

    def to_dict(self, t0_ns: int = 0,
                counts_per_turn: int = DEFAULT_COUNTS_PER_TURN) -> dict[str, Any]:
        """Dump-schema dict; ``t`` is seconds since ``t0_ns``.

        ``counts_per_turn`` sets a dial event's ``turns``; other events ignore it.
        """
        out: dict[str, Any] = {"t": (self.t_ns - t0_ns) / NS_PER_S,  # type: ignore[attr-defined]
                               "device": self.device, "kind": self.kind}  # type: ignore[attr-defined]
        out.update(self.payload(counts_per_turn))  # type: ignore[attr-defined]
        return out

    def to_json(self, t0_ns: int = 0, counts_per_turn: int = DEFAULT_COUNTS_PER_TURN) -> str:
        """Dump-schema JSON text (one line)."""
        return json.dumps(self.to_dict(t0_ns, counts_per_turn), separators=(",", ":"))


@dataclass(frozen=True, slots=True)
class PoseEvent(_Dumped):
    """A head-tracker pose.

    Parameters
    ----------
    t_ns : int
        Receive time, ns, :func:`time.monotonic_ns` domain.
    yaw, pitch, roll : float
        Orientation in degrees (as sent; the decoder does not wrap them).
    x, y, z : float
        Position in device units.
    seq : int
        Frame counter (Hatire 0-999 wrapping, native 0 to 2**32-1 wrapping).
    quat : tuple of 4 float or None
        Orientation quaternion ``(w, x, y, z)`` when the protocol sends one.
    device_t_us : int or None
        Device timestamp in microseconds when the protocol sends one.

    Attributes
    ----------
    device : str
        Always ``"tracker"`` (class attribute).
    """

    t_ns: int
    yaw: float
    pitch: float
    roll: float
    x: float
    y: float
    z: float
    seq: int
    quat: tuple[float, float, float, float] | None = None
    device_t_us: int | None = None
    device = "tracker"
    kind = "pose"

    def payload(self, counts_per_turn: int = DEFAULT_COUNTS_PER_TURN) -> dict[str, Any]:
        """Kind-specific fields of the dump schema (``counts_per_turn``: dials only)."""
        out: dict[str, Any] = {
            "yaw": self.yaw, "pitch": self.pitch, "roll": self.roll,
            "x": self.x, "y": self.y, "z": self.z, "seq": self.seq,
        }
        if self.quat is not None:
            out["quat"] = list(self.quat)
        if self.device_t_us is not None:
            out["device_t_us"] = self.device_t_us
        return out


@dataclass(frozen=True, slots=True)
class DialEvent(_Dumped):
    """A dial turned.

    Parameters
    ----------
    t_ns : int
        Receive time, ns.
    index : int
        Dial 0-7.
    delta : int
        Counts since the previous report of this dial (-32768..32767).
    value : int
        Absolute count since the last reset, unwrapped (unbounded int).

    Notes
    -----
    The dump and the published message add ``turns``, ``value`` divided by the
    counts per turn that the program was given (``--dial-counts-per-turn``); the
    event itself stays a count, so the decoder needs no setting.

    Attributes
    ----------
    device : str
        Always ``"dials"`` (class attribute).
    """

    t_ns: int
    index: int
    delta: int
    value: int
    device = "dials"
    kind = "dial"

    def payload(self, counts_per_turn: int = DEFAULT_COUNTS_PER_TURN) -> dict[str, Any]:
        """Kind-specific fields of the dump schema (``turns`` per ``counts_per_turn``)."""
        return {"index": self.index, "delta": self.delta, "value": self.value,
                "turns": self.turns(counts_per_turn)}

    def turns(self, counts_per_turn: int = DEFAULT_COUNTS_PER_TURN) -> float:
        """Absolute value in turns (VRPN uses 200 counts per turn)."""
        return self.value / counts_per_turn


@dataclass(frozen=True, slots=True)
class ButtonEvent(_Dumped):
    """A button pressed or released.

    Parameters
    ----------
    t_ns : int
        Receive time, ns.
    index : int
        Button 0-31.
    pressed : bool
        True for a press, False for a release.

    Attributes
    ----------
    device : str
        Always ``"dials"`` (class attribute).
    """

    t_ns: int
    index: int
    pressed: bool
    device = "dials"
    kind = "button"

    def payload(self, counts_per_turn: int = DEFAULT_COUNTS_PER_TURN) -> dict[str, Any]:
        """Kind-specific fields of the dump schema (``counts_per_turn``: dials only)."""
        return {"index": self.index, "pressed": self.pressed}


@dataclass(frozen=True, slots=True)
class StatusEvent(_Dumped):
    """Something about the link rather than a reading.

    Parameters
    ----------
    t_ns : int
        Receive time, ns.
    device : str
        ``"tracker"`` or ``"dials"``.
    event : str
        One of :data:`STATUS_EVENTS`.
    details : Mapping
        JSON-able details (e.g. ``{"discarded": 23}``); stored read-only.
        ``{"action": "reinit"}`` asks the driver to re-initialise the device.
    """

    t_ns: int
    device: str
    event: str
    details: Mapping[str, Any] = field(default_factory=dict)
    kind = "status"

    def __post_init__(self) -> None:
        if self.event not in STATUS_EVENTS:
            raise ProtocolError(f"unknown status event {self.event!r}")
        object.__setattr__(self, "details", MappingProxyType(dict(self.details)))

    @property
    def needs_reinit(self) -> bool:
        """True when the decoder asks the driver to re-initialise the device."""
        return self.details.get("action") == "reinit"

    def payload(self, counts_per_turn: int = DEFAULT_COUNTS_PER_TURN) -> dict[str, Any]:
        """Kind-specific fields of the dump schema (``counts_per_turn``: dials only)."""
        return {"event": self.event, "details": dict(self.details)}


Event = PoseEvent | DialEvent | ButtonEvent | StatusEvent


def _pose(d: Mapping[str, Any], t_ns: int) -> PoseEvent:
    quat = d.get("quat")
    return PoseEvent(t_ns, float(d["yaw"]), float(d["pitch"]), float(d["roll"]),
                     float(d["x"]), float(d["y"]), float(d["z"]), int(d["seq"]),
                     tuple(float(v) for v in quat) if quat is not None else None,
                     d.get("device_t_us"))


_FROM_DICT = {
    "pose": _pose,
    "dial": lambda d, t: DialEvent(t, int(d["index"]), int(d["delta"]), int(d["value"])),
    "button": lambda d, t: ButtonEvent(t, int(d["index"]), bool(d["pressed"])),
    "status": lambda d, t: StatusEvent(t, d["device"], d["event"], d.get("details", {})),
}


def event_from_dict(d: Mapping[str, Any], t0_ns: int = 0) -> Event:
    """Read one dump-schema dict back into an event.

    Parameters
    ----------
    d : Mapping
        A dict as produced by ``to_dict``.
    t0_ns : int
        The start time the dict's ``t`` is relative to.

    Returns
    -------
    Event

    Raises
    ------
    ProtocolError
        If the dict does not follow the schema.
    """
    try:
        t_ns = t0_ns + round(float(d["t"]) * NS_PER_S)
        return _FROM_DICT[d["kind"]](d, t_ns)
    except (KeyError, TypeError, ValueError, OverflowError) as exc:  # Overflow: t of 1e400
        raise ProtocolError(f"not a device event: {d!r} ({exc})") from exc


@dataclass(slots=True)
class DecoderStats:
    """Running counters every decoder keeps (read them, never write them).

    Attributes
    ----------
    frames : int
        Frames / packets decoded intact (poses, dial and button reports, text).
    bytes_in : int
        Bytes fed.
    bytes_discarded : int
        Bytes thrown away while resynchronising.
    resyncs : int
        Runs of discarded bytes (one per run, however it was chunked).
    counter_gaps : int
        Jumps in the frame counter.
    crc_errors : int
        Frames whose CRC failed.
    truncated : int
        Frames cut short (a new header came before the frame ended, a dial packet
        timed out, or bytes were left over at ``flush``).
    out_of_range : int
        Frames with values outside the documented range (Hatire and native deliver
        them; opentrack drops them, and counts NaN / infinity here too).
    bad_size : int
        Datagrams of the wrong size (opentrack UDP; dropped, their bytes discarded).
    """

    frames: int = 0
    bytes_in: int = 0
    bytes_discarded: int = 0
    resyncs: int = 0
    counter_gaps: int = 0
    crc_errors: int = 0
    truncated: int = 0
    out_of_range: int = 0
    bad_size: int = 0

    def as_dict(self) -> dict[str, int]:
        """The counters as a plain dict."""
        return {name: getattr(self, name) for name in self.__slots__}
