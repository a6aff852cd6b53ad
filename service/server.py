"""The render service: control ROUTER, render thread, refresh loop (``docs/service.md``).

Three loops share one :class:`State` under a lock:

* the **control loop** (the caller's thread, :meth:`Service.run`) answers requests
  on the ROUTER socket with a handler per message type (``docs/protocol.md``);
* the **render thread** renders the scene as fast as it can (or at most
  ``max_update_hz``) for a rendezvous a little in the future, in process or through
  the LRU broker to worker processes (whole frames, one in flight per worker, each
  for its own rendezvous; or bands of hololines), and builds the galpixmap; with a
  broker but no worker connected to it, it renders in process;
* the **refresh thread** ticks at the refresh rate on an absolute schedule, hands
  finished updates to the Galilean stage, takes the viewer's pose from the devices'
  stream, refreshes and publishes the frame.  It never waits for a render; a render
  that misses its rendezvous is counted (``incomplete_updates``).
"""

from __future__ import annotations

import math
import os
import queue
import secrets
import subprocess
import sys
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import zmq

from service import protocol, wire
from service.broker import BandClient, Broker, Flight, FramePipe, split_rows
from service.curve_keys import curve_server, is_local, start_authenticator
from service.display import DisplaySettings
from service.errors import HoloError, MeshFileError, MessageError, SettingsError
from service.frame_stream import FrameStream
from service.galilean import GalileanSettings, GalileanStage
from service.light import EVALUATIONS, MODELS
from service.pipeline import METHOD_NAMES, Renderer
from service.quality import MODES as QUALITY_MODES
from service.quality import QualityChooser, QualitySettings, choose, parse_budget
from service.readiness import Warmup
from service.scene import MotionState, Scene, Transform, euler_quaternion
from service.scene_motion import advance_scene
from service.signals import end_process
from service.worker import StatsRenderer, render_job, stitch

#: Frame encodings a client may subscribe to: arrays of a refresh by attribute name.
ENCODINGS = ("colour", "depth", "debris", "autostereogram")
#: SIRD methods of the ``autostereogram`` encoding (service.autostereogram).
SIRD_METHODS = ("tiw", "row", "interpolated")
DEFAULT_WORKER_ADDRESS = "tcp://127.0.0.1:5557"
#: ``set_viewer`` keys of a pose (the other form names ``devices``).
VIEWER_POSE_FIELDS = ("position", "orientation", *wire.MOTION_FIELDS)
#: the largest object index a request may name (an int64); past the scene's end: not_found.
MAX_INDEX = 2**63 - 1
#: What a warming-up service answers as usual (with its ``status``); every other
#: request gets a ``warming_up`` error (``docs/protocol.md`` 1.8).
WHILE_WARMING = frozenset({"hello", "ping", "stats", "shutdown"})


@dataclass
class ServiceConfig:
    """Command-line settings of ``holo-service`` (see :mod:`service.cli_service`)."""

    control: str = "tcp://127.0.0.1:5555"
    frames: str = "tcp://127.0.0.1:5556"
    devices: str | None = None
    workers: int = 0
    #: the broker's backend address.  ``None``: :data:`DEFAULT_WORKER_ADDRESS`, and no
    #: broker unless ``workers`` > 0.  Given, the broker starts even with no local
    #: workers, for workers on other hosts (renders run in process while none is connected).
    worker_address: str | None = None
    refresh_hz: float = 60.0
    curve_keys: str | None = None
    render_timeout_s: float = 5.0
    max_update_hz: float = 0.0
    scene: str | None = None
    display: DisplaySettings = field(
        default_factory=lambda: DisplaySettings(zones=5, cols=160, rows=120)
    )
    pose_scale: float = 0.001
    #: level-of-detail error budget in pixels (0: off); ``set_display`` can change it
    lod_error: float = 0.0
    #: directories ``path`` requests may read from (empty: any file the service can read).
    scene_dirs: tuple[str, ...] = ()
    #: with workers: ``frames`` (each worker renders whole updates for successive
    #: rendezvous, several in flight) or ``bands`` (every worker a band of each update).
    split: str = "frames"
    #: libzmq I/O threads; with 2 the frame PUB has one to itself.
    io_threads: int = 2
    #: warm up before serving (:mod:`service.readiness`): compile the kernels in a child
    #: process while answering "warming up"; False (library use, tests): ready at once,
    #: kernels compile when first used.  ``holo-service`` warms up unless ``--no-warmup``.
    warmup: bool = False


#: (field, check, what it must be) for :func:`check_config`.
_CONFIG_RULES: tuple[tuple[str, Callable[[Any], bool], str], ...] = (
    ("refresh_hz", lambda v: math.isfinite(v) and 1.0 <= v <= 240.0, "from 1 to 240 Hz"),
    ("workers", lambda v: v >= 0, ">= 0"),
    ("render_timeout_s", lambda v: math.isfinite(v) and v > 0, "> 0 seconds"),
    ("max_update_hz", lambda v: math.isfinite(v) and v >= 0, ">= 0 (0: no cap)"),
    ("io_threads", lambda v: 1 <= v <= 64, "from 1 to 64"),
    ("pose_scale", lambda v: math.isfinite(v) and v > 0, "> 0"),
    ("split", lambda v: v in ("frames", "bands"), "frames or bands"),
)


def check_config(config: ServiceConfig) -> None:
    """Check every setting before anything starts (a bad one never reaches a thread).

    Raises
    ------
    SettingsError
        Naming the first bad setting and what it must be.
    """
    for name, ok, want in _CONFIG_RULES:
        value = getattr(config, name)
        if not ok(value):
            raise SettingsError(f"{name} must be {want}, got {value!r}")
    if config.scene is not None:
        from service.builtin_scenes import canonical_scene_name

        canonical_scene_name(config.scene)
    GalileanSettings(order=2, refresh_hz=config.refresh_hz)


@dataclass(frozen=True)
class Settings:
    """What ``set_display`` changes (``generation`` counts changes)."""

    display: DisplaySettings
    method: str = "zbuffer"
    light_model: str = "blinn"
    specular: str = "polygon"
    galpixel_order: int = 2
    encodings: tuple[str, ...] = ("colour", "depth")
    refresh_hz: float = 60.0
    sird_method: str = "tiw"
    sird_eye_sep: float = 0.0
    #: level-of-detail error budget in pixels (:mod:`service.lod`); 0: off
    lod_error: float = 0.0
    generation: int = 0
    #: "auto": each render's method and specular chosen within ``max_error``
    #: (service.quality); "fixed": as set.
    quality: str = "fixed"
    max_error: str = "0.5%"

    def as_dict(self) -> dict[str, Any]:
        """The settings as ``set_display`` replies them."""
        d = self.display
        return {
            "zones": d.zones,
            "angle_deg": d.angle_deg,
            "cols": d.cols,
            "rows": d.rows,
            "width": d.width,
            "method": self.method,
            "light_model": self.light_model,
            "specular": self.specular,
            "galpixel_order": self.galpixel_order,
            "encodings": list(self.encodings),
            "refresh_hz": self.refresh_hz,
            "sird_method": self.sird_method,
            "sird_eye_sep": self.sird_eye_sep,
            "lod_error": self.lod_error,
            "quality": self.quality,
            "max_error": self.max_error,
        }


@dataclass
class State:
    """Everything the three loops share (guard with ``lock``)."""

    settings: Settings
    scene: Scene | None = None
    scene_t: float = 0.0
    scene_version: int = 0
    devices: str | None = None
    viewer: ViewerTracker = field(default_factory=lambda: ViewerTracker())
    lock: threading.Lock = field(default_factory=threading.Lock)


