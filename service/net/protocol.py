"""The service protocol, version 1 (``docs/protocol.md``): pure functions over frames.

A request arrives at the service's ROUTER as ``[identity, b"", header, *buffers]``
(the empty delimiter is optional).  :func:`split_envelope` separates the routing
envelope, :func:`parse_request` checks the rest and raises
:class:`~service.base.errors.MessageError` with the protocol's error code;
:func:`reply` and :func:`error_reply` build the answer frames.  Nothing here does
I/O, so every rule is testable without sockets.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from service.base.errors import MessageError
from service.net import wire

VERSION = 1
SUPPORTED_VERSIONS = (1,)
SERVICE_NAME = "holo-service"
HEARTBEAT_S = 1.0
#: a peer not heard from for this many heartbeats is dead.
HEARTBEAT_LIVENESS = 3
#: render workers' heartbeat (``READY`` while idle, ``BUSY`` while rendering): a
#: worker silent for HEARTBEAT_LIVENESS of these is dead (``docs/service.md``,
#: "Supervised workers"); short, so a stopped worker's job is resent within a second.
WORKER_HEARTBEAT_S = 0.2

MESSAGE_TYPES = (
    "hello",
    "ping",
    "load_scene",
    "load_object",
    "update_objects",
    "set_viewer",
    "set_display",
    "render",
    "stats",
    "shutdown",
)
#: requests that change the service's state: a resend of one (same ``client_id``
#: and ``id``) is answered from the reply cache instead of being applied again.
MUTATING_TYPES = ("load_scene", "load_object", "update_objects", "set_viewer", "set_display")
#: replies remembered for resends: at most this many, for this many seconds.
REPLY_CACHE_SIZE = 1024
REPLY_CACHE_S = 60.0

ERROR_CODES = (
    "bad_frames",
    "bad_json",
    "bad_version",
    "unknown_type",
    "bad_message",
    "bad_array",
    "not_finite",
    "too_large",
    "not_found",
    "bad_settings",
    "render_failed",
    "no_scene",
    "warming_up",
    "internal",
)


@dataclass(frozen=True)
class Limits:
    """Size caps of version 1 (``docs/protocol.md`` section 1.6).

    ``max_message_bytes`` is the control socket's ``ZMQ_MAXMSGSIZE``: libzmq
    closes the connection of a peer that sends a frame bigger than that, before
    the service sees the message, so no reply is possible.  Every cap the service
    answers with a ``too_large`` reply (``max_header_bytes``, ``max_array_bytes``,
    ``max_request_bytes``) is well below it.
    """

    max_message_bytes: int = 256 << 20
    max_array_bytes: int = 128 << 20
    max_request_bytes: int = 160 << 20
    max_frames: int = 2 + wire.MAX_ARRAYS
    max_header_bytes: int = 1 << 20
    max_string: int = 4096
    max_id: int = 64
    max_name: int = wire.MAX_NAME
    max_objects: int = wire.MAX_OBJECTS
    max_vertices: int = wire.MAX_VERTICES
    max_polygons: int = wire.MAX_POLYGONS
    max_dims: int = wire.MAX_DIMS

    def as_dict(self) -> dict[str, int]:
        """The limits as the ``hello`` reply lists them."""
        return dict(self.__dict__)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Limits:
        """Limits from a ``hello`` reply (unknown keys ignored, missing ones default)."""
        known = {k: int(v) for k, v in d.items() if k in cls.__dataclass_fields__}
        return cls(**known)


DEFAULT_LIMITS = Limits()


@dataclass
class Request:
    """A parsed request.

    Attributes
    ----------
    envelope : list of bytes
        Routing frames up to and including the empty delimiter (if any).
    header : dict
        The JSON header with array references resolved to read-only ndarrays.
    """

    envelope: list[bytes]
    header: dict[str, Any] = field(default_factory=dict)

    @property
    def type(self) -> str:
        """The message type."""
        return self.header["type"]

    @property
    def id(self) -> Any:
        """The client's request id (echoed in the reply)."""
        return self.header.get("id")


def split_envelope(frames: list[Any]) -> tuple[list[bytes], list[Any]]:
    """Routing envelope (identity and the empty delimiter, if present) and body.

    ``frames`` is what a ROUTER received: ``[identity, (b""), header, *buffers]``.
    """
    ident = [bytes(frames[0])]
    if len(frames) > 1 and len(frames[1]) == 0:
        return [*ident, b""], frames[2:]
    return ident, frames[1:]


