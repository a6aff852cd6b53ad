"""Device events on a ZeroMQ publisher socket (message layout: ``docs/device-messages.md``).

Every message is two frames, a topic and a JSON object (UTF-8; never Python object serialisation):

=============  ===================================================================
``b"pose"``    a tracker pose: the dump fields plus ``t_ns``, ``n`` and ``session``;
               a latest-value stream (each pose is complete; dropping any is
               harmless)
``b"dials"``   a dial turn or button press/release (``kind`` ``dial``/``button``),
               a reset of the state to zero after the box was (re)initialised
               (``kind`` ``reset``; these three bump ``seq``) or a snapshot (``kind``
               ``state``; same ``seq``); a lossless stream with the sequence number
               ``seq`` and the absolute state (``dials``: 8 ints, ``buttons``: 32
               bools) in every message
``b"status"``  link status (the dump's status events)
``b"stats"``   reader statistics, once a second
=============  ===================================================================

The socket is an XPUB: each new subscription makes the publisher send a ``state``
snapshot at once (ZeroMQ's "last value cache" pattern), and a snapshot also goes out
every ``snapshot_s`` seconds, so a subscriber that joins late knows the absolute
dial and button state without waiting for the next turn.

ZeroMQ's ``CONFLATE`` option does not work with multipart messages, so a subscriber
that wants libzmq to keep only the newest pose connects to the optional pose-only
endpoint (``pose_address``): a PUB socket sending single-frame pose JSON with
``CONFLATE`` set on the sending side too.

A :class:`Publisher` is thread-safe: one lock serialises its sockets, so the readers
publish on their own threads (:meth:`Publisher.sink`, no hand-off to another thread
between a byte's arrival and its event's send) while the hub's consumer thread calls
:meth:`Publisher.service`.
"""

from __future__ import annotations

import json
import math
import secrets
import threading
import time
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import zmq

from drivers.events import (
    DEFAULT_COUNTS_PER_TURN,
    NS_PER_S,
    ButtonEvent,
    DialEvent,
    Event,
    PoseEvent,
    StatusEvent,
)
from drivers.protocols.sgi_dialbox import NUM_BUTTONS, NUM_DIALS
from service.base.addresses import check_endpoint
from service.base.errors import DeviceError, SettingsError

if TYPE_CHECKING:
    from drivers.reader import Item, Sink

#: event kind -> topic frame.
TOPICS = {"pose": b"pose", "dial": b"dials", "button": b"dials", "status": b"status"}
STATS_TOPIC = b"stats"
#: Send high-water mark (messages queued per subscriber before PUB drops).
SNDHWM = 100_000
LINGER_MS = 500


#: One compact encoder for every message (json.dumps would build one per call).
_ENCODER = json.JSONEncoder(separators=(",", ":"))


def _dumps(obj: Mapping[str, Any]) -> bytes:
    return _ENCODER.encode(obj).encode()


def pose_json(ev: PoseEvent, t0_ns: int, session: str, n: int) -> bytes | None:
    """The pose message body, formatted directly; None when only ``json`` can write it.

    Byte for byte what ``json`` writes for the envelope (the dump fields in the dump's
    order, then ``t_ns``, ``session``, ``n``): finite floats in ``repr`` form, ints as
    digits.  About half the CPU time of building the dict and encoding it, which
    matters on the path from a byte's arrival to its pose's send.  Values that are
    not plain finite floats / ints (NaN, numpy scalars) or a session name that would
    need escaping return None; the caller then uses the ``json`` path.
    """
    vals = (ev.yaw, ev.pitch, ev.roll, ev.x, ev.y, ev.z, *(ev.quat or ()))
    extra = ev.device_t_us
    if (any(type(v) is not float or not math.isfinite(v) for v in vals)
            or type(ev.seq) is not int or not (extra is None or type(extra) is int)
            or type(ev.t_ns) is not int or (ev.quat is not None and len(ev.quat) != 4)
            or not (session.isascii() and session.isalnum())):
        return None
    r = float.__repr__
    parts = [f'{{"t":{r((ev.t_ns - t0_ns) / NS_PER_S)},"device":"tracker","kind":"pose",'
             f'"yaw":{r(vals[0])},"pitch":{r(vals[1])},"roll":{r(vals[2])},'
             f'"x":{r(vals[3])},"y":{r(vals[4])},"z":{r(vals[5])},"seq":{ev.seq}']
    if ev.quat is not None:
        parts.append(f',"quat":[{r(vals[6])},{r(vals[7])},{r(vals[8])},{r(vals[9])}]')
    if extra is not None:
        parts.append(f',"device_t_us":{extra}')
    parts.append(f',"t_ns":{ev.t_ns},"session":"{session}","n":{n}}}')
    return "".join(parts).encode()