@dataclass
class Ready:
    """A finished update waiting for the refresh thread."""

    render_id: int
    generation: int
    rendezvous: int
    buffer: Any
    rendered: Any
    t_render_ns: int
    scene_version: int = 0


class ReplyCache:
    """Replies to recent mutating requests, so that a resend is not applied twice.

    The key is ``(client_id, id)`` when the request carries a ``client_id`` (the
    library sends a random one per :class:`~service.client.ServiceClient`, so a Lazy
    Pirate resend on a fresh socket still matches), else ``(ROUTER identity, id)``
    (a resend on the same connection only).  Requests without an ``id`` and
    non-mutating types are not cached.  At most ``size`` replies, each for
    ``ttl_s`` seconds (``docs/protocol.md`` 1.7).
    """

    def __init__(
        self, size: int = protocol.REPLY_CACHE_SIZE, ttl_s: float = protocol.REPLY_CACHE_S
    ) -> None:
        self.size, self.ttl_s = size, ttl_s
        self._items: OrderedDict[tuple, tuple[float, list[Any]]] = OrderedDict()

    @staticmethod
    def key(envelope: list[bytes], req: dict[str, Any]) -> tuple | None:
        """The cache key of a parsed request, or None when it is not cached."""
        if req["type"] not in protocol.MUTATING_TYPES or req.get("id") is None:
            return None
        cid = req.get("client_id")
        if isinstance(cid, str) and 0 < len(cid) <= 64:
            return ("client", cid, req["type"], req["id"])
        return ("conn", envelope[0], req["type"], req["id"])

    def get(self, key: tuple | None) -> list[Any] | None:
        """The remembered reply frames (without the envelope), or None."""
        if key is None:
            return None
        self._expire()
        got = self._items.get(key)
        return None if got is None else got[1]

    def put(self, key: tuple, frames: list[Any]) -> None:
        """Remember a reply (header and buffers, without the routing envelope)."""
        self._items[key] = (time.monotonic(), [bytes(f) for f in frames])
        self._items.move_to_end(key)
        while len(self._items) > self.size:
            self._items.popitem(last=False)

    def _expire(self) -> None:
        now = time.monotonic()
        while self._items and now - next(iter(self._items.values()))[0] > self.ttl_s:
            self._items.popitem(last=False)


@dataclass
class Aim:
    """A render about to be made: its job, the snapshot it renders and its rendezvous."""

    render_id: int
    job: dict[str, Any]
    scene: Scene
    settings: Settings
    scene_version: int
    rendezvous: int
    fixed: Any
    t0: int


class Counters:
    """Service statistics (thread-safe enough: ints and deques)."""

    def __init__(self) -> None:
        self.n: dict[str, int] = dict.fromkeys(
            (
                "updates",
                "renders",
                "refreshes",
                "incomplete_updates",
                "late_refused",
                "render_failures",
                "refresh_errors",
                "requests",
                "errors",
                "refresh_overruns",
                "resends_answered",
            ),
            0,
        )
        self.render_ms: deque[float] = deque(maxlen=200)
        self.refresh_ms: deque[float] = deque(maxlen=600)
        self.sird_ms: deque[float] = deque(maxlen=600)
        self.update_t: deque[float] = deque(maxlen=1000)
        self.refresh_t: deque[float] = deque(maxlen=2000)
        self.tick_late_ms: deque[float] = deque(maxlen=2000)

    @staticmethod
    def rate(times: deque[float], window: float = 5.0) -> float:
        """Events per second over the last ``window`` seconds."""
        now = time.monotonic()
        recent = [t for t in list(times) if now - t <= window]
        if len(recent) < 2:
            return 0.0
        return (len(recent) - 1) / max(recent[-1] - recent[0], 1e-9)

    def as_dict(self) -> dict[str, Any]:
        """Counters, rates and medians."""
        med = lambda d: float(np.median(list(d))) if d else None  # noqa: E731
        return {
            **self.n,
            "updates_per_s": self.rate(self.update_t),
            "refreshes_per_s": self.rate(self.refresh_t),
            "render_ms_p50": med(self.render_ms),
            "refresh_ms_p50": med(self.refresh_ms),
            "sird_ms_p50": med(self.sird_ms),
            "tick_late_ms_p50": med(self.tick_late_ms),
            "tick_late_ms_p95": (
                float(np.percentile(list(self.tick_late_ms), 95)) if self.tick_late_ms else None
            ),
        }


