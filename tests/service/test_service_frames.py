"""Frames arrive at the refresh rate, with Galilean refreshes between renders."""

from __future__ import annotations

import time

import pytest
from testkit import wait_until

from service.net.client import FrameSubscriber, ServiceClient


def test_frames_at_refresh_rate_between_renders(service_factory):
    svc = service_factory(
        "--scene",
        "game",
        "--zones",
        "3",
        "--size",
        "64x48",
        "--workers",
        "1",
        "--refresh",
        "30",
        "--max-update-hz",
        "5",
    )
    with FrameSubscriber(svc.frames, hwm=100) as frames, ServiceClient(svc.control) as c:
        assert wait_until(lambda: frames.next(1.0), 90), "no frames"
        headers, start = [], time.monotonic()
        while time.monotonic() - start < 4.0:
            got = frames.next(1.0)
            if got is not None:
                headers.append(got[0])
        span = (headers[-1]["t_ns"] - headers[0]["t_ns"]) / 1e9
        rate = (len(headers) - 1) / span
        assert 30 * 0.85 <= rate <= 30 * 1.1, f"{rate:.1f} frames/s at 30 Hz"
        seqs = [h["seq"] for h in headers]
        assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), "a fast subscriber lost frames"
        renders = {h["render_id"] for h in headers}
        assert len(renders) >= 5, "renders should keep coming (about 5 per second)"
        between = [h for h in headers if h["since_render"] > 0]
        assert len(between) > len(headers) / 2, "most frames come from the Galilean stage"
        assert all(h["since_render"] == 0 for h in headers if h["updated"])
        stamps = [h["t_ns"] / 1e6 for h in headers]
        intervals = [b - a for a, b in zip(stamps, stamps[1:], strict=False)]
        assert sorted(intervals)[len(intervals) // 2] == pytest.approx(33.3, abs=3)
        s = c.stats()
        assert s["refreshes_per_s"] > 25 and s["updates"] >= 5
