"""The render service's state: configuration, settings, what the loops share, counters.

:class:`ServiceState` holds one service's state without its sockets, so the request
handlers (:mod:`.handlers`) run against it in process; the server
(:mod:`.server`) fills in the ZeroMQ context, the frame stream, the broker and the
workers when it starts them.
"""

from __future__ import annotations

import math
import secrets
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from service.base.errors import SettingsError
from service.builtin_scenes import canonical_scene_name
from service.display import DisplaySettings
from service.engine.state import EngineState, Settings, State
from service.galilean import GalileanSettings
from service.net import protocol
from service.render.pipeline import RenderSettings

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

        canonical_scene_name(config.scene)
    GalileanSettings(order=2, refresh_hz=config.refresh_hz)


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


@dataclass(kw_only=True)
class ServiceState(EngineState):
    """One service's state: the engine's, with the configuration and the sockets.

    It needs no socket: :func:`service_state` builds one from a configuration and the
    handlers run against it in process.  The server sets ``ctx``, ``stream``,
    ``broker``, ``supervisor`` and ``warmup`` when it starts them.
    """

    config: ServiceConfig
    session: str = field(default_factory=lambda: secrets.token_hex(4))
    limits: protocol.Limits = field(default_factory=protocol.Limits)
    #: ROUTER identity -> when it last sent a request
    clients: dict[bytes, float] = field(default_factory=dict)
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
    return ServiceState(config=config, state=state)
