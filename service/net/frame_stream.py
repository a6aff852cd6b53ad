"""The frame stream: a PUB socket with a small high-water mark (``docs/protocol.md`` 2).

Frames are a latest-value stream, so a subscriber that cannot keep up should lose
frames, not make the service queue them: the socket's ``SNDHWM`` is 2 messages per
subscriber and a frame's buffers are sent zero-copy (they stay alive only while
libzmq still holds them).  A heartbeat message goes out whenever no frame has been
published for :data:`service.net.protocol.HEARTBEAT_S`, so subscribers can tell a
quiet service from a dead one.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import zmq

from service.net import protocol, wire

SNDHWM = 2
#: kernel socket buffers of the frame stream (both ends): a whole 672 kB frame fits,
#: so a send is not paced by the receiver's window.
SOCKET_BUFFER = 4 << 20
#: the PUB socket's I/O thread (bit mask): the second of the service's two, apart
#: from the control, broker and device sockets (all on the first).
PUB_AFFINITY = 0b10


class FrameStream:
    """Publisher of frames and heartbeats.

    Parameters
    ----------
    context : zmq.Context
    address : str
        Where to bind, e.g. ``tcp://127.0.0.1:5556``.
    session : str
        The service run's id, in every header.
    secure : callable, optional
        Applied to the socket before binding (CurveZMQ server setup).
    """

    def __init__(
        self, context: zmq.Context, address: str, session: str, secure: Any = None
    ) -> None:
        self.sock = context.socket(zmq.PUB)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.setsockopt(zmq.SNDHWM, SNDHWM)
        self.sock.setsockopt(zmq.SNDTIMEO, 0)
        self.sock.setsockopt(zmq.SNDBUF, SOCKET_BUFFER)
        if context.get(zmq.IO_THREADS) > 1:
            self.sock.setsockopt(zmq.AFFINITY, PUB_AFFINITY)
        self.sock.setsockopt(zmq.HEARTBEAT_IVL, int(protocol.HEARTBEAT_S * 1000))
        self.sock.setsockopt(
            zmq.HEARTBEAT_TIMEOUT, int(protocol.HEARTBEAT_S * protocol.HEARTBEAT_LIVENESS * 1000)
        )
        if secure is not None:
            secure(self.sock)
        self.sock.bind(address)
        self.address = self.sock.getsockopt_string(zmq.LAST_ENDPOINT)
        self.session = session
        self.seq = 0
        self.published = 0
        #: more keys for heartbeat headers (the service's ``status`` and ``warmup``).
        self.extra: dict[str, Any] = {}
        self._last_send = 0.0

    def publish(self, header: dict[str, Any], arrays: list[np.ndarray], names: list[str]) -> int:
        """Publish one frame; returns its sequence number.

        Parameters
        ----------
        header : dict
            Frame fields (``docs/protocol.md`` section 2); ``v``, ``kind``,
            ``session``, ``seq`` and ``t_ns`` are added here.
        arrays : list of ndarray
            E.g. colour (Z, R, C, 3) uint8 and depth (Z, R, C) float32.
        names : list of str
            Their names.
        """
        self.seq += 1
        head = {
            "v": protocol.VERSION,
            "kind": "frame",
            "session": self.session,
            "seq": self.seq,
            "t_ns": time.monotonic_ns(),
            **header,
        }
        self._send([b"frame", *wire.encode(head, arrays, names)])
        self.published += 1
        return self.seq

    def heartbeat(self, force: bool = False) -> bool:
        """Send a heartbeat if nothing went out for half a heartbeat interval.

        Callers check at their own pace (the refresh loop: every tick, 1 s apart at
        1 Hz); half the interval as the threshold keeps the gap between messages at
        most ``HEARTBEAT_S`` plus the caller's jitter, as ``docs/protocol.md`` 1.7
        promises, where a full interval would let a tick that comes a hair early
        skip and double the gap.
        """
        if not force and time.monotonic() - self._last_send < protocol.HEARTBEAT_S / 2:
            return False
        head = {
            **self.extra,
            "v": protocol.VERSION,
            "kind": "hb",
            "session": self.session,
            "seq": self.seq,
            "t_ns": time.monotonic_ns(),
        }
        self._send([b"hb", *wire.encode(head, [])])
        return True

    def _send(self, frames: list[Any]) -> None:
        # PUB never blocks: past the HWM libzmq drops the message for that subscriber.
        wire.send(self.sock, frames, timeout_ms=0)
        self._last_send = time.monotonic()

    def close(self) -> None:
        """Close the socket (LINGER 0)."""
        self.sock.close(0)
