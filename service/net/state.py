"""The render service's state: configuration, settings, what the loops share, counters.

:class:`ServiceState` holds one service's state without its sockets, so the request
handlers (:mod:`.handlers`) run against it in process; the server
(:mod:`.server`) fills in the ZeroMQ context, the frame stream, the broker and the
workers when it starts them.
"""

from __future__ import annotations

import math
import queue
import secrets
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from service.base.errors import SettingsError
from service.display import DisplaySettings
from service.frame_settings import FrameSettings
from service.galilean import GalileanSettings
from service.net import protocol
from service.net.settings_wire import display_to_wire, render_to_wire
from service.net.viewer import ViewerTracker
from service.render.pipeline import RenderSettings
from service.render.scene import Scene

if TYPE_CHECKING:
    import zmq

    from service.net.broker import Broker, FramePipe
    from service.net.frame_stream import FrameStream
    from service.net.supervisor import Supervisor
    from service.readiness import Warmup

#: Frame encodings a client may subscribe to: arrays of a refresh by attribute name.
ENCODINGS = ("colour", "depth", "debris", "autostereogram")
#: SIRD methods of the ``autostereogram`` encoding (service.autostereogram).
SIRD_METHODS = ("tiw", "row", "interpolated")
DEFAULT_WORKER_ADDRESS = "tcp://127.0.0.1:5557"
#: the largest object index a request may name (an int64); past the scene's end: not_found.
MAX_INDEX = 2**63 - 1
#: What a warming-up service answers as usual (with its ``status``); every other
#: request gets a ``warming_up`` error (``docs/protocol.md`` 1.8).
WHILE_WARMING = frozenset({"hello", "ping", "stats", "shutdown"})


@dataclass
class ServiceConfig:
    """Command-line settings of ``holo-service`` (see :mod:`service.commands.holo_service`)."""

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
    #: the starting render options (level of detail from ``--lod-error``/``--budget-ms``);
    #: ``set_display`` changes them
    render: RenderSettings = field(default_factory=RenderSettings)
    #: directories ``path`` requests may read from (empty: any file the service can read).
    scene_dirs: tuple[str, ...] = ()
    #: with workers: ``frames`` (each worker renders whole updates for successive
    #: rendezvous, several in flight) or ``bands`` (every worker a band of each update).
    split: str = "frames"
    #: libzmq I/O threads; with 2 the frame PUB has one to itself.
    io_threads: int = 2


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
class Settings(FrameSettings):
    """The service's frame settings, and how often ``set_display`` changed them.

    A :class:`~service.frame_settings.FrameSettings` with ``generation``;
    :mod:`service.net.settings_wire` is the only place that turns the render and
    display settings into wire keys and back.
    """

    generation: int = 0

    def as_dict(self) -> dict[str, Any]:
        """The settings as ``set_display`` replies them."""
        return {
            **display_to_wire(self.display),
            **render_to_wire(self.render),
            "galpixel_order": self.galpixel_order,
            "encodings": list(self.encodings),
            "refresh_hz": self.refresh_hz,
            "sird_method": self.sird_method,
            "sird_eye_sep": self.sird_eye_sep,
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
    #: the scene's version on the wire: ``load_scene`` requests applied (the frames'
    #: and the render replies' ``scene``; ``docs/protocol.md`` 2)
    scene_load: int = 0
    devices: str | None = None
    viewer: ViewerTracker = field(default_factory=ViewerTracker)
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
    #: the ``load_scene`` count of the scene rendered (:attr:`State.scene_load`)
    scene_load: int = 0
    #: refreshes the render may be propagated (None: the stage's rating; see
    #: :func:`service.galilean.local_update.render_use_by`)
    use_by: int | None = None


class ReplyCache:
    """Replies to recent mutating requests, so that a resend is not applied twice.

    The key is ``(client_id, id)`` when the request carries a ``client_id`` (the
    library sends a random one per :class:`~service.net.client.ServiceClient`, so a Lazy
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
    #: the ``load_scene`` count of the scene snapshot (:attr:`State.scene_load`)
    scene_load: int = 0


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
                "held_refreshes",
            ),
            0,
        )
        #: whether the last refresh held the last render (past its use-by date)
        self.held = False
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
            "held": self.held,
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



@dataclass
class ServiceState:
    """One service's state: what the handlers, the scheduler and the refresh loop share.

    It needs no socket: :func:`service_state` builds one from a configuration and the
    handlers run against it in process.  The server sets ``ctx``, ``stream``,
    ``broker``, ``supervisor`` and ``warmup`` when it starts them.
    """

    config: ServiceConfig
    state: State
    session: str = field(default_factory=lambda: secrets.token_hex(4))
    limits: protocol.Limits = field(default_factory=protocol.Limits)
    counters: Counters = field(default_factory=Counters)
    #: set (from any thread) to stop the service
    stop: threading.Event = field(default_factory=threading.Event)
    #: ROUTER identity -> when it last sent a request
    clients: dict[bytes, float] = field(default_factory=dict)
    #: finished renders waiting for the refresh thread
    updates: deque[Ready] = field(default_factory=lambda: deque(maxlen=4))
    #: finished renders for waiting ``render`` requests (the control loop answers them)
    render_results: queue.Queue = field(default_factory=queue.Queue)
    #: (next refresh index, its time, settings generation, stage fixed-point, order),
    #: written by the refresh thread, read by the scheduler
    clock: tuple = field(default_factory=lambda: (0, time.monotonic(), -1, None, 2))
    band_retries: int = 0
    last_render_error: str = ""
    last_refresh_error: str = ""
    #: the last finished render's level-of-detail report (None: LOD off), for ``stats``
    last_lod: dict | None = None
    ctx: zmq.Context | None = None
    stream: FrameStream | None = None
    broker: Broker | None = None
    pipe: FramePipe | None = None
    #: the local workers' supervisor (with the broker; it also counts remote deaths)
    supervisor: Supervisor | None = None
    warmup: Warmup | None = None

    @property
    def ready(self) -> bool:
        """Whether the warm-up is over (always, without one)."""
        return self.warmup is None or self.warmup.ready.is_set()

    def status(self) -> dict[str, Any]:
        """``status`` and, while warming up, ``warmup`` (``docs/protocol.md`` 1.8)."""
        if self.ready:
            return {"status": "ready"}
        return {"status": "warming_up", "warmup": self.warmup.as_dict()}

    def to_workers(self) -> bool:
        """Whether renders go through the broker rather than run in process.

        They do while the broker knows a live worker (idle or busy).  With none (none
        connected yet, local ones still starting, or every one dead or stuck) renders
        run in process until one is back, so renders never wait for a worker that
        may never come (``stats.split`` is then ``in_process``).
        """
        return self.broker is not None and self.broker.live() > 0

    def scene_mark(self) -> tuple[int, int]:
        """(settings generation, scene version): what a render request must see."""
        with self.state.lock:
            return (self.state.settings.generation, self.state.scene_version)


def service_state(config: ServiceConfig) -> ServiceState:
    """A checked configuration's starting state (no sockets; see :class:`ServiceState`).

    Raises
    ------
    SettingsError
        A bad setting (:func:`check_config`).
    """
    check_config(config)
    state = State(
        Settings(config.display, config.render, refresh_hz=config.refresh_hz),
        devices=config.devices,
    )
    state.viewer.scale = config.pose_scale
    return ServiceState(config, state)
