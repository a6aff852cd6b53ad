"""The subscriber path: its own context and I/O thread, and ``latest`` skips stale frames."""

from __future__ import annotations

import zmq
from testkit import wait_until

from service.net.client import FrameSubscriber, ServiceClient


def test_latest_returns_the_newest_queued_frame(small_service):
    with (
        FrameSubscriber(small_service.frames, hwm=100) as sub,
        ServiceClient(small_service.control) as c,
    ):
        assert sub._ctx is not zmq.Context.instance(), "frames share the caller's I/O thread"
        first = wait_until(lambda: sub.next(1.0), 90)
        assert first, "no frames"
        seq0 = first[0]["seq"]
        # let frames queue up in the subscriber unread
        assert wait_until(lambda: c.stats()["frames_published"] >= seq0 + 4, 30)
        assert wait_until(lambda: sub._sock.poll(0), 10)
        header, arrays = sub.latest(1.0)
        assert header["seq"] >= seq0 + 3 and sub.skipped >= 1
        assert arrays["colour"].shape == (2, 24, 32, 3)
