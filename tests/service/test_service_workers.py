"""Scale-out workers: a worker killed mid-render, the band is resent, nothing hangs."""

from __future__ import annotations

import contextlib
import os
import signal

from testkit import wait_until

from service.net.client import FrameSubscriber, ServiceClient


def _busy_pid(c: ServiceClient, known: list[int]) -> int | None:
    info = c.stats()["workers"] or {}
    for w in info.get("workers", []):
        if w["busy"] and w["pid"] in known:
            return w["pid"]
    return None


def test_worker_killed_mid_render(service_factory):
    """A worker stopped holding a job: it is killed, the job resent, the survivor renders on.

    The worker is stopped (SIGSTOP) rather than killed: killed straight away it could
    finish its job between the stats reply that showed it busy and the kill (a
    machine under load widens that gap), and then nothing is lost and nothing is
    resent.  A stopped worker cannot answer, so a job is stranded with it for
    certain: the one it holds, or the next the broker gives it.  Its silence gets it
    killed by the supervisor (tests/service/test_service_supervision.py has more).
    """
    svc = service_factory(
        "--scene", "game", "--zones", "5", "--size", "160x120", "--workers", "2",
        "--render-timeout", "1.5", "--refresh", "30",
    )  # fmt: skip
    with ServiceClient(svc.control, timeout_s=5) as c, FrameSubscriber(svc.frames) as frames:
        pids = c.stats()["worker_pids"]
        assert len(pids) == 2
        assert wait_until(lambda: c.stats()["updates"] >= 2, 90), "workers never rendered"
        victim = wait_until(lambda: _busy_pid(c, pids), 20, 0.005)
        assert victim, "no worker was seen mid-render"
        retried = c.stats()["band_retries"]
        os.kill(victim, signal.SIGSTOP)
        try:
            assert wait_until(lambda: c.stats()["band_retries"] > retried, 30), (
                "the stopped worker's job was never resent")
            before = c.stats()["updates"]
        finally:
            with contextlib.suppress(ProcessLookupError):
                os.kill(victim, signal.SIGKILL)
        header, arrays = c.render_once()  # answered by the surviving worker
        assert arrays["colour"].shape == (5, 120, 160, 3)
        assert wait_until(lambda: c.stats()["updates"] >= before + 3, 30), "updates stopped"
        live = lambda: [w["pid"] for w in c.stats()["workers"]["workers"]]  # noqa: E731
        assert wait_until(lambda: victim not in live(), 10), "the dead worker is still listed"
        assert victim not in c.stats()["worker_pids"]

        def fresh_frame():  # the subscriber's queue may still hold frames from before
            got = frames.next(1.0)
            return got is not None and got[0]["render_id"] >= header["render_id"]

        assert wait_until(fresh_frame, 20), "frames stopped after the worker died"


def test_workers_render_whole_frames_in_flight_together(service_factory):
    """Two workers keep two whole-frame renders in flight (pipelining), not two bands."""
    svc = service_factory(
        "--scene", "game", "--zones", "2", "--size", "64x48",
        "--workers", "2", "--refresh", "30",
    )  # fmt: skip
    with ServiceClient(svc.control, timeout_s=5) as c:
        assert wait_until(lambda: c.stats()["updates"] >= 4, 90), "workers never rendered"
        assert wait_until(lambda: (c.stats()["max_in_flight"] or 0) >= 2, 60), "never 2 in flight"
        st = c.stats()
        assert st["split"] == "frames"
        # one job per render (bands would dispatch two per render)
        assert st["workers"]["dispatched"] <= st["renders"] + st["render_retries"] + 2
        header, arrays = c.render_once()
        assert header["stats"]["mode"] == "frames" and header["stats"]["rows"] == [0, 48]
        assert header["stats"]["polygons"]["in"] > 0
        assert arrays["colour"].shape == (2, 48, 64, 3)
