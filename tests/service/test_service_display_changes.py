"""``set_display`` at run time: the method, the viewing angle and the refresh rate take effect.

One service for the module (a start costs 1-3 s): the tests run in file order, the
first sees the settings it was started with, the others first put back what the
tests before them changed (:func:`_reset`).
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from testkit import start_service, wait_until

from service.net.client import FrameSubscriber, ServiceClient


@pytest.fixture(scope="module")
def svc():
    """A small in-process service at 30 Hz, every zone looking straight ahead."""
    s = start_service(
        "--scene", "game", "--zones", "3", "--size", "32x24",
        "--workers", "0", "--refresh", "30", "--angle", "0",
    )  # fmt: skip
    try:
        yield s
    finally:
        s.stop()


def _reset(c: ServiceClient) -> None:
    """The display settings the service was started with (what the tests change)."""
    shown = c.set_display(method="zbuffer", angle_deg=0.0, refresh_hz=30.0, quality="fixed")
    assert (shown["method"], shown["angle_deg"], shown["refresh_hz"]) == ("zbuffer", 0.0, 30.0)


def test_method_and_angle_change_the_render(svc):
    with ServiceClient(svc.control, timeout_s=20) as c:
        header, arrays = c.render_once()
        assert header["stats"]["method"] == "zbuffer"
        colour = arrays["colour"]
        assert colour.any(), "nothing rendered"
        # every zone looks along the same direction at 0 degrees
        assert all(np.array_equal(colour[0], colour[z]) for z in (1, 2))
        shown = c.set_display(method="runlength", angle_deg=30.0)
        assert shown["method"] == "runlength" and shown["angle_deg"] == 30.0
        header, arrays = c.render_once()
        assert header["stats"]["method"] == "runlength"
        colour, depth = arrays["colour"], arrays["depth"]
        assert not np.array_equal(colour[0], colour[2]), "30 degrees: zones 0 and 2 should differ"
        assert not np.array_equal(depth[0], depth[2])
        c.set_display(method="bsp")
        assert c.render_once()[0]["stats"]["method"] == "bsp"


def _rate(frames: FrameSubscriber, hz: float, window_s: float) -> tuple[float, float, int]:
    """Frames per second and median interval (ms) over ``window_s`` of frames at ``hz``."""
    assert wait_until(lambda: (f := frames.next(0.5)) and f[0]["refresh_hz"] == hz, 20), hz
    stamps, start = [], time.monotonic()
    while time.monotonic() - start < window_s:
        got = frames.next(1.0)
        if got is not None:
            assert got[0]["refresh_hz"] == hz
            stamps.append(got[0]["t_ns"] / 1e6)
    intervals = np.diff(stamps)
    return 1e3 * len(intervals) / (stamps[-1] - stamps[0]), float(np.median(intervals)), len(stamps)


def test_refresh_rate_change_paces_the_frames(svc):
    with FrameSubscriber(svc.frames, hwm=100) as frames, ServiceClient(svc.control) as c:
        _reset(c)
        rate, median, n = _rate(frames, 30.0, 1.0)
        assert 30 * 0.85 <= rate <= 30 * 1.1 and abs(median - 33.3) < 4, (rate, median, n)
        assert c.set_display(refresh_hz=12.0)["refresh_hz"] == 12.0
        rate, median, n = _rate(frames, 12.0, 2.0)
        assert 12 * 0.85 <= rate <= 12 * 1.1 and abs(median - 83.3) < 6, (rate, median, n)


def test_quality_auto_picks_per_render_and_reports_it(svc):
    from service.base.errors import ServiceError

    with ServiceClient(svc.control, timeout_s=20) as c:
        _reset(c)
        assert c.render_once()[0]["stats"].get("quality") is None  # fixed by default
        shown = c.set_display(quality="auto", max_error="40dB", angle_deg=16.0)
        assert shown["quality"] == "auto" and shown["max_error"] == "40dB"
        for _ in range(2):
            header, arrays = c.render_once()
            q = header["stats"]["quality"]
            assert header["stats"]["method"] == q["method"]
            assert q["method"] in ("runlength", "zbuffer", "bsp")
            assert q["predicted_error"]["psnr"] >= 40.0 and q["reason"]
            assert q["galilean"]["order"] in (0, 1, 2, 3)
            assert arrays["colour"].any()
        for bad in ({"quality": "best"}, {"max_error": "lots"}, {"max_error": [1]}):
            with pytest.raises(ServiceError) as info:
                c.set_display(**bad)
            assert info.value.code == "bad_settings", bad
        assert c.set_display(quality="fixed")["quality"] == "fixed"
        assert c.render_once()[0]["stats"].get("quality") is None
