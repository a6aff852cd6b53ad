"""Loading scenes of other sizes while the service runs: refreshes and renders go on."""

from __future__ import annotations

from testkit import wait_until

from service.net.client import ServiceClient


def _counts(c: ServiceClient) -> tuple[int, int]:
    s = c.stats()
    return s["refreshes"], s["renders"]


def test_scenes_with_other_vertex_counts_keep_the_refresh_thread_alive(small_service):
    with ServiceClient(small_service.control, timeout_s=10) as c:
        for builtin in ("sphere-torus", "cyclic", "game", "threaded"):
            polygons = c.load_scene(builtin=builtin)["polygons"]
            assert polygons > 0
            refreshes, renders = _counts(c)
            # several renders of the new scene grafted, and the refresh clock still ticking
            assert wait_until(lambda r=renders: _counts(c)[1] >= r + 3, 60), builtin
            assert wait_until(lambda r=refreshes: _counts(c)[0] >= r + 10, 30), builtin
        s = c.stats()
        assert s["last_refresh_error"] == ""
        assert s["last_render_error"] == "" and s["refresh_errors"] == 0, s
