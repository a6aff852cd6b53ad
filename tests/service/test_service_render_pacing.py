"""In-process renders keep pace with the refresh clock instead of queueing ever further ahead."""

from __future__ import annotations

from testkit import wait_until

from service.client import ServiceClient


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
