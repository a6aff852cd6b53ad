"""A slow subscriber for 20 s: the service's memory stays flat, fast ones keep up."""

from __future__ import annotations

import time

import zmq
from testkit import rss_kb, wait_until

from service.net.client import FrameSubscriber, ServiceClient

FRAME_BYTES = 5 * 120 * 160 * 3 + 5 * 120 * 160 * 4  # colour + depth, 672 kB


def test_slow_subscriber_memory_flat(service_factory):
    svc = service_factory(
        "--scene",
        "game",
        "--zones",
        "5",
        "--size",
        "160x120",
        "--workers",
        "0",
        "--refresh",
        "60",
        "--max-update-hz",
        "2",
    )
    slow = zmq.Context.instance().socket(zmq.SUB)
    slow.setsockopt(zmq.LINGER, 0)
    slow.setsockopt(zmq.RCVHWM, 1)
    slow.setsockopt(zmq.RCVBUF, 65536)
    slow.setsockopt(zmq.SUBSCRIBE, b"")
    slow.connect(svc.frames)
    fast = FrameSubscriber(svc.frames)
    try:
        assert wait_until(lambda: fast.next(1.0), 60), "no frames"
        baseline = rss_kb(svc.proc.pid)
        samples, got_slow = [], 0
        start = time.monotonic()
        fast_frames = fast.frames
        while time.monotonic() - start < 20.0:
            if slow.poll(0):  # one message per second at most: a slow display
                slow.recv_multipart()
                got_slow += 1
            deadline = time.monotonic() + 1.0
            while time.monotonic() < deadline:  # the fast subscriber reads all along
                fast.next(max(0.01, deadline - time.monotonic()))
            samples.append(rss_kb(svc.proc.pid))
        grown_mb = (max(samples) - baseline) / 1024
        produced_mb = (fast.frames - fast_frames) * FRAME_BYTES / 2**20
        assert got_slow >= 10
        assert produced_mb > 300, "the test needs the service to publish far more than the cap"
        assert grown_mb < 64, f"service RSS grew {grown_mb:.1f} MB with a slow subscriber"
        with ServiceClient(svc.control, timeout_s=5) as c:
            assert c.stats()["frames_published"] > 600
    finally:
        slow.close(0)
        fast.close()
