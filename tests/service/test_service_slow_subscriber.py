"""A slow subscriber: the service's memory stays flat, fast ones keep up.

The check runs until the service has published well past what a queue for the
slow subscriber could hold without showing (300+ MB, five times the growth bound)
and the slow subscriber has read 10 frames at one a second: about 10 s on a quiet
machine, 20 s at most (a fixed 20 s before).

The memory is measured from a baseline taken once the service runs steadily (its
third update), not at its first frame: the first updates allocate the refresh
stage's buffers (measured: +12 MB at the first, +18-20 MB at the second, then flat
within 1 MB for 20 s), and on a loaded machine the first frame comes out before
more of that, so a first-frame baseline read 30-40 MB of start-up as growth at load
4-6 and over the 64 MB bound at load 9-12.  The service keeps freed memory in its
heap for reuse (service.base.heap), so its RSS is the high-water mark of the buffers live
at once, which load still raises a little after warm-up (measured: 4 MB at load 5.5,
17 MB at load 7.9).  What the bound is for, a queue that grows with a subscriber that
cannot keep up, would grow by the frames published past the cap: over 300 MB here.
"""

from __future__ import annotations

import time

import zmq
from testkit import rss_kb, wait_until

from service.net.client import FrameSubscriber, ServiceClient

FRAME_BYTES = 5 * 120 * 160 * 3 + 5 * 120 * 160 * 4  # colour + depth, 672 kB
#: Growth allowed, MB: the frame stream holds at most SNDHWM (2) frames per subscriber
#: (4 MB here) and a render's buffers are reused; a queue that grows would add 300+ MB.
GROWTH_MB = 64
#: Updates after which the service's buffers are all allocated (see the module notes).
WARM_UPDATES = 3
#: Published past the slow subscriber before the check ends, MB: a queue that grew
#: with it would have grown by this much (far over GROWTH_MB).
PRODUCED_MB = 300
#: Frames the slow subscriber reads (one a second at most) before the check ends.
SLOW_READS = 10
#: Frames published since the start before the check ends (at 60 Hz, over 10 s).
TOTAL_FRAMES = 600
#: Longest the check runs, s.
SOAK_S = 20.0


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
    control = ServiceClient(svc.control, timeout_s=5)
    try:
        assert wait_until(lambda: fast.next(1.0), 60), "no frames"
        assert wait_until(lambda: fast.next(0.1) and control.stats()["updates"] >= WARM_UPDATES,
                          60), "the service never reached its third update"
        baseline = rss_kb(svc.proc.pid)
        samples, got_slow, produced_mb = [], 0, 0.0
        start = time.monotonic()
        total = first = control.stats()["frames_published"]
        while time.monotonic() - start < SOAK_S and (
                got_slow < SLOW_READS or produced_mb <= PRODUCED_MB or total <= TOTAL_FRAMES):
            if slow.poll(0):  # one message per second at most: a slow display
                slow.recv_multipart()
                got_slow += 1
            deadline = time.monotonic() + 1.0
            while time.monotonic() < deadline:  # the fast subscriber reads all along
                fast.next(max(0.01, deadline - time.monotonic()))
            samples.append(rss_kb(svc.proc.pid))
            # what the service published so far, whether or not this (loaded) test
            # process read it all: that is what would have queued for the slow subscriber
            total = control.stats()["frames_published"]
            published = total - first
            produced_mb = published * FRAME_BYTES / 2**20
        grown_mb = (max(samples) - baseline) / 1024
        assert got_slow >= SLOW_READS
        assert produced_mb > PRODUCED_MB, \
            "the test needs the service to publish far more than the cap"
        assert grown_mb < GROWTH_MB, (
            f"service RSS grew {grown_mb:.1f} MB with a slow subscriber "
            f"(baseline {baseline // 1024} MB, samples {[s // 1024 for s in samples]} MB)")
        assert fast.frames > published / 4, "the fast subscriber fell behind"
        assert control.stats()["frames_published"] > TOTAL_FRAMES
    finally:
        control.close()
        slow.close(0)
        fast.close()
