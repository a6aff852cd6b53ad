"""Client side of the device publisher: latest pose, dial/button state, gap detection.

Used by the render service and the game::

    with DeviceSubscriber("tcp://127.0.0.1:5556") as sub:
        pose = sub.wait_pose(timeout_s=2.0)          # None on timeout
        sub.poll()                                    # take what has arrived, never blocks
        sub.dials, sub.buttons                        # absolute state
        for ev in sub.take_events(): ...              # dial / button / status, in order

With ``pose_address`` (the publisher's ``--pub-pose`` endpoint) poses come through
a second, conflating socket, so a slow client never works through a backlog of old
poses.  Nothing here waits forever: :meth:`~DeviceSubscriber.poll` takes a timeout (0 by
default), the ``wait_*`` helpers return None / False after theirs.  Malformed
messages are counted and skipped.  Message layout: ``docs/device-messages.md``.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import zmq

from drivers.events import Event, PoseEvent, event_from_dict
from drivers.protocols.sgi_dialbox import NUM_BUTTONS, NUM_DIALS
from service.base.errors import ProtocolError

DEFAULT_TOPICS = (b"pose", b"dials", b"status")
#: Topics taken from the main socket when poses come from the pose-only endpoint.
NON_POSE_TOPICS = (b"dials", b"status")
#: A dials message's ``seq`` is below this (a 64-bit counter; larger is malformed).
SEQ_LIMIT = 1 << 63


@dataclass
class SubscriberStats:
    """What a subscriber received.

    Attributes
    ----------
    messages : int
        Messages taken off the socket.
    malformed : int
        Messages skipped because they did not follow the layout.
    gaps : int
        Places where the dials stream skipped sequence numbers.
    missing : int
        Dial/button messages missed in total (the state stays right regardless).
    stale : int
        Dials messages older than the state already held (ignored).
    sessions : int
        Publisher sessions seen (a new one means the publisher restarted).
    """

    messages: int = 0
    malformed: int = 0
    gaps: int = 0
    missing: int = 0
    stale: int = 0
    sessions: int = 0


class DeviceSubscriber:
    """Subscribe to a device publisher (see the module docstring).

    Parameters
    ----------
    address : str
        The publisher's address, e.g. ``tcp://127.0.0.1:5556``.
    topics : iterable of bytes or None
        Topics to subscribe to (default pose, dials, status; without pose when
        ``pose_address`` is given).
    pose_address : str or None
        The publisher's pose-only endpoint (``--pub-pose``): poses then come through a
        ``CONFLATE`` socket, so libzmq keeps only the newest one.
    context : zmq.Context or None
    max_events : int
        Dial/button/status events kept for :meth:`take_events` (oldest dropped).
    """

    def __init__(self, address: str, topics: Iterable[bytes] | None = None, *,
                 pose_address: str | None = None, context: zmq.Context | None = None,
                 max_events: int = 10_000) -> None:
        ctx = context or zmq.Context.instance()
        if topics is None:
            topics = DEFAULT_TOPICS if pose_address is None else NON_POSE_TOPICS
        self._sock = self._socket(ctx, address, tuple(topics), conflate=False)
        self._pose_sock = (None if pose_address is None
                           else self._socket(ctx, pose_address, (b"",), conflate=True))
        self._poller = zmq.Poller()
        for sock in (self._sock, self._pose_sock):
            if sock is not None:
                self._poller.register(sock, zmq.POLLIN)
        self.address = address
        self.stats = SubscriberStats()
        self.pose: PoseEvent | None = None
        self.pose_count = 0
        self.dials: tuple[int, ...] = (0,) * NUM_DIALS
        self.buttons: tuple[bool, ...] = (False,) * NUM_BUTTONS
        self.seq: int | None = None
        self.session: str | None = None
        self.last_stats: dict[str, Any] | None = None
        self._events: deque[Event] = deque(maxlen=max_events)
        self._handlers: dict[bytes, Callable[[dict[str, Any]], None]] = {
            b"pose": self._on_pose, b"dials": self._on_dials, b"status": self._on_status,
            b"stats": self._on_stats}

    @staticmethod
    def _socket(ctx: zmq.Context, address: str, topics: tuple[bytes, ...],
                conflate: bool) -> zmq.Socket:
        sock = ctx.socket(zmq.SUB)
        sock.setsockopt(zmq.LINGER, 0)
        if conflate:
            sock.setsockopt(zmq.CONFLATE, 1)  # before connect
        else:
            sock.setsockopt(zmq.RCVHWM, 100_000)
        for topic in topics:
            sock.setsockopt(zmq.SUBSCRIBE, topic)
        sock.connect(address)
        return sock

    @property
    def state_known(self) -> bool:
        """True once a dials message (event or snapshot) has arrived."""
        return self.seq is not None

    # -- receiving ------------------------------------------------------------------
    def poll(self, timeout_s: float = 0.0, max_messages: int = 100_000) -> int:
        """Wait up to ``timeout_s`` for a message, then take all that are waiting.

        Returns
        -------
        int
            Messages processed (0 on timeout).
        """
        if not self._poller.poll(max(0, round(timeout_s * 1000))):
            return 0
        count = self._drain(self._sock, max_messages, multipart=True)
        if self._pose_sock is not None:
            count += self._drain(self._pose_sock, max_messages, multipart=False)
        return count

    def _drain(self, sock: zmq.Socket, max_messages: int, multipart: bool) -> int:
        count = 0
        while count < max_messages:
            try:
                frames = (sock.recv_multipart(zmq.NOBLOCK) if multipart
                          else [b"pose", sock.recv(zmq.NOBLOCK)])
            except zmq.Again:
                break
            count += 1
            self._handle(frames)
        return count

    def wait_for(self, predicate: Callable[[DeviceSubscriber], bool],
                 timeout_s: float) -> bool:
        """Poll until ``predicate(self)`` is true; False after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while not predicate(self):
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            self.poll(min(left, 0.05))
        return True

    def wait_pose(self, timeout_s: float, after: int = 0) -> PoseEvent | None:
        """The latest pose once more than ``after`` poses have arrived; None on timeout.

        ``wait_pose(t)`` waits for any pose; ``wait_pose(t, after=sub.pose_count)``
        for a new one.
        """
        ok = self.wait_for(lambda s: s.pose_count > after, timeout_s)
        return self.pose if ok else None

    def take_events(self) -> list[Event]:
        """Dial, button and status events received since the last call, in order."""
        out = list(self._events)
        self._events.clear()
        return out

    # -- parsing --------------------------------------------------------------------
    def _handle(self, frames: list[bytes]) -> None:
        self.stats.messages += 1
        try:
            if len(frames) != 2:
                raise ProtocolError(f"expected 2 frames, got {len(frames)}")
            handler = self._handlers.get(bytes(frames[0]))
            if handler is None:
                raise ProtocolError(f"unknown topic {bytes(frames[0])[:32]!r}")
            msg = json.loads(frames[1])
            if not isinstance(msg, dict):
                raise ProtocolError("message body is not a JSON object")
            self._check_session(msg)
            handler(msg)
        except (ProtocolError, ValueError, KeyError, TypeError, IndexError, OverflowError):
            self.stats.malformed += 1  # OverflowError: a number of 1e400 read as inf

    @staticmethod
    def _event(msg: dict[str, Any]) -> Event:
        ev = event_from_dict(msg)
        return dataclasses.replace(ev, t_ns=int(msg["t_ns"]))

    def _check_session(self, msg: dict[str, Any]) -> None:
        session = msg.get("session")
        if session != self.session:
            self.session = session
            self.stats.sessions += 1
            self.seq = None

    def _on_pose(self, msg: dict[str, Any]) -> None:
        ev = self._event(msg)
        if not isinstance(ev, PoseEvent):
            raise ProtocolError("pose topic without a pose")
        self.pose = ev
        self.pose_count += 1

    def _on_status(self, msg: dict[str, Any]) -> None:
        self._events.append(self._event(msg))

    def _on_stats(self, msg: dict[str, Any]) -> None:
        self.last_stats = dict(msg["devices"])

    def _on_dials(self, msg: dict[str, Any]) -> None:
        seq = int(msg["seq"])
        if not 0 <= seq < SEQ_LIMIT:
            raise ProtocolError(f"dials seq {seq} outside 0..2^63")
        dials = tuple(int(v) for v in msg["dials"])
        buttons = tuple(bool(v) for v in msg["buttons"])
        if len(dials) != NUM_DIALS or len(buttons) != NUM_BUTTONS:
            raise ProtocolError("dials message with a wrong state size")
        kind = msg.get("kind")
        is_event = kind != "state"
        event = self._event(msg) if kind in ("dial", "button") else None
        if self.seq is not None:
            expected = self.seq + 1 if is_event else self.seq
            if seq < expected:
                self.stats.stale += 1
                return
            if seq > expected:
                self.stats.gaps += 1
                self.stats.missing += seq - expected
        self.seq, self.dials, self.buttons = seq, dials, buttons
        if event is not None:
            self._events.append(event)

    def close(self) -> None:
        """Close the sockets."""
        for sock in (self._sock, self._pose_sock):
            if sock is not None and not sock.closed:
                sock.close(0)

    def __enter__(self) -> DeviceSubscriber:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
