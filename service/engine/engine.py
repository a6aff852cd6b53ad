"""The engine: the render thread and the refresh thread over one shared state.

:class:`Engine` runs :class:`~service.engine.scheduler.Scheduler` (renders aimed at
rendezvous) and :class:`~service.engine.refresh.RefreshLoop` (the Galilean stage at
the refresh rate, held frames, the scene-version guard) on two threads of this
process.  The render service runs one with its workers and frame stream as the
transport (:mod:`service.net.server`); the game's local mode runs one as it is
(:meth:`Engine.local`), so both show the same frames for the same inputs.
"""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Callable

from service.engine.refresh import RefreshLoop, Sink
from service.engine.scheduler import Scheduler
from service.engine.state import EngineState, Settings, State
from service.frame_settings import FrameSettings
from service.galilean import GalileanStage
from service.render.scene import Scene


def engine_settings(settings: FrameSettings, generation: int = 0) -> Settings:
    """The engine's :class:`Settings` of a :class:`FrameSettings` (its first generation)."""
    values = {f.name: getattr(settings, f.name) for f in dataclasses.fields(FrameSettings)}
    return Settings(**values, generation=generation)


class Engine:
    """The render and refresh threads of one :class:`EngineState`.

    Parameters
    ----------
    st : EngineState
    scheduler : Scheduler, optional
        The render thread (default: renders in this process).
    refresh : RefreshLoop, optional
        The refresh thread (default: frames counted, handed to no one).
    """

    def __init__(self, st: EngineState, scheduler: Scheduler | None = None,
                 refresh: RefreshLoop | None = None) -> None:
        self.st = st
        self.scheduler = scheduler or Scheduler(st)
        self.refresh = refresh or RefreshLoop(st)
        self._threads: list[threading.Thread] = []

    @classmethod
    def local(cls, settings: FrameSettings, sink: Sink | None = None, *,
              max_update_hz: float = 0.0, log: Callable[[str], None] | None = None) -> Engine:
        """An engine that renders in this process and hands its frames to ``sink``."""
        st = EngineState(state=State(engine_settings(settings)))
        return cls(st, Scheduler(st, log, max_update_hz), RefreshLoop(st, sink))

    @property
    def stage(self) -> GalileanStage | None:
        """The refresh thread's Galilean stage (None before its first tick)."""
        return self.refresh.stage

    def start(self) -> None:
        """Start the render and the refresh threads."""
        for name, target in (("render", self.scheduler.run), ("refresh", self.refresh.run)):
            t = threading.Thread(target=target, name=name, daemon=True)
            t.start()
            self._threads.append(t)

    def load_scene(self, scene: Scene) -> int:
        """Replace the scene; its version (frames of the scenes before are not shown).

        Level-of-detail chains the scene lacks start building at once.
        """
        version = self.st.state.load(scene)
        self.st.queue_chains()
        return version

    def move(self, scene: Scene) -> None:
        """The same scene's objects in new states as of now (``update_objects``)."""
        self.st.state.move(scene)

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop both threads (each gets ``timeout_s`` to finish) and any chain build."""
        self.st.stop.set()
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(timeout_s)
        self._threads.clear()
        self.scheduler.close()
