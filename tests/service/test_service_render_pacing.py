"""Renders keep pace with the refresh clock instead of queueing ever further ahead."""

from __future__ import annotations

import pytest
from testkit import wait_until

from service.net.client import ServiceClient


def test_in_process_renders_are_aimed_near_the_present(small_service):
    # --workers 0 and no --max-update-hz: a tiny render takes a few ms, a refresh
    # period 33 ms; each render must not be aimed one rendezvous past the last
    # (that ran ~5x ahead of the clock, holding every queued galpixmap in memory)
    with ServiceClient(small_service.control, timeout_s=20) as c:
        assert wait_until(lambda: c.stats()["refreshes"] >= 60, 30), "refreshes too slow"
        header, _ = c.render_once()
        s = c.stats()
        ahead = header["stats"]["rendezvous"] - s["refreshes"]
        assert ahead <= 10, f"render aimed {ahead} refreshes ahead of the clock"
        assert s["renders"] <= s["refreshes"] + 10, s
        assert s["updates"] >= s["renders"] - 10, "renders grafted long after they finished"


@pytest.mark.timeout(120)
def test_worker_renders_at_one_refresh_a_second_are_grafted(service_factory):
    # one worker rendering a tiny frame in ~10 ms against a refresh every second: it
    # used to be handed a render per rendezvous, each aimed one past the last, so by
    # the time a frame could show its render was minutes in the future (no update)
    svc = service_factory("--scene", "game", "--zones", "2", "--size", "32x24",
                          "--workers", "1", "--refresh", "2")
    with ServiceClient(svc.control, timeout_s=20) as c:
        assert wait_until(lambda: c.stats()["updates"] >= 3, 60), c.stats()
        s = c.stats()
        in_flight = s["workers"]["dispatched"] - s["renders"]
        assert s["renders"] <= s["refreshes"] + 10 and in_flight <= 2, s
