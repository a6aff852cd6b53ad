"""What the engine's two threads share: settings, the scene, renders on their way, counters.

:class:`EngineState` is the engine's state without any socket: the scene and its
versions (:class:`State`), the refresh clock the render thread aims by, the finished
renders waiting for the refresh thread (:class:`Ready`), and the counters ``stats``
reports.  The render service's state (:class:`service.net.state.ServiceState`) is one
with its configuration and sockets added; the game's local mode uses one as it is.
"""

from __future__ import annotations

import queue
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from service.engine.viewer import ViewerTracker
from service.frame_settings import FrameSettings
from service.lod.builds import ChainBuilds
from service.net.settings_wire import display_to_wire, render_to_wire
from service.render.scene import Scene


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

    def load(self, scene: Scene) -> int:
        """Replace the scene (a new version on the wire); its ``load_scene`` count.

        Frames and renders of the scenes before it are never shown after it
        (``docs/protocol.md`` 2).
        """
        with self.lock:
            self.scene, self.scene_t = scene, time.monotonic()
            self.scene_version += 1
            self.scene_load += 1
            return self.scene_load

    def move(self, scene: Scene) -> None:
        """The same scene's objects in new states, as of now (``update_objects``)."""
        with self.lock:
            self.scene, self.scene_t = scene, time.monotonic()
            self.scene_version += 1


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


@dataclass(kw_only=True)
class EngineState:
    """What the render thread, the refresh thread and their callers share.

    The render thread (:class:`service.engine.scheduler.Scheduler`) aims renders by
    ``clock`` and appends them to ``updates``; the refresh thread
    (:class:`service.engine.refresh.RefreshLoop`) writes ``clock`` and grafts the
    updates.  ``stop`` ends both.
    """

    state: State
    counters: Counters = field(default_factory=Counters)
    #: set (from any thread) to stop the engine
    stop: threading.Event = field(default_factory=threading.Event)
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
    #: level-of-detail chains built off the render path, queued when a scene loads
    #: (the in-process renderer's; workers read them from the cache)
    chains: ChainBuilds = field(default_factory=ChainBuilds)

    def queue_chains(self) -> int:
        """Start building the chains the scene's meshes lack, when level of detail is on.

        Called when a scene or an object is loaded and when the settings change, so
        chains are built before frames need them (the first frames draw full meshes).
        Returns how many were queued.
        """
        with self.state.lock:
            scene, lod = self.state.scene, self.state.settings.render.lod
        if scene is None or lod is None or not lod.enabled:
            return 0
        return self.chains.submit_scene(scene, lod)

    def to_workers(self) -> bool:
        """Whether renders go to worker processes: never, in the engine alone."""
        return False
