"""The render thread: aim renders at rendezvous, render them, hand them on.

Renders are aimed a little in the future (a rendezvous: a refresh index of the
Galilean stage, :meth:`Scheduler.aim`) and rendered in this process
(:func:`service.engine.jobs.render_job`).  A finished render goes to the refresh
thread (``EngineState.updates``) and to waiting ``render`` requests
(``EngineState.render_results``).  The render service's scheduler
(:class:`service.net.scheduler.WorkerScheduler`) is this one sending the same jobs
to worker processes, as bands of hololines or as whole frames.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from service.base.errors import HoloError
from service.engine.jobs import StatsRenderer, render_job, stitch
from service.engine.state import Aim, EngineState, Ready, Settings
from service.galilean import GalileanSettings
from service.galilean.local_update import render_use_by
from service.net import wire
from service.net.settings_wire import display_to_wire, render_to_wire
from service.quality import QualityChooser, QualitySettings, choose, parse_budget
from service.render.pipeline import Renderer
from service.render.scene import MotionState, Scene

#: Level-of-detail notes (a failed chain build, a damaged cache) remembered so each is
#: logged once, however many renders and workers report it.
LOD_NOTES_LOGGED = 256


class Scheduler:
    """The render thread of an :class:`EngineState` (:meth:`run`).

    ``log`` (the service's one-line log) hears each new level-of-detail note once:
    a chain whose build failed, a damaged cache file rebuilt.  ``max_update_hz``
    (0: none) caps how often a render starts.
    """

    def __init__(self, st: EngineState, log: Callable[[str], None] | None = None,
                 max_update_hz: float = 0.0) -> None:
        self.st = st
        self.max_update_hz = max_update_hz
        self.log = log or (lambda line: None)
        self._lod_notes: dict[str, None] = {}  # insertion-ordered: the oldest go first
        self._last_aim: tuple[int, int] = (-1, -1)  # (generation, rendezvous) last aimed at
        self._chooser: tuple[int, QualityChooser] | None = None  # (generation, chooser)
        #: renders in process (in the service: while no worker lives)
        self._local = StatsRenderer()
        self._local.lod.builds = st.chains  # chains queued at load are this renderer's
        self.local_ms: deque[float] = deque(maxlen=50)  # their times, ms
        self._local_renders = 0

    def run(self) -> None:
        """Render in this process until the engine stops (at most ``max_update_hz``)."""
        self.loop(self.local(), lambda: None)

    def loop(self, renderer: Renderer, remote: Callable[[], Any]) -> None:
        """Render one update after another: in process, or through ``remote()``.

        ``remote()`` gives the band client to render through, or None to render in
        process (no live worker).  With ``max_update_hz`` a render starts no sooner
        than its period after the one before.
        """
        render_id, last_start = 0, 0.0
        while not self.st.stop.is_set():
            if self.max_update_hz > 0:
                wait = last_start + 1.0 / self.max_update_hz - time.monotonic()
                if wait > 0 and self.st.stop.wait(wait):
                    break
            last_start = time.monotonic()
            if self.render_once(renderer, remote(), render_id):
                render_id += 1
            elif self.st.stop.wait(0.02):
                break

    def aim(self, render_id: int, local: bool = False) -> Aim | None:
        """Snapshot the scene and aim a render at a rendezvous after every earlier one.

        ``local``: it renders in process now; aimed by the times of renders in process
        (:meth:`render_ms`), not those of the workers' pipelined ones.
        """
        state = self.st.state
        with state.lock:
            scene, scene_t, settings = state.scene, state.scene_t, state.settings
            viewer = state.viewer.render_spec()
            version, loaded = state.scene_version, state.scene_load
        if scene is None or not scene.objects:
            return None
        index, t_index, gen, fixed, order = self.st.clock
        if gen != settings.generation:
            return None
        hz = settings.refresh_hz
        lead = _lead_s(self.render_ms(local))
        rendezvous = index + math.ceil(lead * hz) + 1
        if gen == self._last_aim[0]:
            rendezvous = max(rendezvous, self._last_aim[1] + 1)  # one render per rendezvous
        self._last_aim = (gen, rendezvous)
        t_target = t_index + (rendezvous - index) / hz
        job = {
            "job": render_id,
            "t": t_target - scene_t,
            "refresh_hz": hz,
            "display": display_to_wire(settings.display),
            "render": render_to_wire(settings.render),
            "viewer": viewer,
            "order": order,
        }
        if settings.quality == "auto":
            self.auto(job, scene, settings)
        return Aim(render_id, job, scene, settings, version, rendezvous, fixed, time.monotonic_ns(),
                   loaded)

    def auto(self, job: dict[str, Any], scene: Scene, settings: Settings) -> None:
        """``quality: "auto"``: this render's method and specular, and the choice in the job."""
        gen = settings.generation
        if self._chooser is None or self._chooser[0] != gen:
            self._chooser = (gen, QualityChooser(
                QualitySettings("auto", parse_budget(settings.max_error))))
        q = choose(self._chooser[1], scene, settings.display, settings.render.light.model)
        job["render"] = {**job["render"], "method": q.method, "specular": q.specular}
        job["quality"] = q.as_dict()

    def render_ms(self, local: bool) -> deque[float]:
        """Recent render times, ms: in process (``local``, once there are some), or all."""
        return self.local_ms if local and self.local_ms else self.st.counters.render_ms

    def ahead(self, local: bool = False) -> bool:
        """Whether the last render is aimed past the rendezvous one started now would get.

        Renders one at a time (in process, or in bands) wait for the refresh clock
        then: aiming each at the last rendezvous + 1 while renders are quicker than
        refreshes would queue them ever further ahead (latency and memory growing
        without bound).
        """
        index, _t, gen, _fixed, _order = self.st.clock
        if gen != self._last_aim[0]:
            return False
        hz = self.st.state.settings.refresh_hz
        return self._last_aim[1] >= index + math.ceil(_lead_s(self.render_ms(local)) * hz) + 1

    def render_once(self, renderer: Renderer, remote: Any, render_id: int) -> bool:
        """Render one update (in process when ``remote`` is None); False if none was due."""
        local = remote is None
        if self.ahead(local):
            return False
        aim = self.aim(render_id, local)
        if aim is None:
            return False
        got = self.run_job(renderer, remote, aim)
        if local and self._local_renders > 0:  # the first one loaded the kernels
            self.local_ms.append((time.monotonic_ns() - aim.t0) / 1e6)
        self._local_renders += local
        if got is None:
            self.st.counters.render_ms.append((time.monotonic_ns() - aim.t0) / 1e6)
            self.st.counters.n["render_failures"] += 1
            return False
        return self.deliver(aim, *got)

    def deliver(self, aim: Aim, parts: list[dict[str, np.ndarray]], stats: dict[str, Any]) -> bool:
        """:meth:`finish`, or count a render failure when the parts do not make a render.

        The parts and stats of a render in workers are what the workers sent, and a
        worker may be a remote one of another version: a reply whose arrays do not
        stitch, or whose stats are not what this service reads, fails that render
        (``render_failures``, ``last_render_error``) and the render thread goes on.
        """
        try:
            self.finish(aim, parts, stats)
        except REPLY_ERRORS as exc:
            self.st.counters.n["render_failures"] += 1
            self.st.last_render_error = f"render {aim.render_id}: {type(exc).__name__}: {exc}"
            return False
        return True

    def finish(self, aim: Aim, parts: list[dict[str, np.ndarray]], stats: dict[str, Any]) -> None:
        """Stitch a finished render, hand it to the refresh thread and to render requests."""
        t_stitch = time.perf_counter()
        rendered, buf = stitch(parts, _viewer_motion(aim.job), aim.fixed, aim.job["order"])
        d = aim.settings.display
        if rendered.frame.colour.shape != (d.zones, d.rows, d.cols, 3):
            raise HoloError(f"the render is {rendered.frame.colour.shape[:3]} (zones, rows, "
                            f"columns), the display {(d.zones, d.rows, d.cols)}")
        wall = (time.monotonic_ns() - aim.t0) / 1e6
        self.st.counters.render_ms.append(wall)
        stats = {
            **stats,
            "wall_ms": round(wall, 3),
            "stitch_ms": round((time.perf_counter() - t_stitch) * 1e3, 3),
            "rendezvous": aim.rendezvous,
            "scene": aim.scene_load,
        }
        if "quality" in aim.job:
            stats["quality"] = aim.job["quality"]
            self.observe(aim, parts, stats)
        lod = _lod_of(stats)
        self.st.counters.n["renders"] += 1
        self.st.last_lod = {"render_id": aim.render_id, **lod} if lod else None
        if lod:
            self._log_lod_notes(as_dict(lod.get("chains")).get("notes", ()))
        self.st.updates.append(
            Ready(
                aim.render_id,
                aim.settings.generation,
                aim.rendezvous,
                buf,
                rendered,
                aim.t0,
                aim.scene_version,
                aim.scene_load,
                render_use_by(aim.scene, aim.job["refresh_hz"], GalileanSettings.n_prop,
                              rendered.viewer_motion),
            )
        )
        mark = (aim.settings.generation, aim.scene_version)
        self.st.render_results.put((aim.render_id, aim.t0, rendered.frame, mark, stats))

    def _log_lod_notes(self, notes: Any) -> None:
        """Log the level-of-detail notes not logged before (each once)."""
        for note in map(str, notes if isinstance(notes, list | tuple) else ()):
            if note in self._lod_notes:
                continue
            self._lod_notes[note] = None
            if len(self._lod_notes) > LOD_NOTES_LOGGED:
                del self._lod_notes[next(iter(self._lod_notes))]
            self.log(str(note))

    def observe(self, aim: Aim, parts: list[dict[str, np.ndarray]], stats: dict) -> None:
        """Tell the quality chooser what the render showed (out-of-order points, coverage)."""
        chooser = self._chooser
        if chooser is None or chooser[0] != aim.settings.generation:
            return
        bands = [b for b in stats.get("bands") or [stats] if isinstance(b, dict)]
        bad = sum(int(b.get("inconsistent_pixels", 0)) for b in bands)
        covered = sum(int(np.isfinite(p["depth"]).sum()) for p in parts if "depth" in p)
        chooser[1].observe(aim.job["render"]["method"], {"inconsistent_pixels": bad}, covered)

    def run_job(
        self, renderer: Renderer, remote: Any, aim: Aim
    ) -> tuple[list[dict[str, np.ndarray]], dict[str, Any]] | None:
        """Render in process: (parts, stats), or None (the error in ``last_render_error``).

        ``remote`` is None here; the service's scheduler
        (:class:`service.net.scheduler.WorkerScheduler`) renders through it instead.
        """
        try:
            aim.job["rows"] = [0, aim.settings.display.rows]
            out, stats = render_job(renderer, aim.job, aim.scene)
            return [out], {**stats, "mode": "in_process"}
        except (HoloError, ValueError) as exc:
            self.st.last_render_error = str(exc)
            return None

    def local(self) -> StatsRenderer:
        """The renderer of renders in process."""
        return self._local

    def close(self) -> None:
        """End a level-of-detail chain build still running in its child process."""
        self._local.lod.close()


#: What :meth:`Scheduler.finish` raises on parts and stats that a worker got wrong
#: (arrays missing or of the wrong shapes and types, numbers that are not numbers).
REPLY_ERRORS = (HoloError, ValueError, KeyError, TypeError)


def as_dict(value: Any) -> dict:
    """``value`` when it is a dict, else an empty one (a worker's stats, read defensively)."""
    return value if isinstance(value, dict) else {}


def _lod_of(stats: dict[str, Any]) -> dict | None:
    """The level-of-detail stats of a render: its own, or in bands the first band's."""
    lod = stats.get("lod") or next(
        (b["lod"] for b in stats.get("bands", ()) if isinstance(b, dict) and "lod" in b), None)
    return lod if isinstance(lod, dict) and lod else None


def _lead_s(render_ms: deque[float]) -> float:
    """How far ahead to aim a render: its 90th percentile time plus a little.

    The slowest of the last 3 renders counts too, so a machine that just got slower
    (load, workers restarting beside the renders) moves the aim at once: with the
    percentile alone, every render missed its rendezvous (refused, no update) until
    five slow ones had come.
    """
    if not render_ms:
        return 0.5
    recent = list(render_ms)
    slow = max(float(np.percentile(recent[-50:], 90)), *recent[-3:])
    return slow / 1e3 * 1.2 + 0.01


def _viewer_motion(job: dict[str, Any]) -> MotionState:
    """The viewer's motion a job was rendered with (for the Galilean stage)."""
    spec = job.get("viewer") or {}
    return MotionState(**{k: np.asarray(v) for k, v in spec.items() if k in wire.MOTION_FIELDS})