class DialState:
    """Absolute dial values and button states, with the stream's sequence number."""

    def __init__(self) -> None:
        self.seq = 0
        self.dials = [0] * NUM_DIALS
        self.buttons = [False] * NUM_BUTTONS
        self._apply: dict[type, Callable[[Any], bool]] = {
            DialEvent: self._dial, ButtonEvent: self._button, StatusEvent: self._status,
            PoseEvent: lambda ev: False}

    def apply(self, event: Event) -> bool:
        """Update from ``event``; True when the state changed (``seq`` was bumped)."""
        changed = self._apply[type(event)](event)
        self.seq += int(changed)
        return changed

    def snapshot(self) -> dict[str, Any]:
        """``seq``, ``dials``, ``buttons`` as JSON-able values."""
        return {"seq": self.seq, "dials": list(self.dials), "buttons": list(self.buttons)}

    def _dial(self, ev: DialEvent) -> bool:
        self.dials[ev.index] = ev.value
        return True

    def _button(self, ev: ButtonEvent) -> bool:
        self.buttons[ev.index] = ev.pressed
        return True

    def _status(self, ev: StatusEvent) -> bool:
        if ev.device != "dials" or not ev.details.get("decoder_reset"):
            return False
        self.dials = [0] * NUM_DIALS
        self.buttons = [False] * NUM_BUTTONS
        return True