class Service:
    """The render service; see the module notes.

    Parameters
    ----------
    config : ServiceConfig
    log : callable, optional
        Called with one line of text per warm-up step (the CLI prints them).

    Raises
    ------
    SettingsError
        A bad setting (:func:`check_config`), before any socket is bound.
    """

    def __init__(self, config: ServiceConfig, log: Callable[[str], None] | None = None) -> None:
        check_config(config)
        self.config = config
        self.log = log or (lambda line: None)
        self.session = secrets.token_hex(4)
        # two I/O threads: the frame PUB gets one of its own (FrameStream sets the
        # affinity), so a worker's multi-MB reply never queues a frame behind it
        self.ctx = zmq.Context(io_threads=max(1, config.io_threads))
        self.limits = protocol.Limits()
        self.counters = Counters()
        self.state = State(
            Settings(config.display, refresh_hz=config.refresh_hz, lod_error=config.lod_error),
            devices=config.devices
        )
        self.state.viewer.scale = config.pose_scale
        self._stop = threading.Event()
        self._ready: deque[Ready] = deque(maxlen=4)
        self._render_results: queue.Queue = queue.Queue()
        self._waiting: list[tuple[list[bytes], Any, float, tuple]] = []
        # (next refresh index, its time, settings generation, stage fixed-point, order)
        self._clock: tuple = (0, time.monotonic(), -1, None, 2)
        self.band_retries = 0
        self._last_aim: tuple[int, int] = (-1, -1)  # (generation, rendezvous) last aimed at
        self._chooser: tuple[int, QualityChooser] | None = None  # (generation, chooser)
        self._pipe: FramePipe | None = None
        self.last_render_error = ""
        self.last_refresh_error = ""
        self.clients: dict[bytes, float] = {}
        self.replies = ReplyCache()
        self._threads: list[threading.Thread] = []
        self.workers: list[subprocess.Popen] = []
        self.broker: Broker | None = None
        self._auth = None
        self._open_sockets()
        self.warmup: Warmup | None = Warmup(self.log) if config.warmup else None
        if self.warmup is None:
            self._prepare()
        self.handlers: dict[str, Callable[[dict[str, Any]], tuple | None]] = {
            "hello": self._hello,
            "ping": self._ping,
            "load_scene": self._load_scene,
            "load_object": self._load_object,
            "update_objects": self._update_objects,
            "set_viewer": self._set_viewer,
            "set_display": self._set_display,
            "render": self._render,
            "stats": self._stats,
            "shutdown": self._shutdown,
        }

    # ---------------------------------------------------------------- set-up
    def _secure(self, address: str) -> Callable[[zmq.Socket], None] | None:
        keys = self.config.curve_keys
        if keys is None:
            if not is_local(address):
                raise SettingsError(
                    f"binding {address} (not loopback) needs --curve-keys DIR "
                    "(make them with holo-service-keys DIR)"
                )
            return None
        if self._auth is None:
            self._auth = start_authenticator(self.ctx, keys)
        return curve_server(keys)

    def _open_sockets(self) -> None:
        c = self.config
        self.router = self.ctx.socket(zmq.ROUTER)
        self.router.setsockopt(zmq.LINGER, 0)
        self.router.setsockopt(zmq.MAXMSGSIZE, self.limits.max_message_bytes)
        self.router.setsockopt(zmq.ROUTER_MANDATORY, 1)
        self.router.setsockopt(zmq.SNDTIMEO, 1000)
        self.router.setsockopt(zmq.HEARTBEAT_IVL, int(protocol.HEARTBEAT_S * 1000))
        self.router.setsockopt(
            zmq.HEARTBEAT_TIMEOUT, int(protocol.HEARTBEAT_S * protocol.HEARTBEAT_LIVENESS * 1000)
        )
        secure = self._secure(c.control)
        if secure:
            secure(self.router)
        try:
            self.router.bind(c.control)
            self.control_address = self.router.getsockopt_string(zmq.LAST_ENDPOINT)
            self.stream = FrameStream(self.ctx, c.frames, self.session, self._secure(c.frames))
            if c.workers > 0 or c.worker_address is not None:
                self._start_broker()
        except (zmq.ZMQError, SettingsError):
            self.close()
            raise

    def _start_broker(self) -> None:
        """Bind the broker's backend and start ``config.workers`` local workers (maybe 0)."""
        c = self.config
        address = c.worker_address or DEFAULT_WORKER_ADDRESS
        self.broker = Broker(
            self.ctx,
            "inproc://holo-broker",
            address,
            self._secure(address),
            busy_limit_s=2 * c.render_timeout_s,
        )
        t = threading.Thread(target=self.broker.run, name="broker", daemon=True)
        t.start()
        self._threads.append(t)

    def _start_workers(self) -> None:
        """Start ``config.workers`` local workers (after the warm-up: they load its cache)."""
        c = self.config
        if self.broker is None or c.workers <= 0:
            return
        cmd = [
            sys.executable,
            "-m",
            "service.worker",
            "--connect",
            self.broker.backend_address,
            "--warm-up",
            "--parent",
            str(_pid()),
        ]
        if c.curve_keys:
            cmd += ["--curve-keys", str(c.curve_keys)]
        env = _worker_env(c.workers)
        self.workers = [
            subprocess.Popen(cmd, stdin=subprocess.DEVNULL, env=env) for _ in range(c.workers)
        ]

    def _prepare(self) -> None:
        """What needs the kernels: the ``--scene`` and the local workers."""
        if self.config.scene:
            self.state.scene = _builtin(self.config.scene)
            self.state.scene_t = time.monotonic()
        if not self.workers:
            self._start_workers()

    # ------------------------------------------------------------- control
    @property
    def ready(self) -> bool:
        """Whether the warm-up is over (always, without one)."""
        return self.warmup is None or self.warmup.ready.is_set()

    def status(self) -> dict[str, Any]:
        """``status`` and, while warming up, ``warmup`` (``docs/protocol.md`` 1.8)."""
        if self.ready:
            return {"status": "ready"}
        return {"status": "warming_up", "warmup": self.warmup.as_dict()}

    def run(self, deadline_s: float | None = None) -> None:
        """Serve until ``shutdown`` (or ``deadline_s``); starts and joins the threads.

        With a warm-up the control loop first answers "warming up" and sends the
        heartbeats itself until the kernels are ready, then starts the workers, the
        render and the refresh threads.
        """
        end = None if deadline_s is None else time.monotonic() + deadline_s
        try:
            if self.warmup is not None:
                self._warm(end)
            if self._stop.is_set() or (end is not None and time.monotonic() >= end):
                return
            for name, target in (("render", self._render_loop), ("refresh", self._refresh_loop)):
                t = threading.Thread(target=target, name=name, daemon=True)
                t.start()
                self._threads.append(t)
            self.stream.extra = {"status": "ready"}
            self._serve(end)
        finally:
            self.close()

    def _warm(self, end: float | None) -> None:
        """Answer requests and send heartbeats until the warm-up is over, then prepare."""
        self.warmup.start()
        while not self._stop.is_set() and (end is None or time.monotonic() < end):
            if self.warmup.ready.wait(0):
                break
            self.stream.extra = self.status()
            self.stream.heartbeat()
            if not self.workers and self.warmup.phase == "loading":
                self._start_workers()  # the cache is full: they load it while this does
            if self.router.poll(20):
                self._serve_one(self.router.recv_multipart(copy=False))
            self._forget_clients()
        if self.warmup.ready.is_set() and not self._stop.is_set():
            self.log(f"ready after {self.warmup.summary()}")
            self._prepare()

    def _serve(self, end: float | None) -> None:
        """The control loop of a ready service."""
        while not self._stop.is_set() and (end is None or time.monotonic() < end):
            if self.router.poll(5):
                self._serve_one(self.router.recv_multipart(copy=False))
            self._answer_renders()
            self._forget_clients()

    def _serve_one(self, frames: list[zmq.Frame]) -> None:
        envelope, body = protocol.split_envelope([f.buffer for f in frames])
        self.counters.n["requests"] += 1
        self.clients[envelope[0]] = time.monotonic()
        rid = mtype = None
        key = None
        try:
            req = protocol.parse_request(body, self.limits)
            rid, mtype = req.get("id"), req["type"]
            if not self.ready and mtype not in WHILE_WARMING:  # never cached: retry later
                self._send(self._warming_reply(envelope, rid, mtype))
                return
            key = self.replies.key(envelope, req)
            cached = self.replies.get(key)
            if cached is not None:  # a resend (Lazy Pirate): the same answer, not applied twice
                self.counters.n["resends_answered"] += 1
                self._send([*envelope, *cached])
                return
            out = self.handlers[mtype](req)
            if out is None:  # answered later (render)
                self._waiting.append(
                    (envelope, rid, time.monotonic(), (time.monotonic_ns(), self._scene_mark()))
                )
                return
            frames_out = protocol.reply(envelope, rid, mtype, *out)
        except MessageError as exc:
            partial = getattr(exc, "partial", {"id": rid, "type": mtype})
            frames_out = self._error(
                envelope, partial["id"], partial["type"], exc.code, exc.message
            )
        except Exception as exc:  # noqa: BLE001 - every request gets a reply
            code = _error_code(exc)
            frames_out = self._error(envelope, rid, mtype, code, f"{type(exc).__name__}: {exc}")
        if key is not None:
            self.replies.put(key, frames_out[len(envelope) :])
        self._send(frames_out)

    def _warming_reply(self, envelope: list[bytes], rid: Any, mtype: str) -> list[Any]:
        """The ``warming_up`` error reply, with the progress (``docs/protocol.md`` 1.8)."""
        self.counters.n["errors"] += 1
        w = self.warmup.as_dict()
        message = (
            f"warming up: {w['phase']} {w['done']}/{w['total']}; "
            "retry when hello, ping or a heartbeat says status ready"
        )
        return protocol.error_reply(envelope, rid, mtype, "warming_up", message, self.status())

    def _error(
        self, envelope: list[bytes], rid: Any, mtype: str | None, code: str, message: str
    ) -> list[Any]:
        self.counters.n["errors"] += 1
        return protocol.error_reply(envelope, rid, mtype, code, message)

    def _send(self, frames: list[Any]) -> None:
        try:
            wire.send(self.router, frames, 1000)
        except zmq.ZMQError:
            pass  # the client is gone (ROUTER_MANDATORY); nothing to answer

    def _forget_clients(self) -> None:
        limit = protocol.HEARTBEAT_S * protocol.HEARTBEAT_LIVENESS
        now = time.monotonic()
        for ident in [i for i, t in self.clients.items() if now - t > limit]:
            del self.clients[ident]

    # ------------------------------------------------------------ handlers
    def _hello(self, req: dict[str, Any]) -> tuple:
        versions = req.get("versions", [protocol.VERSION])
        if not isinstance(versions, list):
            raise MessageError("bad_message", "versions must be a list of ints")
        common = [v for v in protocol.SUPPORTED_VERSIONS if v in versions]
        if not common:
            raise MessageError(
                "bad_version",
                f"no common version; the service speaks {list(protocol.SUPPORTED_VERSIONS)}",
            )
        return (
            {
                "version": max(common),
                "versions": list(protocol.SUPPORTED_VERSIONS),
                "service": protocol.SERVICE_NAME,
                "session": self.session,
                "heartbeat_s": protocol.HEARTBEAT_S,
                "frames": self.stream.address,
                "limits": self.limits.as_dict(),
                **self.status(),
            },
        )

    def _ping(self, req: dict[str, Any]) -> tuple:
        return ({"t_ns": time.monotonic_ns(), **self.status()},)

    def _load_scene(self, req: dict[str, Any]) -> tuple:
        sources = [k for k in ("builtin", "path", "scene") if k in req]
        if len(sources) != 1:
            raise MessageError("bad_message", "give exactly one of builtin, path, scene")
        loaders = {
            "builtin": lambda v: _builtin(wire.string(v, "builtin", 64)),
            "path": lambda v: _load_path(wire.string(v, "path"), self.config.scene_dirs),
            "scene": wire.scene_from_wire,
        }
        scene = loaders[sources[0]](req[sources[0]])
        with self.state.lock:
            self.state.scene, self.state.scene_t = scene, time.monotonic()
            self.state.scene_version += 1
        return (
            {
                "objects": [o.name for o in scene.objects],
                "polygons": int(sum(o.mesh.n_polygons for o in scene.objects)),
            },
        )

    def _load_object(self, req: dict[str, Any]) -> tuple:
        if "path" in req:
            from service.scene import SceneObject

            mesh_scene = _load_path(wire.string(req["path"], "path"), self.config.scene_dirs)
            obj = mesh_scene.objects[0]
            if "name" in req:
                obj = SceneObject(
                    obj.mesh,
                    obj.material,
                    obj.transform,
                    obj.motion,
                    wire.string(req["name"], "name", wire.MAX_NAME),
                )
        else:
            obj = wire.object_from_wire(req.get("object"), "object")
        with self.state.lock:
            scene = self.state.scene or Scene()
            if len(scene.objects) >= self.limits.max_objects:
                raise MessageError(
                    "too_large", f"a scene holds at most {self.limits.max_objects} objects"
                )
            self._advance_locked(time.monotonic())
            scene = self.state.scene or Scene()
            self.state.scene = Scene([*scene.objects, obj], scene.lights, scene.ambient)
            self.state.scene_version += 1
            return ({"index": len(self.state.scene.objects) - 1},)

    def _advance_locked(self, now: float) -> None:
        """Move the scene's state to ``now`` (so updates start from the present)."""
        s = self.state
        if s.scene is not None and s.scene.objects:
            s.scene = advance_scene(s.scene, now - s.scene_t)
        s.scene_t = now

    def _update_objects(self, req: dict[str, Any]) -> tuple:
        ups = req.get("objects")
        if not isinstance(ups, list):
            raise MessageError("bad_message", "objects must be a list")
        if len(ups) > self.limits.max_objects:
            raise MessageError("too_large", f"at most {self.limits.max_objects} updates")
        with self.state.lock:
            if self.state.scene is None:
                raise MessageError("no_scene", "load a scene first")
            objs = list(self.state.scene.objects)
            todo = [(_object_index(u, objs, i), u) for i, u in enumerate(ups)]
            changed = [
                (k, wire.apply_fields(objs[k], u, f"objects[{i}]")) for i, (k, u) in enumerate(todo)
            ]
            self._advance_locked(time.monotonic())
            objs = list(self.state.scene.objects)
            for k, new in changed:
                objs[k] = replace(new, transform=new.transform, motion=new.motion)
            sc = self.state.scene
            self.state.scene = Scene(objs, sc.lights, sc.ambient)
            self.state.scene_version += 1
        return ({"updated": len(changed)},)

    def _set_viewer(self, req: dict[str, Any]) -> tuple:
        pose = [k for k in VIEWER_POSE_FIELDS if k in req]
        if pose and "devices" in req:
            raise MessageError(
                "bad_message", f"set_viewer takes a pose or devices, not both (got {pose})"
            )
        with self.state.lock:
            if "devices" in req:
                dev = req["devices"]
                self.state.devices = None if dev is None else wire.string(dev, "devices", 256)
            self.state.viewer.set_fields(req)
            return ({"viewer": self.state.viewer.as_dict(), "devices": self.state.devices},)

    def _set_display(self, req: dict[str, Any]) -> tuple:
        with self.state.lock:
            new = _apply_display(self.state.settings, req)
            self.state.settings = new
        return ({"display": new.as_dict()},)

    def _render(self, req: dict[str, Any]) -> None:
        if "encodings" in req:
            _encodings(req["encodings"])
        with self.state.lock:
            if self.state.scene is None:
                raise MessageError("no_scene", "load a scene first")
        return None

    def _stats(self, req: dict[str, Any]) -> tuple:
        s = self.counters.as_dict()
        s.update(
            frames_published=self.stream.published,
            clients=len(self.clients),
            pose_count=self.state.viewer.poses,
            zone=self.state.viewer.zone,
            workers=self.broker.info() if self.broker else None,
            worker_pids=[p.pid for p in self.workers],
            band_retries=self.band_retries,
            render_retries=self.band_retries,
            split=self.config.split if self._to_workers() else "in_process",
            max_in_flight=self._pipe.max_in_flight if self._pipe is not None else None,
            last_render_error=self.last_render_error,
            last_refresh_error=self.last_refresh_error,
            session=self.session,
            **self.status(),
        )
        return ({"stats": s},)

    def _shutdown(self, req: dict[str, Any]) -> tuple:
        self._stop.set()
        return ({},)

    # ------------------------------------------------------- render replies
    def _scene_mark(self) -> tuple[int, int]:
        """(settings generation, scene version): what a render request must see."""
        with self.state.lock:
            return (self.state.settings.generation, self.state.scene_version)

    def _answer_renders(self) -> None:
        """Answer waiting ``render`` requests with the newest finished render."""
        done = None
        while True:
            try:
                done = self._render_results.get_nowait()
            except queue.Empty:
                break
            # a render started after the request, with its settings and scene, answers it
            fresh = [w for w in self._waiting if done[1] >= w[3][0] and done[3] >= w[3][1]]
            self._waiting = [w for w in self._waiting if w not in fresh]
            for envelope, rid, _t, _mark in fresh:
                self._send(_render_reply(envelope, rid, done))
        limit = self.config.render_timeout_s * 4 + 5
        now = time.monotonic()
        for item in [w for w in self._waiting if now - w[2] > limit]:
            self._waiting.remove(item)
            self._send(
                self._error(
                    item[0], item[1], "render", "render_failed", "no render finished in time"
                )
            )

    # -------------------------------------------------------- render thread
    def _render_loop(self) -> None:
        if self.broker is not None and self.config.split == "frames":
            self._pipeline_loop()
            return
        renderer = StatsRenderer()
        bands = None
        if self.broker is not None:
            bands = BandClient(
                self.ctx,
                "inproc://holo-broker",
                self.config.render_timeout_s,
                stop=self._stop,
                has_workers=self._to_workers,
            )
        render_id = 0
        last_start = 0.0
        try:
            while not self._stop.is_set():
                if self.config.max_update_hz > 0:
                    wait = last_start + 1.0 / self.config.max_update_hz - time.monotonic()
                    if wait > 0 and self._stop.wait(wait):
                        break
                last_start = time.monotonic()
                if self._render_once(renderer, bands if self._to_workers() else None, render_id):
                    render_id += 1
                elif self._stop.wait(0.02):
                    break
        finally:
            if bands is not None:
                bands.close()

    def _aim(self, render_id: int) -> Aim | None:
        """Snapshot the scene and aim a render at a rendezvous after every earlier one."""
        with self.state.lock:
            scene, scene_t, settings = self.state.scene, self.state.scene_t, self.state.settings
            viewer = self.state.viewer.render_spec()
            version = self.state.scene_version
        if scene is None or not scene.objects:
            return None
        index, t_index, gen, fixed, order = self._clock
        if gen != settings.generation:
            return None
        hz = settings.refresh_hz
        lead = _lead_s(self.counters.render_ms)
        rendezvous = index + math.ceil(lead * hz) + 1
        if gen == self._last_aim[0]:
            rendezvous = max(rendezvous, self._last_aim[1] + 1)  # one render per rendezvous
        self._last_aim = (gen, rendezvous)
        t_target = t_index + (rendezvous - index) / hz
        job = {
            "job": render_id,
            "t": t_target - scene_t,
            "refresh_hz": hz,
            "display": settings.as_dict(),
            "render": settings.as_dict(),
            "viewer": viewer,
            "order": order,
        }
        if settings.quality == "auto":
            self._auto(job, scene, settings)
        return Aim(render_id, job, scene, settings, version, rendezvous, fixed, time.monotonic_ns())

    def _auto(self, job: dict[str, Any], scene: Scene, settings: Settings) -> None:
        """``quality: "auto"``: this render's method and specular, and the choice in the job."""
        gen = settings.generation
        if self._chooser is None or self._chooser[0] != gen:
            self._chooser = (gen, QualityChooser(
                QualitySettings("auto", parse_budget(settings.max_error))))
        q = choose(self._chooser[1], scene, settings.display, settings.light_model)
        job["render"] = {**job["render"], "method": q.method, "specular": q.specular}
        job["quality"] = q.as_dict()

    def _ahead(self) -> bool:
        """Whether the last render is aimed past the rendezvous one started now would get.

        Renders one at a time (in process, or in bands) wait for the refresh clock
        then: aiming each at the last rendezvous + 1 while renders are quicker than
        refreshes would queue them ever further ahead (latency and memory growing
        without bound).
        """
        index, _t, gen, _fixed, _order = self._clock
        if gen != self._last_aim[0]:
            return False
        hz = self.state.settings.refresh_hz
        return self._last_aim[1] >= index + math.ceil(_lead_s(self.counters.render_ms) * hz) + 1

    def _render_once(self, renderer: Renderer, bands: BandClient | None, render_id: int) -> bool:
        if self._ahead():
            return False
        aim = self._aim(render_id)
        if aim is None:
            return False
        got = self._run_job(renderer, bands, aim)
        if got is None:
            self.counters.render_ms.append((time.monotonic_ns() - aim.t0) / 1e6)
            self.counters.n["render_failures"] += 1
            return False
        self._finish(aim, *got)
        return True

    def _finish(self, aim: Aim, parts: list[dict[str, np.ndarray]], stats: dict[str, Any]) -> None:
        """Stitch a finished render, hand it to the refresh thread and to render requests."""
        t_stitch = time.perf_counter()
        rendered, buf = stitch(parts, _viewer_motion(aim.job), aim.fixed, aim.job["order"])
        wall = (time.monotonic_ns() - aim.t0) / 1e6
        self.counters.render_ms.append(wall)
        stats = {
            **stats,
            "wall_ms": round(wall, 3),
            "stitch_ms": round((time.perf_counter() - t_stitch) * 1e3, 3),
            "rendezvous": aim.rendezvous,
        }
        if "quality" in aim.job:
            stats["quality"] = aim.job["quality"]
            self._observe(aim, parts, stats)
        self.counters.n["renders"] += 1
        self._ready.append(
            Ready(
                aim.render_id,
                aim.settings.generation,
                aim.rendezvous,
                buf,
                rendered,
                aim.t0,
                aim.scene_version,
            )
        )
        mark = (aim.settings.generation, aim.scene_version)
        self._render_results.put((aim.render_id, aim.t0, rendered.frame, mark, stats))

    def _observe(self, aim: Aim, parts: list[dict[str, np.ndarray]], stats: dict) -> None:
        """Tell the quality chooser what the render showed (out-of-order points, coverage)."""
        chooser = self._chooser
        if chooser is None or chooser[0] != aim.settings.generation:
            return
        bands = stats.get("bands") or [stats]
        bad = sum(int(b.get("inconsistent_pixels", 0)) for b in bands)
        covered = sum(int(np.isfinite(p["depth"]).sum()) for p in parts if "depth" in p)
        chooser[1].observe(aim.job["render"]["method"], {"inconsistent_pixels": bad}, covered)

    def _run_job(
        self, renderer: Renderer, bands: BandClient | None, aim: Aim
    ) -> tuple[list[dict[str, np.ndarray]], dict[str, Any]] | None:
        """Render in process or as bands through the broker: (parts, stats) or None."""
        job, settings = aim.job, aim.settings
        try:
            if bands is None:
                job["rows"] = [0, settings.display.rows]
                out, stats = render_job(renderer, job, aim.scene)
                return [out], {**stats, "mode": "in_process"}
            spec, arrays = wire.extract(wire.scene_to_wire(aim.scene))
            n = max(1, len(self.broker.ready) + len(self.broker.busy), self.config.workers)
            got = bands.run({**job, "scene": spec}, arrays, split_rows(settings.display.rows, n))
            self.band_retries = bands.resent
            if got is None:
                return None
            per_band = [g.pop("_stats", {}) for g in got]
            return got, {"mode": "bands", "method": settings.method, "bands": per_band}
        except (HoloError, ValueError) as exc:
            self.last_render_error = str(exc)
            return None

    # ------------------------------------------------- pipelined whole frames
    def _to_workers(self) -> bool:
        """Whether renders go through the broker rather than run in process.

        They do when the broker knows a worker (ready or busy), and always when this
        service started local workers (they say ``READY`` once warmed up; jobs wait
        for them).  With only remote workers expected (``--workers 0`` and a
        ``--worker-address``), renders run in process while none is connected.
        """
        b = self.broker
        if b is None:
            return False
        return self.config.workers > 0 or len(b.ready) + len(b.busy) > 0

    def _capacity(self) -> int:
        """Renders to keep in flight: one per worker the broker knows (at least one)."""
        b = self.broker
        return max(1, len(b.ready) + len(b.busy)) if b is not None else 1

    def _cap_s(self) -> float:
        """The shortest time between render starts (``--max-update-hz``; 0: no cap)."""
        hz = self.config.max_update_hz
        return 1.0 / hz if hz > 0 else 0.0

    def _spacing_s(self, capacity: int) -> float:
        """Time between dispatches: a render's time over the workers (and the cap)."""
        cap = self._cap_s()
        recent = list(self.counters.render_ms)[-20:]
        spread = float(np.median(recent)) / 1e3 / capacity if recent else 0.0
        return max(cap, spread)

    def _pipeline_loop(self) -> None:
        """Whole-frame renders for successive rendezvous, one in flight per worker.

        With no local workers and none connected (``--workers 0`` with a
        ``--worker-address``; see :meth:`_to_workers`) it renders in process, so
        renders never wait for a worker that may never come.
        """
        pipe = FramePipe(self.ctx, "inproc://holo-broker", self.config.render_timeout_s)
        self._pipe = pipe
        local: StatsRenderer | None = None
        render_id, next_start = 0, 0.0
        try:
            while not self._stop.is_set():
                capacity, remote = self._capacity(), self._to_workers()
                now = time.monotonic()
                if not remote and now >= next_start:
                    local = local or StatsRenderer()
                    done = self._render_once(local, None, render_id)
                    render_id += int(done)
                    next_start = now + (self._cap_s() if done else 0.02)
                elif remote and len(pipe.flights) < capacity and now >= next_start:
                    # renders quicker than refreshes (a low refresh_hz) would otherwise be
                    # aimed one rendezvous past the last, ever further into the future
                    aim = None if self._ahead() else self._aim(render_id)
                    if aim is None:
                        next_start = now + 0.02
                    else:
                        self._dispatch(pipe, aim, 0)
                        render_id += 1
                        next_start = now + self._spacing_s(capacity)
                full = remote and len(pipe.flights) >= capacity
                wait = 50 if full else (next_start - time.monotonic()) * 1000
                for flight, head in pipe.poll(min(50, max(0, int(wait)))):
                    self._landed(flight, head)
                for flight in pipe.expired():
                    self._retry(pipe, flight)
        finally:
            pipe.close()

    def _dispatch(self, pipe: FramePipe, aim: Aim, attempt: int) -> None:
        spec, arrays = wire.extract(wire.scene_to_wire(aim.scene))
        job = {**aim.job, "rows": [0, aim.settings.display.rows], "scene": spec}
        pipe.send(job, arrays, aim, attempt)

    def _landed(self, flight: Flight, head: dict[str, Any]) -> None:
        """A worker's whole-frame reply: stitch and hand it on (or count the failure)."""
        if not head.get("ok") or not isinstance(head.get("arrays"), dict):
            self.counters.n["render_failures"] += 1
            self.last_render_error = str(head.get("error", "bad worker reply"))
            return
        stats = {**(head.get("stats") or {}), "mode": "frames", "attempt": flight.attempt}
        try:
            self._finish(flight.meta, [head["arrays"]], stats)
        except (HoloError, ValueError, KeyError) as exc:
            self.counters.n["render_failures"] += 1
            self.last_render_error = f"{type(exc).__name__}: {exc}"

    def _retry(self, pipe: FramePipe, flight: Flight) -> None:
        """A job past its deadline (its worker died or stalled): re-aim it and resend.

        The resend is aimed at a new rendezvous from the present, so the render is
        never grafted late; after 3 resends, or when the broker knows no worker any
        more, the render counts as failed.
        """
        self.band_retries += 1
        retry = flight.attempt < 3 and self._to_workers()  # none: renders run in process
        aim = self._aim(flight.meta.render_id) if retry else None
        if aim is None:
            self.counters.n["render_failures"] += 1
            self.last_render_error = f"render {flight.meta.render_id}: no worker answered"
            return
        self._dispatch(pipe, aim, flight.attempt + 1)

    # ------------------------------------------------------- refresh thread
    def _refresh_loop(self) -> None:
        RefreshLoop(self).run()

    # ------------------------------------------------------------- closing
    @property
    def stop_event(self) -> threading.Event:
        """Set it (from any thread) to make :meth:`run` return and close the service."""
        return self._stop

    def close(self) -> None:
        """Stop the threads and workers; close every socket (LINGER 0).

        Threads get 5 s each to finish; the context is then destroyed (every socket
        still open closed with LINGER 0), so closing never waits forever.
        """
        self._stop.set()
        if self.warmup is not None:
            self.warmup.stop()
        if self.broker is not None:
            self.broker.stop()
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(5.0)
        for p in self.workers:
            end_process(p, 3.0)
        for sock in (
            getattr(self, "router", None),
            getattr(getattr(self, "stream", None), "sock", None),
        ):
            if sock is not None:
                sock.close(0)
        if self._auth is not None:
            self._auth.stop()
        self.ctx.destroy(linger=0)


