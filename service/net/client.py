"""Client library of the render service (``docs/protocol.md``): control and frame stream.

::

    from service.net.client import ServiceClient, FrameSubscriber

    with ServiceClient("tcp://127.0.0.1:5555") as svc:
        info = svc.hello()                       # version, session, frames address...
        svc.load_scene(builtin="game")
        svc.update_objects([{"name": "player", "position": [0.1, -0.5, 0.1]}])
        svc.set_display(zones=5, cols=160, rows=120, refresh_hz=60)
        header, arrays = svc.render_once()       # arrays["colour"] (Z, R, C, 3) uint8
    with FrameSubscriber(info["frames"]) as frames:
        got = frames.next(timeout_s=1.0)         # (header, {"colour": ..., ...}) or None

Every call has a deadline.  A request that gets no reply within ``timeout_s`` is
resent on a fresh socket (the ZeroMQ guide's *Lazy Pirate*), up to ``retries``
times, then :class:`~service.base.errors.ServiceUnavailableError` is raised; an error
reply raises :class:`~service.base.errors.ServiceError` with the protocol's code.  A
new ``session`` in a reply to :meth:`ServiceClient.hello` (or in frame headers)
means the service restarted: ``restarted`` is set so the caller can load its
scene again.  A service still warming up (compiling its kernels) answers with
``status: "warming_up"`` and its progress; a request it cannot serve yet raises
:class:`WarmingUpError`, and :meth:`ServiceClient.wait_ready` waits for it.  JSON
and raw buffers only, never Python object serialisation.
"""

from __future__ import annotations

import itertools
import secrets
import time
from pathlib import Path
from typing import Any

import numpy as np
import zmq
import zmq.auth

from service.base.errors import MessageError, ServiceError, ServiceUnavailableError
from service.net import protocol, wire
from service.net.frame_stream import SOCKET_BUFFER
from service.render.scene import Scene, SceneObject

LINGER_MS = 0


class RequestTooLargeError(ServiceError):
    """A request breaks a size cap of the service; it was not sent.

    Raised before sending, so a request the service would refuse, or one past
    ``ZMQ_MAXMSGSIZE`` that libzmq would answer by dropping the connection, never
    leaves the client.  Its ``code`` is ``too_large``.
    """


class WarmingUpError(ServiceError):
    """The service is still warming up (code ``warming_up``); retry when it is ready.

    Attributes
    ----------
    warmup : dict
        Its progress: ``phase``, ``done``, ``total``, ``step``, ``elapsed_s``
        (``docs/protocol.md`` 1.8).
    """

    def __init__(self, message: str, warmup: dict[str, Any] | None = None) -> None:
        super().__init__("warming_up", message)
        self.warmup = warmup or {}


def _curve_client(sock: zmq.Socket, keys_dir: str | Path | None) -> None:
    """Make ``sock`` a CURVE client with the keys of ``holo-service-keys DIR``."""
    if keys_dir is None:
        return
    d = Path(keys_dir)
    server_public, _ = zmq.auth.load_certificate(d / "server.key")
    public, secret = zmq.auth.load_certificate(d / "client.key_secret")
    sock.curve_serverkey = server_public
    sock.curve_publickey = public
    sock.curve_secretkey = secret


def _dealer(
    ctx: zmq.Context, address: str, curve_keys: str | Path | None, linger_ms: int,
    heartbeat: bool = False,
) -> zmq.Socket:
    """A DEALER connected to the service's control ``address`` (ZMTP heartbeats optional)."""
    sock = ctx.socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, linger_ms)
    if heartbeat:
        sock.setsockopt(zmq.HEARTBEAT_IVL, int(protocol.HEARTBEAT_S * 1000))
        sock.setsockopt(
            zmq.HEARTBEAT_TIMEOUT, int(protocol.HEARTBEAT_S * protocol.HEARTBEAT_LIVENESS * 1000)
        )
    _curve_client(sock, curve_keys)
    sock.connect(address)
    return sock