class Publisher:
    """Publishes events (see the module docstring).

    Parameters
    ----------
    address : str
        Where to bind, e.g. ``tcp://127.0.0.1:5560`` (``tcp://127.0.0.1:0`` or
        ``:*`` picks a free port; :attr:`address` then holds the real one).
    t0_ns : int
        Session start; messages' ``t`` is seconds since it (as in the dump).
    pose_address : str or None
        Also bind a pose-only, single-frame, conflating PUB socket here.
    snapshot_s : float
        Period of the ``state`` snapshots and ``stats`` messages.
    context : zmq.Context or None
        Defaults to the process-wide instance.
    clock_ns : callable
        For the snapshot period.
    counts_per_turn : int
        Dial counts per turn, for the ``turns`` key of ``dial`` messages.

    Raises
    ------
    DeviceError
        The address cannot be bound.
    SettingsError
        ``counts_per_turn`` is not positive, or an address is malformed
        (:func:`service.base.addresses.check_endpoint`: a port outside 1-65535...).
    """

    def __init__(self, address: str, t0_ns: int = 0, *, pose_address: str | None = None,
                 snapshot_s: float = 1.0, context: zmq.Context | None = None,
                 clock_ns: Callable[[], int] = time.monotonic_ns,
                 counts_per_turn: int = DEFAULT_COUNTS_PER_TURN) -> None:
        if counts_per_turn <= 0:
            raise SettingsError(f"counts_per_turn must be > 0, not {counts_per_turn}")
        self.t0_ns = t0_ns
        self.counts_per_turn = counts_per_turn
        self.session = secrets.token_hex(4)
        self.state = DialState()
        self.snapshot_s = snapshot_s
        self.counts = {"pose": 0, "status": 0, "stats": 0}
        self._clock = clock_ns
        self._last_snapshot = clock_ns()
        self._lock = threading.Lock()
        for where in (address, pose_address or "inproc://none"):
            check_endpoint(where, bind=True)  # libzmq would bind port 99999 mod 65536
        ctx = context or zmq.Context.instance()
        self._sock = self._bind(ctx, zmq.XPUB, address, {zmq.XPUB_VERBOSE: 1})
        self.address = self._sock.getsockopt_string(zmq.LAST_ENDPOINT)
        self._pose_sock = None
        self.pose_address: str | None = None
        if pose_address:
            try:
                self._pose_sock = self._bind(ctx, zmq.PUB, pose_address, {zmq.CONFLATE: 1})
            except DeviceError:
                self._sock.close(0)
                raise
            self.pose_address = self._pose_sock.getsockopt_string(zmq.LAST_ENDPOINT)
        self._send_kind = {"pose": self._pose, "dial": self._dials, "button": self._dials,
                           "status": self._status}

    def _bind(self, ctx: zmq.Context, kind: int, address: str,
              options: Mapping[int, int]) -> zmq.Socket:
        sock = ctx.socket(kind)
        sock.setsockopt(zmq.LINGER, LINGER_MS)
        sock.setsockopt(zmq.SNDHWM, SNDHWM)
        for opt, value in options.items():
            sock.setsockopt(opt, value)
        try:
            sock.bind(address)
        except zmq.ZMQError as exc:
            sock.close(0)
            raise DeviceError(f"cannot bind publisher to {address!r}: {exc}") from exc
        return sock

    def _envelope(self, ev: Event) -> dict[str, Any]:
        d = ev.to_dict(self.t0_ns, self.counts_per_turn)
        d["t_ns"] = ev.t_ns
        d["session"] = self.session
        return d

    def publish(self, event: Event) -> None:
        """Publish one event on its topic (any thread)."""
        with self._lock:
            self._send_kind[event.kind](event)

    def publish_all(self, events: list[Event]) -> None:
        """Publish events in order (any thread; the batch is not interleaved)."""
        with self._lock:
            for ev in events:
                self._send_kind[ev.kind](ev)

    def sink(self, then: Sink | None = None) -> Sink:
        """A reader sink that publishes an item's events at once, then calls ``then``.

        Give it to a :class:`~drivers.reader.DeviceReader` so events go out on the
        reader's thread the moment they are decoded, with ``then`` (usually
        :meth:`~drivers.reader.EventHub.put`) passing the item on to the slower
        listeners (recorder, dump).

        Parameters
        ----------
        then : callable (item, events) -> None, optional
            Called after the events were sent.

        Returns
        -------
        callable (item, events) -> None
        """
        publish_all = self.publish_all

        def sink(item: Item, events: list[Event]) -> None:
            if events:
                publish_all(events)
            if then is not None:
                then(item, events)

        return sink

    def _pose(self, ev: PoseEvent) -> None:
        n = self.counts["pose"] = self.counts["pose"] + 1
        body = pose_json(ev, self.t0_ns, self.session, n)
        if body is None:
            d = self._envelope(ev)
            d["n"] = n
            body = _dumps(d)
        sock = self._sock
        sock.send(b"pose", zmq.SNDMORE)
        sock.send(body)
        if self._pose_sock is not None:
            self._pose_sock.send(body)

    def _dials(self, ev: DialEvent | ButtonEvent) -> None:
        self.state.apply(ev)
        d = self._envelope(ev)
        d.update(self.state.snapshot())
        self._sock.send_multipart((b"dials", _dumps(d)))

    def _status(self, ev: StatusEvent) -> None:
        self.counts["status"] += 1
        d = self._envelope(ev)
        d["n"] = self.counts["status"]
        self._sock.send_multipart((b"status", _dumps(d)))
        if self.state.apply(ev):
            self._send_state("reset", ev.t_ns, {"reason": ev.event})

    def publish_state(self) -> None:
        """Send a ``state`` snapshot on ``b"dials"`` (seq unchanged; any thread)."""
        with self._lock:
            self._snapshot()

    def _snapshot(self) -> None:
        now = self._clock()
        self._send_state("state", now)
        self._last_snapshot = now

    def _send_state(self, kind: str, t_ns: int, extra: Mapping[str, Any] | None = None) -> None:
        d = {"t": (t_ns - self.t0_ns) / 1e9, "t_ns": t_ns, "device": "dials", "kind": kind,
             "session": self.session, **(extra or {})}
        d.update(self.state.snapshot())
        self._sock.send_multipart((b"dials", _dumps(d)))

    def publish_stats(self, stats: Mapping[str, Any]) -> None:
        """Send reader statistics on ``b"stats"`` (``devices``: name -> counters)."""
        with self._lock:
            self._stats(stats)

    def _stats(self, stats: Mapping[str, Any]) -> None:
        self.counts["stats"] += 1
        now = self._clock()
        d = {"t": (now - self.t0_ns) / 1e9, "t_ns": now, "kind": "stats",
             "session": self.session, "n": self.counts["stats"], "devices": dict(stats)}
        self._sock.send_multipart((STATS_TOPIC, _dumps(d)))

    def service(self, stats: Callable[[], Mapping[str, Any]] | None = None) -> int:
        """Answer new subscriptions with a snapshot; send the periodic snapshot/stats.

        Call it often from one thread (the hub's consumer; it never blocks, and holds
        the lock only while it touches the socket).  Returns the number of
        subscription messages seen.
        """
        due = self._clock() - self._last_snapshot >= self.snapshot_s * 1e9
        figures = stats() if due and stats is not None else None
        seen = 0
        with self._lock:
            while True:
                try:
                    msg = self._sock.recv(zmq.NOBLOCK)
                except zmq.Again:
                    break
                seen += bool(msg[:1] == b"\x01")
            if seen or due:
                self._snapshot()
            if figures is not None:
                self._stats(figures)
        return seen

    def close(self) -> None:
        """Close the sockets (pending messages get ``LINGER_MS`` to go out)."""
        with self._lock:
            for sock in (self._sock, self._pose_sock):
                if sock is not None and not sock.closed:
                    sock.close()

    def __enter__(self) -> Publisher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