# ------------------------------------------------------------------ helpers
def _pid() -> int:
    import os

    return os.getpid()


def _worker_env(workers: int) -> dict[str, str]:
    """Environment of local workers: their numba thread pools share the cores.

    Each worker renders whole frames with parallel kernels; N workers with a pool
    of every core each would oversubscribe the machine N times, so each gets
    ``cores // N`` threads (at least one) unless ``NUMBA_NUM_THREADS`` is set.
    """
    env = dict(os.environ)
    if "NUMBA_NUM_THREADS" not in env and workers > 0:
        env["NUMBA_NUM_THREADS"] = str(max(1, (os.cpu_count() or 1) // workers))
    return env


def _lead_s(render_ms: deque[float]) -> float:
    """How far ahead to aim a render: its 90th percentile time plus a little."""
    if not render_ms:
        return 0.5
    return float(np.percentile(list(render_ms)[-50:], 90)) / 1e3 * 1.2 + 0.01


def _builtin(name: str) -> Scene:
    from service.builtin_scenes import builtin_scene

    try:
        return builtin_scene(name)
    except SettingsError as exc:
        raise MessageError("not_found", str(exc)) from exc


def _load_path(path: str, roots: tuple[str, ...] = ()) -> Scene:
    """Load a scene or mesh file; with ``roots``, only from inside those directories."""
    from service.loaders import load_scene

    if roots:
        real = Path(path).resolve()
        if not any(real.is_relative_to(Path(r).resolve()) for r in roots):
            raise MessageError("not_found", f"{path} is outside the service's scene directories")
    if not Path(path).is_file():
        raise MessageError("not_found", f"no such file: {path}")
    try:
        scene = load_scene(path)
    except MeshFileError as exc:
        raise MessageError("not_found", str(exc)) from exc
    if scene.billboards:  # the wire to the workers does not carry them yet
        raise MessageError("bad_settings", f"{path}: billboard clouds (.hbc) are not served "
                           "yet (workers receive meshes only); render them with holo-render")
    return scene


def _object_index(u: Any, objs: list, i: int) -> int:
    """The scene index an ``update_objects`` entry names (by ``index`` or ``name``).

    Raises
    ------
    MessageError
        ``bad_message`` for a malformed entry (not an object, neither key, an index
        that is not a non-negative integer); ``not_found`` for a well-formed index or
        name that names no object of the scene.
    """
    if not isinstance(u, dict):
        raise MessageError("bad_message", f"objects[{i}] must be an object")
    if "index" in u:
        k = wire.integer(u["index"], f"objects[{i}].index", 0, MAX_INDEX)
        if k >= len(objs):
            raise MessageError(
                "not_found", f"objects[{i}]: no object {k} (the scene has {len(objs)})"
            )
        return k
    if "name" not in u:
        raise MessageError("bad_message", f"objects[{i}] needs an index or a name")
    name = wire.string(u["name"], f"objects[{i}].name", wire.MAX_NAME)
    for k, o in enumerate(objs):
        if o.name == name:
            return k
    raise MessageError("not_found", f"objects[{i}]: no object {name!r}")


def _encodings(v: Any) -> tuple[str, ...]:
    if not isinstance(v, list) or not v or not all(e in ENCODINGS for e in v):
        raise MessageError("bad_message", f"encodings must be a non-empty list from {ENCODINGS}")
    return tuple(dict.fromkeys(v))


def _check_sird(cols: int, eye_sep: float) -> None:
    """Refuse an autostereogram the eyes cannot fuse (``bad_settings``)."""
    from service.autostereogram import SirdSettings, default_eye_sep

    try:
        SirdSettings(eye_sep=eye_sep or default_eye_sep(cols)).check_width(cols)
    except SettingsError as exc:
        raise MessageError("bad_settings", f"autostereogram: {exc}") from None


def _apply_display(s: Settings, req: dict[str, Any]) -> Settings:
    d = s.display
    disp = {
        "zones": wire.integer(req.get("zones", d.zones), "zones", 1, 64),
        "angle_deg": wire.number(req.get("angle_deg", d.angle_deg), "angle_deg", 0, 60),
        "cols": wire.integer(req.get("cols", d.cols), "cols", 1, 8192),
        "rows": wire.integer(req.get("rows", d.rows), "rows", 1, 8192),
        "width": wire.number(req.get("width", d.width), "width", 1e-6, 1e6),
    }
    choices = {
        "method": METHOD_NAMES,
        "light_model": tuple(MODELS),
        "specular": tuple(EVALUATIONS),
        "sird_method": SIRD_METHODS,
    }
    kw: dict[str, Any] = {}
    for key, allowed in choices.items():
        if key in req:
            if req[key] not in allowed:
                raise MessageError("bad_settings", f"{key} must be one of {list(allowed)}")
            kw[key] = req[key]
    if "galpixel_order" in req:
        kw["galpixel_order"] = wire.integer(req["galpixel_order"], "galpixel_order", 0, 3)
    if "encodings" in req:
        kw["encodings"] = _encodings(req["encodings"])
    if "refresh_hz" in req:
        kw["refresh_hz"] = wire.number(req["refresh_hz"], "refresh_hz", 1.0, 240.0)
    if "sird_eye_sep" in req:
        kw["sird_eye_sep"] = wire.number(req["sird_eye_sep"], "sird_eye_sep", 0.0, 4096.0)
    if "autostereogram" in kw.get("encodings", s.encodings):
        _check_sird(disp["cols"], kw.get("sird_eye_sep", s.sird_eye_sep))
    if "lod_error" in req:  # pixels; 0 turns level of detail off
        kw["lod_error"] = wire.number(req["lod_error"], "lod_error", 0.0, 1e6)
    kw.update(_quality_fields(req))
    if disp["cols"] * disp["rows"] * disp["zones"] > 64 * 1024 * 1024:
        raise MessageError("too_large", "display has more than 64 Mi pixels")
    return replace(s, display=DisplaySettings(**disp), generation=s.generation + 1, **kw)


def _sird_output(settings: Settings) -> Any:
    """The ``autostereogram`` encoding's state for these settings, or None when it is off."""
    if "autostereogram" not in settings.encodings:
        return None
    from service.autostereogram.output import SirdOutput

    d = settings.display
    return SirdOutput(d.cols, d.rows, d.width, settings.sird_method, settings.sird_eye_sep)


def _quality_fields(req: dict[str, Any]) -> dict[str, str]:
    """``quality`` ("fixed" / "auto") and ``max_error`` ("0.5%", 0.5, "40dB") of set_display."""
    kw = {}
    if "quality" in req:
        if req["quality"] not in QUALITY_MODES:
            raise MessageError("bad_settings", f"quality must be one of {list(QUALITY_MODES)}")
        kw["quality"] = req["quality"]
    if "max_error" in req:
        v = req["max_error"]
        try:
            if not isinstance(v, str | int | float) or isinstance(v, bool):
                raise SettingsError("max_error must be a number or a string like 40dB")
            parse_budget(v)
        except SettingsError as exc:
            raise MessageError("bad_settings", str(exc)) from None
        kw["max_error"] = str(v)
    return kw


def _viewer_motion(job: dict[str, Any]) -> MotionState:
    """The viewer's motion a job was rendered with (for the Galilean stage)."""
    spec = job.get("viewer") or {}
    return MotionState(**{k: np.asarray(v) for k, v in spec.items() if k in wire.MOTION_FIELDS})


def _render_reply(envelope: list[bytes], rid: Any, done: tuple) -> list[Any]:
    render_id, t0, frame, _mark, stats = done
    return protocol.reply(
        envelope,
        rid,
        "render",
        {"render_id": render_id, "t_ns": t0, "stats": stats},
        [frame.colour, frame.depth],
        ["colour", "depth"],
    )


def _error_code(exc: Exception) -> str:
    codes: dict[type, str] = {
        SettingsError: "bad_settings",
        MeshFileError: "not_found",
        HoloError: "bad_message",
    }
    for cls, code in codes.items():
        if isinstance(exc, cls):
            return code
    return "internal"


def transform_of(position: np.ndarray, orientation: np.ndarray) -> Transform:
    """A viewer transform (helper for tests and the viewer tracker)."""
    return Transform(np.asarray(position, float), np.asarray(orientation, float))


class ViewerTracker:
    """The viewer's pose and motion: set by ``set_viewer`` or tracked from the devices.

    Tracked poses (device units, degrees) go through an alpha-beta filter for
    velocity and acceleration; positions are scaled by ``scale`` (default 0.001:
    millimetres to world units).  Renders see the viewer relative to the first
    tracked pose (the nominal viewing position); the zone is picked from the
    absolute position's angle ``atan2(x, z)`` across the viewing angle.
    """

    def __init__(self, scale: float = 0.001) -> None:
        from drivers.filters import AlphaBetaSettings, make_filter

        self.scale = scale
        self.position = np.zeros(3)
        self.orientation = np.array([1.0, 0.0, 0.0, 0.0])
        self.motion = MotionState()
        self.active = False
        self.poses = 0
        self.zone: int | None = None
        self.pose_info: dict[str, Any] = {"pose_n": None, "pose_t_ns": None, "pose_seq": None}
        self._origin: np.ndarray | None = None
        self._absolute = np.zeros(3)
        self._filter = make_filter("alpha-beta", AlphaBetaSettings(on_bad="skip"))

    def set_fields(self, req: dict[str, Any]) -> None:
        """Apply ``set_viewer`` fields (validated)."""
        if not any(k in req for k in VIEWER_POSE_FIELDS):
            return
        probe = wire.apply_fields(_probe_object(), req, "viewer")
        self.position = probe.transform.position
        self.orientation = probe.transform.orientation
        self.motion = probe.motion
        self._absolute = self.position
        self.active = True

    def on_pose(self, pose: Any, n: int) -> bool:
        """Take a tracker :class:`~drivers.events.PoseEvent`; True when it was usable."""
        sample = np.array([pose.x, pose.y, pose.z, pose.yaw, pose.pitch, pose.roll], float)
        if not np.all(np.isfinite(sample)):
            return False
        try:
            st = self._filter.update_ns(int(pose.t_ns), sample)
        except HoloError:
            return False
        if self._origin is None:
            self._origin = sample[:3] * self.scale
        yaw, pitch, roll = np.radians(st.position[3:6])
        self._absolute = sample[:3] * self.scale  # the zone follows the newest sample
        self.position = st.position[:3] * self.scale - self._origin
        self.orientation = euler_quaternion(yaw, pitch, roll)
        rates = np.radians(st.velocity[3:6])
        self.motion = MotionState(
            st.velocity[:3] * self.scale,
            st.acceleration[:3] * self.scale,
            np.array([rates[1], rates[0], rates[2]]),
        )
        self.active = True
        self.poses += 1
        self.pose_info = {"pose_n": int(n), "pose_t_ns": int(pose.t_ns), "pose_seq": pose.seq}
        return True

    def pick_zone(self, display: DisplaySettings, distance: float = 0.6) -> int | None:
        """The view zone the viewer's eye is in, or None without a viewer."""
        if not self.active:
            return None
        x, z = float(self._absolute[0]), float(self._absolute[2])
        theta = math.atan2(x, z if z > 1e-6 else distance)
        span = math.radians(display.angle_deg) or 1e-9
        self.zone = int(
            min(display.zones - 1, max(0, math.floor((theta / span + 0.5) * display.zones)))
        )
        return self.zone

    def render_spec(self) -> dict[str, Any] | None:
        """The viewer as a render job carries it (None: no viewer)."""
        if not self.active:
            return None
        return {
            "position": self.position.tolist(),
            "orientation": self.orientation.tolist(),
            **{k: getattr(self.motion, k).tolist() for k in wire.MOTION_FIELDS},
        }

    def as_dict(self) -> dict[str, Any]:
        """The pose in use (for the ``set_viewer`` reply)."""
        return self.render_spec() or {"position": None}


def _probe_object() -> Any:
    from service.mesh import Mesh
    from service.scene import SceneObject

    return SceneObject(Mesh.from_triangles(np.eye(3), [[0, 1, 2]]))


class RefreshLoop:
    """The refresh thread: stage, devices, publishing, at a fixed rate."""

    def __init__(self, svc: Service) -> None:
        self.svc = svc
        self.stage: GalileanStage | None = None
        self.generation = -1
        self.scene_version = -1
        self.sub = None
        self.sub_address: str | None = None
        self.due: dict[int, tuple[int, int]] = {}  # rendezvous -> (render id, t_render_ns)
        self.render_id = -1
        self.t_render_ns = 0
        self.since = 0
        self.prepared: tuple[Any, dict[str, Any]] | None = None
        self.input: dict[str, Any] | None = None
        self.sird = None  # service.autostereogram.SirdOutput while that encoding is on

    def _restart(self, settings: Settings) -> None:
        self.stage = GalileanStage(
            settings.display,
            GalileanSettings(order=settings.galpixel_order, refresh_hz=settings.refresh_hz),
        )
        self.generation = settings.generation
        self.sird = _sird_output(settings)
        self.due.clear()
        self.render_id, self.since = -1, 0
        self.prepared = None

    def run(self) -> None:
        """Tick until the service stops."""
        svc = self.svc
        next_t = time.monotonic()
        try:
            while not svc._stop.is_set():
                settings = svc.state.settings
                if settings.generation != self.generation:
                    self._restart(settings)
                period = 1.0 / settings.refresh_hz
                svc._clock = (  # the refresh computed now is shown at the next tick
                    self.stage.index,
                    next_t + period,
                    self.generation,
                    self.stage.fixed,
                    settings.galpixel_order,
                )
                try:
                    self._tick(settings)
                except Exception as exc:  # a bug must not stop the display: log, restart
                    svc.counters.n["refresh_errors"] += 1
                    svc.last_refresh_error = f"{type(exc).__name__}: {exc}"
                    self._restart(settings)
                next_t = self._wait(next_t + period, period)
        finally:
            if self.sub is not None:
                self.sub.close()

    def _wait(self, next_t: float, period: float) -> float:
        """Sleep until ``next_t``; past a whole period late, skip the missed ticks."""
        now = time.monotonic()
        if now - next_t > period:
            missed = math.floor((now - next_t) / period)
            self.svc.counters.n["refresh_overruns"] += missed
            next_t += missed * period
        if next_t > now:
            self.svc._stop.wait(next_t - now)
        self.svc.counters.tick_late_ms.append((time.monotonic() - next_t) * 1e3)
        return next_t

    def _tick(self, settings: Settings) -> None:
        """Publish the frame prepared last tick, then prepare the next one.

        The pose is latched at the start of the tick and the frame goes out at once
        (as a display scans out at vsync what was computed before it); the refresh
        for the next tick is computed afterwards, so its cost and jitter do not sit
        between the newest pose and the published frame.
        """
        svc, c = self.svc, self.svc.counters
        self._devices(settings)  # latch: the newest pose picks the zone
        if self.prepared is not None:
            self._publish(*self.prepared, settings)
        else:
            svc.stream.heartbeat()
        t0 = time.perf_counter()
        self._submit()
        r = self.stage.refresh()
        c.n["refreshes"] += 1
        c.refresh_t.append(time.monotonic())
        if r.flags["updated"] and r.index in self.due:
            self.render_id, self.t_render_ns = self.due.pop(r.index)
            self.since = 0
            c.n["updates"] += 1
            c.update_t.append(time.monotonic())
        else:
            self.since += 1
        c.n["incomplete_updates"] += sum(
            e.get("kind") == "incomplete_update" for e in r.flags["events"]
        )
        ms = (time.perf_counter() - t0) * 1e3
        c.refresh_ms.append(ms)
        if self.sird is not None:  # the SIRD of the zone the newest pose picked (or the centre)
            zone = self.svc.state.viewer.zone
            sird = self.sird.frame(r.depth[r.depth.shape[0] // 2 if zone is None else zone])
            r = replace(r, flags={**r.flags, "autostereogram": sird})
            c.sird_ms.append(self.sird.last_ms)
        if self.render_id >= 0:
            self.prepared = (
                r,
                {
                    "render_id": self.render_id,
                    "since_render": self.since,
                    "t_render_ns": self.t_render_ns,
                    "ms": ms,
                },
            )

    def _submit(self) -> None:
        svc = self.svc
        while svc._ready:
            up = svc._ready.popleft()
            if up.generation != self.generation:
                continue
            rd = up.rendered
            if up.scene_version != self.scene_version:
                self.stage.reset_guard()  # a new scene: the old points predict nothing
                self.scene_version = up.scene_version
            ok = self.stage.submit(
                up.buffer,
                up.rendezvous,
                None,
                True,
                (),
                rd.points,
                rd.point_derivs,
                rd.viewer_motion,
            )
            if ok:
                self.due[up.rendezvous] = (up.render_id, up.t_render_ns)
            else:
                svc.counters.n["late_refused"] += 1
                svc.counters.n["incomplete_updates"] += 1

    def _devices(self, settings: Settings) -> None:
        state = self.svc.state
        if state.devices != self.sub_address:
            self._connect(state.devices)
        if self.sub is None:
            state.viewer.pick_zone(settings.display)
            return
        self.sub.poll(0)
        pose = self.sub.pose
        if self.sub.state_known:
            self.input = {
                "seq": self.sub.seq,
                "dials": list(self.sub.dials),
                "buttons": list(self.sub.buttons),
            }
        with state.lock:
            if pose is not None and self.sub.pose_count != state.viewer.pose_info["pose_n"]:
                if state.viewer.on_pose(pose, self.sub.pose_count):
                    self.stage.viewer(state.viewer.motion)
            state.viewer.pick_zone(settings.display)

    def _connect(self, address: str | None) -> None:
        from drivers.subscriber import DeviceSubscriber

        if self.sub is not None:
            self.sub.close()
        self.sub = None if address is None else DeviceSubscriber(address, context=self.svc.ctx)
        self.sub_address = address
        self.input = None

    def _publish(self, r: Any, made: dict[str, Any], settings: Settings) -> None:
        names = list(settings.encodings)
        viewer = self.svc.state.viewer
        header = {
            "refresh": r.index,
            **made,
            "updated": bool(r.flags["updated"]),
            "refresh_hz": settings.refresh_hz,
            "zone": viewer.zone,
            **viewer.pose_info,
            "input": self.input,
            "events": r.flags["events"],
            "age": r.flags["age"],
        }
        arrays = [r.flags[n] if n == "autostereogram" else getattr(r, n) for n in names]
        self.svc.stream.publish(header, arrays, names)