def _next_reply(sock: zmq.Socket) -> dict[str, Any] | None:
    """The reply waiting on ``sock`` (a poll said one is there); None when it is garbled."""
    frames = sock.recv_multipart(copy=False)
    try:
        return protocol.parse_reply([f.buffer for f in frames])
    except MessageError:
        return None


class ServiceClient:
    """Request/reply client of the control channel (DEALER, Lazy Pirate retries).

    Parameters
    ----------
    address : str
        The service's control address.
    timeout_s : float
        Reply deadline per attempt.
    retries : int
        Resends after the first attempt before giving up.
    curve_keys : str or Path, optional
        Directory made by ``holo-service-keys`` (CurveZMQ).
    context : zmq.Context, optional
    """

    def __init__(
        self,
        address: str = "tcp://127.0.0.1:5555",
        timeout_s: float = 2.5,
        retries: int = 3,
        curve_keys: str | Path | None = None,
        context: zmq.Context | None = None,
    ) -> None:
        self.address = address
        self.timeout_s = float(timeout_s)
        self.retries = int(retries)
        self.curve_keys = curve_keys
        self._ctx = context or zmq.Context.instance()
        self._ids = itertools.count(1)
        self._sock: zmq.Socket | None = None
        self.session: str | None = None
        self.restarted = False
        self.reconnects = 0
        self.last_reply_t = 0.0
        #: random per client; with the request ``id`` it lets the service answer a
        #: resend from its reply cache instead of applying the request twice.
        self.client_id = secrets.token_hex(8)
        #: the service's size caps (from ``hello``; version 1 defaults before it).
        self.limits = protocol.DEFAULT_LIMITS

    # ------------------------------------------------------------ transport
    def _open(self) -> zmq.Socket:
        return _dealer(self._ctx, self.address, self.curve_keys, LINGER_MS, heartbeat=True)

    def _reset(self) -> None:
        if self._sock is not None:
            self._sock.close(LINGER_MS)
        self._sock = None

    def request(self, msg_type: str, **fields: Any) -> dict[str, Any]:
        """Send one request and return its reply header (arrays resolved).

        Raises
        ------
        ServiceError
            On an error reply.
        ServiceUnavailableError
            When no reply came within ``timeout_s`` after every retry.
        RequestTooLargeError
            When the request breaks a size cap (nothing is sent).
        """
        rid = next(self._ids)
        frames = protocol.request(msg_type, rid, {**fields, "client_id": self.client_id})
        try:
            protocol.check_request_size(frames, self.limits)
        except MessageError as exc:
            raise RequestTooLargeError(exc.code, f"{msg_type}: {exc.message}; not sent") from exc
        for _attempt in range(self.retries + 1):
            if self._sock is None:
                self._sock = self._open()
            if wire.send(self._sock, frames, int(self.timeout_s * 1000)):
                got = self._await(rid)
                if got is not None:
                    return self._check(got)
            self._reset()  # Lazy Pirate: a fresh socket, then resend
            self.reconnects += 1
        raise ServiceUnavailableError(
            f"no reply from {self.address} to {msg_type!r} after "
            f"{self.retries + 1} attempts of {self.timeout_s} s"
        )

    def _await(self, rid: int) -> dict[str, Any] | None:
        deadline = time.monotonic() + self.timeout_s
        while (left := deadline - time.monotonic()) > 0:
            if not self._sock.poll(max(1, int(left * 1000))):
                return None
            header = _next_reply(self._sock)
            if header is not None and header.get("id") == rid:
                self.last_reply_t = time.monotonic()
                return header
        return None

    @staticmethod
    def _check(header: dict[str, Any]) -> dict[str, Any]:
        if not header.get("ok"):
            err = header.get("error") or {}
            code, message = str(err.get("code", "internal")), str(err.get("message", ""))
            if code == "warming_up":
                raise WarmingUpError(message, header.get("warmup"))
            raise ServiceError(code, message)
        return header

    # ----------------------------------------------------------- messages
    def hello(self, name: str = "client") -> dict[str, Any]:
        """Negotiate the version; notes a service restart (new ``session``)."""
        got = self.request("hello", versions=list(protocol.SUPPORTED_VERSIONS), client=name)
        if self.session is not None and got["session"] != self.session:
            self.restarted = True
        self.session = got["session"]
        if isinstance(got.get("limits"), dict):
            self.limits = protocol.Limits.from_dict(got["limits"])
        return got

    def wait_ready(
        self, timeout_s: float, progress: Any = None, poll_s: float = 0.25
    ) -> dict[str, Any]:
        """``hello`` until the service says ``status: ready``; returns that reply.

        Parameters
        ----------
        timeout_s : float
            Give up after this long (a first start compiles for minutes on a slow machine).
        progress : callable, optional
            Called with each warming-up reply's ``warmup`` progress.
        poll_s : float
            Seconds between ``hello`` requests.

        Raises
        ------
        WarmingUpError
            Still warming up after ``timeout_s``.
        ServiceUnavailableError
            No reply at all.
        """
        deadline = time.monotonic() + timeout_s
        while True:
            got = self.hello()
            if got.get("status", "ready") == "ready":
                return got
            if progress is not None:
                progress(got.get("warmup") or {})
            if time.monotonic() + poll_s > deadline:
                raise WarmingUpError(f"{self.address} still warming up after {timeout_s} s",
                                     got.get("warmup"))
            time.sleep(poll_s)

    def ping(self) -> dict[str, Any]:
        """One heartbeat round trip."""
        return self.request("ping")

    def heartbeat(self) -> bool:
        """Ping when idle for a heartbeat interval; False when the service is gone."""
        if time.monotonic() - self.last_reply_t < protocol.HEARTBEAT_S:
            return True
        try:
            self.ping()
        except ServiceUnavailableError:
            return False
        return True

    def load_scene(
        self, builtin: str | None = None, path: str | None = None, scene: Scene | dict | None = None
    ) -> dict[str, Any]:
        """Load a built-in scene, a file the service reads, or an inline scene."""
        if isinstance(scene, Scene):
            scene = wire.scene_to_wire(scene)
        fields = {
            k: v
            for k, v in (("builtin", builtin), ("path", path), ("scene", scene))
            if v is not None
        }
        return self.request("load_scene", **fields)

    def load_object(
        self,
        obj: SceneObject | dict | None = None,
        path: str | None = None,
        name: str | None = None,
    ) -> int:
        """Add one object (inline or from a file); returns its index."""
        if isinstance(obj, SceneObject):
            obj = wire.scene_to_wire(Scene([obj]))["objects"][0]
        fields: dict[str, Any] = {"object": obj} if obj is not None else {"path": path}
        if name is not None:
            fields["name"] = name
        return int(self.request("load_object", **fields)["index"])

    def update_objects(self, updates: list[dict[str, Any]]) -> int:
        """Batched object updates (``index`` or ``name`` plus pose/motion fields)."""
        clean = [
            {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in u.items()}
            for u in updates
        ]
        return int(self.request("update_objects", objects=clean)["updated"])

    def set_viewer(self, **fields: Any) -> dict[str, Any]:
        """Viewer pose/motion fields, or ``devices=ADDR`` (``None`` to stop)."""
        return self.request("set_viewer", **fields)

    def set_display(self, **settings: Any) -> dict[str, Any]:
        """Display, render and stream settings; returns all settings in force."""
        return self.request("set_display", **settings)["display"]

    def render_once(
        self, encodings: list[str] | None = None
    ) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        """Render now; returns (reply header, arrays by name)."""
        fields = {} if encodings is None else {"encodings": encodings}
        header = self.request("render", **fields)
        return header, header.pop("arrays", {})

    def stats(self) -> dict[str, Any]:
        """The service's counters."""
        return self.request("stats")["stats"]

    def shutdown(self) -> None:
        """Ask the service to stop (one attempt: a retry could stop a restarted one)."""
        retries, self.retries = self.retries, 0
        try:
            self.request("shutdown")
        finally:
            self.retries = retries

    def close(self) -> None:
        """Close the socket (LINGER 0)."""
        self._reset()

    def __enter__(self) -> ServiceClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class PendingRequest:
    """One request at a time whose reply is picked up later, never waited for.

    For a loop that must not stall (the game's tick): :meth:`send` sends and returns
    at once, :meth:`poll` looks for the reply with a zero timeout.  It has its own
    DEALER socket, so a reply that comes late never lands in
    :class:`ServiceClient`'s socket, and one that never comes is dropped after
    ``timeout_s`` (the socket is closed, LINGER 0; a later :meth:`send` opens a new
    one).  No retries: the caller asks again when it next wants to.

    Parameters
    ----------
    address : str
        The service's control address.
    timeout_s : float
        How long a reply may take before it is dropped.
    curve_keys : str or Path, optional
    context : zmq.Context, optional
    """

    def __init__(
        self,
        address: str,
        timeout_s: float = 5.0,
        curve_keys: str | Path | None = None,
        context: zmq.Context | None = None,
    ) -> None:
        self.address = address
        self.timeout_s = float(timeout_s)
        self.curve_keys = curve_keys
        self._ctx = context or zmq.Context.instance()
        self._ids = itertools.count(1)
        self._sock: zmq.Socket | None = None
        self._waiting: tuple[int, float] | None = None  # (request id, deadline)
        self.sent = self.answered = self.dropped = 0

    @property
    def waiting(self) -> bool:
        """Whether a request is out and its reply neither taken nor dropped yet."""
        return self._waiting is not None

    def send(self, msg_type: str, **fields: Any) -> bool:
        """Send a request without waiting; False (nothing sent) while one is waiting.

        Also False when the socket cannot take it at once (the reply is then not
        waited for either).

        Raises
        ------
        RequestTooLargeError
            When the request breaks the protocol's default size caps (nothing is
            sent), as :meth:`ServiceClient.request` checks them.
        """
        if self._waiting is not None:
            return False
        rid = next(self._ids)
        frames = protocol.request(msg_type, rid, fields)
        try:
            protocol.check_request_size(frames)
        except MessageError as exc:
            raise RequestTooLargeError(exc.code, f"{msg_type}: {exc.message}; not sent") from exc
        if self._sock is None:
            self._sock = _dealer(self._ctx, self.address, self.curve_keys, 0)
        if not wire.send(self._sock, frames, timeout_ms=0):
            return False
        self._waiting = (rid, time.monotonic() + self.timeout_s)
        self.sent += 1
        return True

    def poll(self) -> dict[str, Any] | None:
        """The reply's header if it has come (zero timeout), else None.

        A reply past ``timeout_s`` is dropped (``dropped`` counts it) and the socket
        closed, so a later :meth:`send` starts afresh.

        Raises
        ------
        ServiceError
            The reply is an error reply (the request is over either way).
        """
        if self._waiting is None:
            return None
        rid, deadline = self._waiting
        while self._sock.poll(0):
            header = _next_reply(self._sock)
            if header is not None and header.get("id") == rid:
                self._waiting = None
                self.answered += 1
                return ServiceClient._check(header)
        if time.monotonic() > deadline:
            self.dropped += 1
            self.close()
        return None

    def close(self) -> None:
        """Close the socket (LINGER 0); a waiting reply is forgotten."""
        if self._sock is not None:
            self._sock.close(0)
        self._sock, self._waiting = None, None