def _header(frame: Any, limits: Limits) -> dict[str, Any]:
    raw = bytes(frame)
    if len(raw) > limits.max_header_bytes:
        raise MessageError(
            "too_large", f"header has {len(raw)} bytes (max {limits.max_header_bytes})"
        )
    try:
        header = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise MessageError("bad_json", f"header is not UTF-8 JSON: {exc}") from exc
    if not isinstance(header, dict):
        raise MessageError("bad_json", "header must be a JSON object")
    return header


def check_id(value: Any, limits: Limits) -> Any:
    """The request id if valid (int, or str of <= ``max_id`` chars), else None."""
    if isinstance(value, bool):
        return None
    if isinstance(value, int) or (isinstance(value, str) and len(value) <= limits.max_id):
        return value
    return None


def _check_token(header: dict[str, Any], key: str, limits: Limits) -> None:
    """``id`` (int or str) and ``client_id`` (str of 1 or more chars): at most ``max_id``."""
    value = header[key]
    kinds = (int, str) if key == "id" else (str,)
    if isinstance(value, bool) or not isinstance(value, kinds) or value == "":
        want = "an int or a non-empty string" if key == "id" else "a non-empty string"
        raise MessageError("bad_message", f"{key} must be {want}, got {value!r:.80}")
    if isinstance(value, str) and len(value) > limits.max_id:
        raise MessageError(
            "too_large", f"{key} has {len(value)} characters (max {limits.max_id})"
        )


