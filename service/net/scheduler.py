"""The service's render thread: the engine's scheduler, rendering in worker processes.

:class:`WorkerScheduler` is :class:`service.engine.scheduler.Scheduler` (aims,
rendezvous, hand-off to the refresh thread) with the workers as its transport:
as bands of hololines through the broker (``split: bands``), or as whole frames,
one in flight per worker (``split: frames``, :meth:`WorkerScheduler.pipeline_loop`);
a job past its deadline is re-aimed and resent (:meth:`WorkerScheduler.retry`).
With no live worker it renders in process, as the engine alone does.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from service.base.errors import HoloError
from service.engine.scheduler import Scheduler, as_dict
from service.engine.state import Aim
from service.net import wire
from service.net.broker import BandClient, Flight, FramePipe, split_rows
from service.net.state import ServiceState
from service.render.pipeline import Renderer


class WorkerScheduler(Scheduler):
    """The render thread of a :class:`ServiceState`: renders go to its workers."""

    def __init__(self, st: ServiceState, log: Callable[[str], None] | None = None) -> None:
        super().__init__(st, log, st.config.max_update_hz)
        self.st: ServiceState = st

    def run(self) -> None:
        """Render until the service stops: whole frames, bands, or in process."""
        if self.st.broker is not None and self.st.config.split == "frames":
            self.pipeline_loop()
            return
        if self.st.broker is None:
            super().run()
            return
        bands = BandClient(self.st.ctx, "inproc://holo-broker", self.st.config.render_timeout_s,
                           stop=self.st.stop, has_workers=self.st.to_workers)
        try:
            self.loop(self.local(), lambda: bands if self.st.to_workers() else None)
        finally:
            bands.close()

    def run_job(
        self, renderer: Renderer, remote: BandClient | None, aim: Aim
    ) -> tuple[list[dict[str, np.ndarray]], dict[str, Any]] | None:
        """Render as bands through the broker (in process without ``remote``)."""
        if remote is None:
            return super().run_job(renderer, None, aim)
        try:
            spec, arrays = wire.extract(wire.scene_to_wire(aim.scene))
            n = max(1, self.st.broker.live(), self.st.config.workers)
            rows = split_rows(aim.settings.display.rows, n)
            got = remote.run({**aim.job, "scene": spec}, arrays, rows)
            self.st.band_retries += remote.resent
            remote.resent = 0
            if got is None and not self.st.stop.is_set() and not self.st.to_workers():
                self.st.band_retries += 1  # every worker died: render it here instead
                return super().run_job(renderer, None, aim)
            if got is None:  # a band unanswered after its resends (or the service stopped)
                self.st.last_render_error = (f"render {aim.render_id}: a band got no usable "
                                             "reply from the workers")
                return None
            per_band = [g.pop("_stats", {}) for g in got]
            return got, {"mode": "bands", "method": aim.settings.render.method,
                         "bands": per_band}
        except (HoloError, ValueError) as exc:
            self.st.last_render_error = str(exc)
            return None

    def capacity(self) -> int:
        """Renders to keep in flight: one per worker the broker knows (at least one)."""
        b = self.st.broker
        return max(1, b.live()) if b is not None else 1

    def cap_s(self) -> float:
        """The shortest time between render starts (``--max-update-hz``; 0: no cap)."""
        hz = self.max_update_hz
        return 1.0 / hz if hz > 0 else 0.0

    def spacing_s(self, capacity: int) -> float:
        """Time between dispatches: a render's time over the workers (and the cap)."""
        cap = self.cap_s()
        recent = list(self.st.counters.render_ms)[-20:]
        spread = float(np.median(recent)) / 1e3 / capacity if recent else 0.0
        return max(cap, spread)

    def pipeline_loop(self) -> None:
        """Whole-frame renders for successive rendezvous, one in flight per worker.

        With no live worker (none connected or started yet, or every one dead or
        stuck; see :meth:`ServiceState.to_workers`) it renders in process, so renders
        never wait for a worker that may never come.
        """
        pipe = FramePipe(self.st.ctx, "inproc://holo-broker", self.st.config.render_timeout_s)
        self.st.pipe = pipe
        render_id, next_start = 0, 0.0
        try:
            while not self.st.stop.is_set():
                capacity, remote = self.capacity(), self.st.to_workers()
                now = time.monotonic()
                if not remote and now >= next_start:
                    done = self.render_once(self.local(), None, render_id)
                    render_id += int(done)
                    next_start = now + (self.cap_s() if done else 0.02)
                elif remote and len(pipe.flights) < capacity and now >= next_start:
                    # renders quicker than refreshes (a low refresh_hz) would otherwise be
                    # aimed one rendezvous past the last, ever further into the future
                    aim = None if self.ahead() else self.aim(render_id)
                    if aim is None:
                        next_start = now + 0.02
                    else:
                        self.dispatch(pipe, aim, 0)
                        render_id += 1
                        next_start = now + self.spacing_s(capacity)
                full = remote and len(pipe.flights) >= capacity
                wait = 50 if full else (next_start - time.monotonic()) * 1000
                for flight, head in pipe.poll(min(50, max(0, int(wait)))):
                    self.landed(flight, head)
                for flight in pipe.expired():
                    self.retry(pipe, flight)
        finally:
            pipe.close()

    def dispatch(self, pipe: FramePipe, aim: Aim, attempt: int) -> None:
        """Send a whole-frame job (the aim's scene and settings) to the workers."""
        spec, arrays = wire.extract(wire.scene_to_wire(aim.scene))
        job = {**aim.job, "rows": [0, aim.settings.display.rows], "scene": spec}
        pipe.send(job, arrays, aim, attempt)

    def landed(self, flight: Flight, head: dict[str, Any]) -> None:
        """A worker's whole-frame reply: stitch and hand it on (or count the failure)."""
        if not head.get("ok") or not isinstance(head.get("arrays"), dict):
            self.st.counters.n["render_failures"] += 1
            self.st.last_render_error = str(head.get("error", "bad worker reply"))
            return
        stats = {**as_dict(head.get("stats")), "mode": "frames", "attempt": flight.attempt}
        self.deliver(flight.meta, [head["arrays"]], stats)

    def retry(self, pipe: FramePipe, flight: Flight) -> None:
        """A job lost with its worker or past its deadline: re-aim it and resend it.

        The resend is aimed at a new rendezvous from the present, so the render is
        never grafted late.  With no live worker left, or none idle to take it now
        (the others busy, or stopped and not yet found dead: queued behind them it
        would come too late for its rendezvous), it renders in process now; after 3
        resends it counts as failed.  Each counts in ``jobs_resent``.
        """
        self.st.band_retries += 1
        if not self.st.to_workers() or self.st.broker.idle() == 0:  # render it here, now
            self.render_once(self.local(), None, flight.meta.render_id)
            return
        aim = self.aim(flight.meta.render_id) if flight.attempt < 3 else None
        if aim is None:
            self.st.counters.n["render_failures"] += 1
            self.st.last_render_error = f"render {flight.meta.render_id}: no worker answered"
            return
        self.dispatch(pipe, aim, flight.attempt + 1)