class FrameSubscriber:
    """Subscriber of the frame stream (SUB, small RCVHWM, reconnects when silent).

    Parameters
    ----------
    address : str
        The service's frame stream address.
    hwm : int
        Receive high-water mark in messages.
    curve_keys : str or Path, optional
    context : zmq.Context, optional
        Without one the subscriber makes its own context (one I/O thread of its
        own, closed with it), so frames are not received behind other sockets'
        traffic in a shared context.
    """

    def __init__(
        self,
        address: str = "tcp://127.0.0.1:5556",
        hwm: int = 2,
        curve_keys: str | Path | None = None,
        context: zmq.Context | None = None,
    ) -> None:
        self.address = address
        self.hwm = hwm
        self.curve_keys = curve_keys
        self._own_ctx = context is None
        self._ctx = zmq.Context() if context is None else context
        self._sock = self._open()
        self.last_heard = time.monotonic()
        self.session: str | None = None
        self.restarted = False
        self.reconnects = 0
        self.frames = 0
        self.dropped = 0
        self.skipped = 0
        #: messages :func:`~service.net.protocol.parse_frame` refused, and why the last was
        self.malformed = 0
        self.last_error = ""
        #: the newest heartbeat's ``status`` (``ready`` or ``warming_up``) and progress.
        self.status: str | None = None
        self.warmup: dict[str, Any] | None = None
        self._last_seq: int | None = None

    def _open(self) -> zmq.Socket:
        sock = self._ctx.socket(zmq.SUB)
        sock.setsockopt(zmq.LINGER, LINGER_MS)
        sock.setsockopt(zmq.RCVHWM, self.hwm)
        sock.setsockopt(zmq.RCVBUF, SOCKET_BUFFER)
        sock.setsockopt(zmq.SUBSCRIBE, b"")
        _curve_client(sock, self.curve_keys)
        sock.connect(self.address)
        return sock

    @property
    def alive(self) -> bool:
        """Heard from the service (frame or heartbeat) within 3 heartbeats."""
        limit = protocol.HEARTBEAT_S * protocol.HEARTBEAT_LIVENESS
        return time.monotonic() - self.last_heard < limit

    def _reconnect(self) -> None:
        self._sock.close(LINGER_MS)
        self._sock = self._open()
        self.last_heard = time.monotonic()
        self.reconnects += 1

    def next(self, timeout_s: float = 1.0) -> tuple[dict[str, Any], dict[str, np.ndarray]] | None:
        """The next frame: (header, arrays by name), or None after ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while (left := deadline - time.monotonic()) > 0:
            if not self.alive:
                self._reconnect()
            if not self._sock.poll(max(1, min(int(left * 1000), 500))):
                continue
            got = self._take(self._sock.recv_multipart(copy=False))
            if got is not None:
                return got
        return None

    def _take(self, frames: list[zmq.Frame]) -> tuple[dict, dict] | None:
        try:
            header = protocol.parse_frame([f.buffer for f in frames])
        except MessageError as exc:  # counted, never shown: a torn header, a bad key
            self.malformed += 1
            self.last_error = f"{exc.code}: {exc.message}"
            return None
        self.last_heard = time.monotonic()
        session = header.get("session")
        if self.session is not None and session != self.session:
            self.restarted = True
            self._last_seq = None
        self.session = session
        if header.get("kind") != "frame":
            self.status, self.warmup = header.get("status"), header.get("warmup")
            return None
        self.status, self.warmup = "ready", None
        seq = int(header.get("seq", 0))
        if self._last_seq is not None and seq > self._last_seq + 1:
            self.dropped += seq - self._last_seq - 1
        self._last_seq = seq
        self.frames += 1
        return header, header.pop("arrays", {})

    def latest(self, timeout_s: float = 1.0) -> tuple[dict[str, Any], dict[str, np.ndarray]] | None:
        """The newest frame: waits like :meth:`next`, then drops any older queued frames.

        For a display that shows only the newest frame: a frame that waited in the
        receive queue behind another is never returned (counted in ``skipped``).
        """
        got = self.next(timeout_s)
        while got is not None and self._sock.poll(0):
            newer = self._take(self._sock.recv_multipart(copy=False))
            if newer is not None:
                self.skipped += 1
                got = newer
        return got

    def close(self) -> None:
        """Close the socket (LINGER 0) and the subscriber's own context."""
        self._sock.close(LINGER_MS)
        if self._own_ctx:
            self._ctx.term()

    def __enter__(self) -> FrameSubscriber:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
