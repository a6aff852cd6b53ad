"""A service whose renders stop holds the last render, and says so (seed 002 use-by).

Renders come once every 4 s (``--max-update-hz 0.25``), more than 3 s of refreshes
apart: the frames go on at the refresh rate, propagated for ``use_by`` refreshes
after the last render, then showing that render bit for bit (``held`` in the frame
header and in ``stats``); the next render ends the hold.  (A stopped worker no
longer stops the renders: it is killed and replaced, and the service renders in
process meanwhile; ``docs/service.md``, "Supervised workers".)
"""

from __future__ import annotations

import time

import numpy as np
from testkit import HANG_S, wait_until

from service.net.client import FrameSubscriber, ServiceClient

HZ = 30
STARVED = 3 * HZ  # refreshes without a render


def _starve(frames: FrameSubscriber, c: ServiceClient) -> tuple[dict, dict, dict]:
    """Frames until one is ``STARVED`` refreshes past its render.

    Returns the frames of the last render (since_render -> (header, arrays)), and
    ``stats`` taken while held.
    """
    seen: dict[int, dict[int, tuple]] = {}
    held_stats: dict = {}
    deadline = time.monotonic() + HANG_S
    while time.monotonic() < deadline:
        got = frames.next(1.0)
        if got is None:
            continue
        header, arrays = got
        seen.setdefault(header["render_id"], {})[header["since_render"]] = (header, arrays)
        if header["held"] and not held_stats:
            held_stats = c.stats()
        if header["since_render"] >= STARVED:
            return seen[header["render_id"]], held_stats
    raise AssertionError("renders never stopped for 3 s")


def test_renders_that_stop_coming_leave_the_last_render_held_not_extrapolated(
        service_factory):
    svc = service_factory(
        "--scene", "game", "--zones", "2", "--size", "48x32", "--workers", "1",
        "--max-update-hz", "0.25", "--refresh", str(HZ),
    )  # fmt: skip
    with ServiceClient(svc.control, timeout_s=5) as c, FrameSubscriber(svc.frames) as frames:
        assert wait_until(lambda: c.stats()["updates"] >= 1, HANG_S), "the service never rendered"
        last, held_stats = _starve(frames, c)
        assert 0 in last, "the frame showing the last render itself was not received"
        render_header, render = last[0]
        use_by = render_header["use_by"]
        # the rating, or less: the game's attackers spin 45 degrees in 15.7 refreshes
        assert use_by == 15 and not render_header["held"]
        held = 0
        for since, (header, arrays) in sorted(last.items()):
            # held past the use-by; sooner when the loaded refresh thread missed ticks
            assert header["held"] or since <= use_by, header
            if header["held"]:  # every pixel the render's own: none from an expired galpixel
                held += 1
                for name in ("colour", "depth"):
                    assert np.array_equal(arrays[name], render[name]), (since, name)
        assert held >= STARVED - use_by - 10  # a few frames may be dropped, not many
        assert held_stats["held"] is True and held_stats["held_refreshes"] > 0
        # the next render ends the hold
        assert wait_until(lambda: (f := frames.next(1.0)) is not None
                          and f[0]["render_id"] > render_header["render_id"]
                          and not f[0]["held"], HANG_S), "no render after the hold"
        assert wait_until(lambda: c.stats()["held"] is False, HANG_S)
