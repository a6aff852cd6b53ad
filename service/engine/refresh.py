"""The refresh thread (:class:`RefreshLoop`): the Galilean stage at the refresh rate.

The refresh thread ticks at the refresh rate on an absolute schedule, hands finished
updates to the Galilean stage, latches the viewer's pose, refreshes and hands the
frame on (:meth:`RefreshLoop.publish`: to a callback here; the render service's
:class:`service.net.refresh.ServiceRefresh` publishes it on the frame stream and
takes the pose from the devices).  It never waits for a render; a render that
misses its rendezvous is counted (``incomplete_updates``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

from service.autostereogram.output import SirdOutput
from service.engine.state import EngineState, Settings
from service.galilean import GalileanSettings, GalileanStage


def _sird_output(settings: Settings) -> Any:
    """The ``autostereogram`` encoding's state for these settings, or None when it is off."""
    if "autostereogram" not in settings.encodings:
        return None

    d = settings.display
    return SirdOutput(d.cols, d.rows, d.width, settings.sird_method, settings.sird_eye_sep)



def stage_settings(settings: Settings) -> GalileanSettings:
    """The service's Galilean stage.

    It holds (``GalileanSettings.hold``, the default): a render is propagated for
    at most ``n_prop`` refreshes; past that, until the next render comes, each
    frame shows the last render as it was (header ``held``), never a smear
    extrapolated past the rating.
    """
    return GalileanSettings(order=settings.galpixel_order, refresh_hz=settings.refresh_hz)


#: What a refresh thread hands each frame to: (the refresh, how it was made, settings).
#: ``made`` holds ``render_id``, ``since_render``, ``t_render_ns``, ``scene`` and ``ms``.
Sink = Callable[[Any, dict[str, Any], Settings], None]


class RefreshLoop:
    """The refresh thread: stage, viewer, frames, at a fixed rate.

    Parameters
    ----------
    st : EngineState
    sink : callable, optional
        Gets each frame (:data:`Sink`); none: frames are made and counted only.
    """

    def __init__(self, st: EngineState, sink: Sink | None = None) -> None:
        self.st = st
        self.sink = sink
        self.stage: GalileanStage | None = None
        self.generation = -1
        #: the newest scene load the stage knows of, and the one the shown render is of
        self.scene_load = 0
        self.shown_scene = 0
        #: rendezvous -> (render id, t_render_ns, scene load)
        self.due: dict[int, tuple[int, int, int]] = {}
        self.render_id = -1
        self.t_render_ns = 0
        self.since = 0
        self.prepared: tuple[Any, dict[str, Any]] | None = None
        #: ticks skipped before the coming one (their periods count towards a use-by)
        self.missed = 0
        self.sird = None  # service.autostereogram.SirdOutput while that encoding is on

    def _restart(self, settings: Settings) -> None:
        self.stage = GalileanStage(settings.display, stage_settings(settings))
        self.generation = settings.generation
        self.sird = _sird_output(settings)
        self.due.clear()
        self.render_id, self.since = -1, 0
        self.prepared = None

    def run(self) -> None:
        """Tick until the service stops."""
        st = self.st
        next_t = time.monotonic()
        try:
            while not st.stop.is_set():
                settings = st.state.settings
                if settings.generation != self.generation:
                    self._restart(settings)
                period = 1.0 / settings.refresh_hz
                st.clock = (  # the refresh computed now is shown at the next tick
                    self.stage.index,
                    next_t + period,
                    self.generation,
                    self.stage.fixed,
                    settings.galpixel_order,
                )
                try:
                    self._tick(settings)
                except Exception as exc:  # a bug must not stop the display: log, restart
                    st.counters.n["refresh_errors"] += 1
                    st.last_refresh_error = f"{type(exc).__name__}: {exc}"
                    self._restart(settings)
                next_t = self._wait(next_t + period, period)
        finally:
            self.close()

    def _wait(self, next_t: float, period: float) -> float:
        """Sleep until ``next_t``; past a whole period late, skip the missed ticks."""
        now = time.monotonic()
        if now - next_t > period:
            missed = math.floor((now - next_t) / period)
            self.st.counters.n["refresh_overruns"] += missed
            self.missed += missed
            next_t += missed * period
        if next_t > now:
            self.st.stop.wait(next_t - now)
        self.st.counters.tick_late_ms.append((time.monotonic() - next_t) * 1e3)
        return next_t

    def _tick(self, settings: Settings) -> None:
        """Publish the frame prepared last tick, then prepare the next one.

        The pose is latched at the start of the tick and the frame goes out at once
        (as a display scans out at vsync what was computed before it); the refresh
        for the next tick is computed afterwards, so its cost and jitter do not sit
        between the newest pose and the published frame.
        """
        st, c = self.st, self.st.counters
        self.latch(settings)  # the newest pose picks the zone
        if st.state.scene_load > self.scene_load:
            self._new_scene(st.state.scene_load)
        if self.prepared is not None:
            self.publish(*self.prepared, settings)
        else:
            self.idle()
        t0 = time.perf_counter()
        self._submit()
        r = self.stage.refresh(1 + self.missed)
        self.missed = 0
        c.n["refreshes"] += 1
        c.n["held_refreshes"] += r.flags["held"]
        c.held = r.flags["held"]
        c.refresh_t.append(time.monotonic())
        if r.flags["updated"] and r.index in self.due:
            self.render_id, self.t_render_ns, self.shown_scene = self.due.pop(r.index)
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
            zone = self.st.state.viewer.zone
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
                    "scene": self.shown_scene,
                    "ms": ms,
                },
            )

    def _submit(self) -> None:
        st = self.st
        while st.updates:
            up = st.updates.popleft()
            if up.generation != self.generation:
                continue
            rd = up.rendered
            if up.scene_load > self.scene_load:  # loaded after this tick's check
                self._new_scene(up.scene_load)
            elif up.scene_load < self.scene_load:  # rendered from a scene replaced since
                continue
            # no guard reset on object updates: a changed motion is what the order
            # guard is for; a new scene resets it (new_scene), as a new object does
            # (another count of control points)
            ok = self.stage.submit(
                up.buffer,
                up.rendezvous,
                None,
                True,
                (),
                rd.points,
                rd.point_derivs,
                rd.viewer_motion,
                up.use_by,
            )
            if ok:
                self.due[up.rendezvous] = (up.render_id, up.t_render_ns, up.scene_load)
            else:
                st.counters.n["late_refused"] += 1
                st.counters.n["incomplete_updates"] += 1

    def _new_scene(self, loaded: int) -> None:
        """A scene load: a discontinuity for the stage (``docs/protocol.md`` 2).

        The stage forgets the old scene's galpixels and pending grafts and shows
        nothing until the new scene's first render is grafted; until then no frame
        is published (heartbeats only), so no frame shows the old scene after it.
        """
        self.stage.new_scene()
        self.scene_load = loaded
        self.due.clear()
        self.render_id, self.since = -1, 0
        self.prepared = None

    def latch(self, settings: Settings) -> None:
        """Take the viewer's newest pose (here: as set) and pick its zone."""
        self.st.state.viewer.pick_zone(settings.display)

    def publish(self, r: Any, made: dict[str, Any], settings: Settings) -> None:
        """Hand a frame on (to the sink)."""
        if self.sink is not None:
            self.sink(r, made, settings)

    def idle(self) -> None:
        """A tick with no frame to hand on (no render grafted yet)."""

    def close(self) -> None:
        """The thread ends: release what it holds."""