def check_strings(value: Any, limits: Limits, path: str = "") -> None:
    """Raise ``too_large`` for any string in a JSON value longer than ``max_string``."""
    if isinstance(value, str):
        if len(value) > limits.max_string:
            raise MessageError(
                "too_large",
                f"{path or 'a string'} has {len(value)} characters (max {limits.max_string})",
            )
    elif isinstance(value, dict):
        for k, v in value.items():
            check_strings(k, limits, f"a key of {path or 'the header'}")
            check_strings(v, limits, f"{path}.{k}" if path else str(k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            check_strings(v, limits, f"{path}[{i}]")


def _readable_type(header: dict[str, Any]) -> str | None:
    """The request's ``type`` when it is a short string (echoed even if unknown)."""
    t = header.get("type")
    return t if isinstance(t, str) and len(t) <= 64 else None


def _check_frame_count(body: list[Any], limits: Limits) -> None:
    """Raise unless ``body`` has a header frame and at most ``max_frames - 1`` frames."""
    if not body:
        raise MessageError("bad_frames", "a request needs a header frame after the envelope")
    if len(body) > limits.max_frames - 1:  # max_frames counts the empty delimiter
        raise MessageError(
            "too_large",
            f"a request has at most {limits.max_frames - 1} frames after the delimiter "
            f"(header and {limits.max_frames - 2} buffers), got {len(body)}",
        )


def _check_version_and_type(header: dict[str, Any]) -> None:
    """Raise ``bad_version`` or ``unknown_type`` for a request header."""
    v = header.get("v")
    if isinstance(v, bool) or not isinstance(v, int) or v not in SUPPORTED_VERSIONS:
        raise MessageError(
            "bad_version",
            f"v must be one of {list(SUPPORTED_VERSIONS)}, got {header.get('v')!r}",
        )
    if header.get("type") not in MESSAGE_TYPES:
        raise MessageError(
            "unknown_type",
            f"type must be one of {list(MESSAGE_TYPES)}, got {str(header.get('type'))[:64]!r}",
        )


def _check_request(header: dict[str, Any], body: list[Any], limits: Limits) -> None:
    """Every check of a request's header and size before its arrays are decoded."""
    _check_version_and_type(header)
    for key in ("id", "client_id"):
        if key in header:
            _check_token(header, key, limits)
    check_strings(header, limits)
    total = sum(memoryview(b).nbytes for b in body)
    if total > limits.max_request_bytes:
        raise MessageError(
            "too_large",
            f"request has {total} bytes (max {limits.max_request_bytes} in all frames)",
        )


def parse_request(body: list[Any], limits: Limits | None = None) -> dict[str, Any]:
    """Check a request body (header frame plus buffers) and resolve its arrays.

    Parameters
    ----------
    body : list of bytes-like
        The frames after the routing envelope.
    limits : Limits, optional

    Returns
    -------
    dict
        The header, ``{"$array": i}`` replaced by read-only arrays.

    Raises
    ------
    MessageError
        With the error code of ``docs/protocol.md`` section 1.3.  Its ``partial``
        attribute holds the ``id``/``type`` read so far (for the error reply).
    """
    limits = limits or Limits()
    _check_frame_count(body, limits)
    header = _header(body[0], limits)
    partial = {"id": check_id(header.get("id"), limits), "type": _readable_type(header)}
    try:
        _check_request(header, body, limits)
        arrays = wire.decode_arrays(header.pop("arrays", None), body[1:], limits.max_array_bytes)
        return wire.resolve(header, arrays)
    except MessageError as exc:
        exc.partial = partial  # type: ignore[attr-defined]
        raise


def reply(
    envelope: list[bytes],
    request_id: Any,
    msg_type: str | None,
    fields: dict[str, Any] | None = None,
    arrays: list[np.ndarray] | None = None,
    names: list[str] | None = None,
) -> list[Any]:
    """Frames of a success reply (envelope, header, buffers)."""
    header = {"v": VERSION, "id": request_id, "type": msg_type, "ok": True, **(fields or {})}
    return [*envelope, *wire.encode(header, arrays or [], names)]


def error_reply(
    envelope: list[bytes],
    request_id: Any,
    msg_type: str | None,
    code: str,
    message: str,
    extra: dict[str, Any] | None = None,
) -> list[Any]:
    """Frames of an error reply (``extra``: more header keys, e.g. ``warmup``)."""
    header = {
        **(extra or {}),
        "v": VERSION,
        "id": request_id,
        "type": msg_type,
        "ok": False,
        "error": {"code": code, "message": message[:4096]},
    }
    return [*envelope, *wire.encode(header, [])]


def request(msg_type: str, request_id: Any, fields: dict[str, Any] | None = None) -> list[Any]:
    """Frames of a request (empty delimiter, header, buffers) for a DEALER.

    ndarrays anywhere in ``fields`` travel as buffers (``$array`` references).
    """
    body, arrays = wire.extract(fields or {})
    header = {"v": VERSION, "type": msg_type, "id": request_id, **body}
    return [b"", *wire.encode(header, arrays)]


def check_request_size(frames: list[Any], limits: Limits | None = None) -> None:
    """Raise ``MessageError("too_large")`` when request frames break a size cap.

    ``frames`` as :func:`request` makes them (empty delimiter, header, buffers).
    Clients call it before sending, so a request the service would refuse (or
    libzmq would drop with the connection, past ``ZMQ_MAXMSGSIZE``) never leaves.
    """
    limits = limits or DEFAULT_LIMITS
    body = frames[1:] if frames and len(frames[0]) == 0 else frames
    sizes = [memoryview(f).nbytes for f in body]
    if len(body) > limits.max_frames - 1:  # max_frames counts the empty delimiter
        raise MessageError("too_large", f"{len(body) + 1} frames (max {limits.max_frames})")
    if sizes and sizes[0] > limits.max_header_bytes:
        raise MessageError(
            "too_large", f"header has {sizes[0]} bytes (max {limits.max_header_bytes})"
        )
    for i, n in enumerate(sizes[1:]):
        if n > limits.max_array_bytes:
            raise MessageError(
                "too_large", f"arrays[{i}] has {n} bytes (max {limits.max_array_bytes})"
            )
    if sum(sizes) > limits.max_request_bytes:
        raise MessageError(
            "too_large", f"request has {sum(sizes)} bytes (max {limits.max_request_bytes})"
        )


def parse_reply(frames: list[Any]) -> dict[str, Any]:
    """A reply's header with arrays resolved (``[b"", header, *buffers]`` or without b"").

    Raises
    ------
    MessageError
        When the reply itself breaks the protocol.
    """
    body = frames[1:] if frames and len(frames[0]) == 0 else frames
    if not body:
        raise MessageError("bad_frames", "empty reply")
    header = _header(body[0], DEFAULT_LIMITS)
    descs = header.pop("arrays", None)
    arrays = wire.decode_arrays(descs, body[1:], DEFAULT_LIMITS.max_message_bytes, max_dims=8)
    names = [d.get("name") for d in descs or []]  # decode_arrays checked: a list of dicts
    if names and all(isinstance(n, str) for n in names):
        header["arrays"] = dict(zip(names, arrays, strict=True))
    elif arrays:
        header["arrays"] = arrays
    return header


#: Frame stream topics (``docs/protocol.md`` 2): the first frame of each message.
STREAM_KINDS = ("frame", "hb")
#: Frame header keys that must be integers when present: (key, least value, required
#: in a ``frame``).  ``scene`` is absent in services older than it.
FRAME_INTS = (("seq", 0, True), ("render_id", -1, True), ("since_render", 0, False),
              ("scene", 0, False), ("refresh", 0, False), ("t_ns", 0, False),
              ("order", 0, False))


def _frame_int(header: dict[str, Any], key: str, least: int, required: bool) -> None:
    if key not in header:
        if required and header.get("kind") == "frame":
            raise MessageError("bad_message", f"frame header: {key} missing")
        return
    v = header[key]
    if isinstance(v, bool) or not isinstance(v, int) or v < least:
        raise MessageError(
            "bad_message", f"frame header: {key} must be an integer >= {least}, got {v!r:.40}"
        )


def _stream_header(frames: list[Any]) -> tuple[str, dict[str, Any]]:
    """The topic (``frame`` or ``hb``) and the parsed JSON header of a stream message."""
    if len(frames) < 2:
        raise MessageError("bad_frames", f"a stream message needs a topic and a header, "
                           f"got {len(frames)} frame(s)")
    topic = bytes(frames[0])
    if topic.decode("ascii", "replace") not in STREAM_KINDS:
        raise MessageError("bad_frames", f"unknown topic {topic[:16]!r} (frame or hb)")
    try:
        header = _header(frames[1], DEFAULT_LIMITS)
    except MessageError as exc:
        raise MessageError(exc.code, f"{topic.decode()} header: {exc.message} "
                           "(torn or cut short?)") from exc
    return topic.decode(), header


def _check_frame_header(header: dict[str, Any], topic: str) -> None:
    """Raise unless a stream header is well formed.

    It needs a known ``v``, its topic's ``kind``, a ``session`` string and the
    integers of :data:`FRAME_INTS`.
    """
    v = header.get("v")
    if isinstance(v, bool) or v not in SUPPORTED_VERSIONS:
        raise MessageError("bad_version", f"frame header: v must be one of "
                           f"{list(SUPPORTED_VERSIONS)}, got {v!r:.40}")
    if header.get("kind") != topic:
        raise MessageError("bad_message", f"frame header: kind {header.get('kind')!r:.40} "
                           f"under topic {topic!r}")
    if not isinstance(header.get("session"), str):
        raise MessageError("bad_message", "frame header: session must be a string")
    for key, least, required in FRAME_INTS:
        _frame_int(header, key, least, required)


def parse_frame(frames: list[Any]) -> dict[str, Any]:
    """A frame stream message (topic, header, buffers): its checked header, arrays by name.

    Parameters
    ----------
    frames : list of bytes-like
        ``[topic, header JSON, *buffers]`` as a SUB socket receives them.

    Returns
    -------
    dict
        The header; a frame's arrays are under ``arrays`` as ``{name: ndarray}``.

    Raises
    ------
    MessageError
        With a message saying what is wrong: ``bad_frames`` (no header, an unknown
        topic, buffers not matching ``arrays``), ``bad_json`` (not JSON: a torn or
        cut-short header), ``bad_version``, ``bad_message`` (a key missing or of the
        wrong type: ``session``, ``seq``, ``render_id``, ``scene``...), ``bad_array``.
    """
    topic, header = _stream_header(frames)
    _check_frame_header(header, topic)
    descs = header.pop("arrays", None)
    arrays = wire.decode_arrays(descs, frames[2:], DEFAULT_LIMITS.max_message_bytes)
    names = [d.get("name") for d in descs or []]  # decode_arrays checked: a list of dicts
    if len(names) != len(arrays) or not all(isinstance(n, str) for n in names):
        raise MessageError("bad_message", "frame header: every array needs a name")
    if header["kind"] == "frame":
        header["arrays"] = dict(zip(names, arrays, strict=True))
    return header
