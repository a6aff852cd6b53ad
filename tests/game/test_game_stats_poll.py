"""The game's ``stats`` polls (level-of-detail notes) never stall a tick.

A stand-in service (``slow_stats_service.py``, a real process on 127.0.0.1) answers
every request at once but ``stats`` late: the first reply never comes (within a
test), later ones after 0.35 s (:data:`LATER_S` in the tick test).  Waiting inside
the tick (the backend's request timeout) made such ticks as long as the reply's
delay; now the request goes out, a later tick picks the reply up, and one that never
comes in time is dropped without stopping the polls.

The checks are on what happens, not on how long it takes, so a loaded machine only
slows them: a tick that returns while its stats request is still out did not wait
for the reply (however long the tick took), and the replies that must be taken
come well inside the time allowed them.
"""

from __future__ import annotations

import contextlib
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import zmq
from testkit import HANG_S, ROOT, wait_for, wait_until

from game.backends import ServiceBackend
from game.client_loop import GameClient, LoopSettings
from game.display import GameWindow
from game.scene import game_scene
from service.base.errors import ServiceError
from service.display import DisplaySettings
from service.frame_settings import FrameSettings
from service.lod.settings import LodSettings
from service.net.client import PendingRequest
from service.render.pipeline import RenderSettings

TICK_HZ = 30.0
#: The first ``stats`` reply's delay: longer than any test, so it is always dropped.
NEVER_S = 3600.0
#: The tick test's later stats replies come LATER_S late, taken if within REPLY_S:
#: a 2.5 s margin for a loaded machine (a reply taken late is dropped, not an error)
LATER_S, REPLY_S = 0.5, 3.0


@contextlib.contextmanager
def _stand_in(first_s: float, later_s: float) -> Iterator[tuple[str, str]]:
    """The stand-in service with stats replies ``first_s`` (first), ``later_s`` late."""
    script = Path(__file__).with_name("slow_stats_service.py")
    proc = subprocess.Popen([sys.executable, str(script), str(first_s), str(later_s)],
                            cwd=ROOT, stdout=subprocess.PIPE, stdin=subprocess.DEVNULL,
                            text=True)
    try:
        words = proc.stdout.readline().split()
        assert words[:1] == ["control"], f"the stand-in did not start: {words}"
        yield words[1], words[3]
    finally:
        proc.kill()
        proc.wait(10)


@pytest.fixture
def slow_service():
    """The stand-in service with stats replies never (first) and 0.35 s (later) late."""
    with _stand_in(NEVER_S, 0.35) as addresses:
        yield addresses


@pytest.fixture
def slower_service():
    """The stand-in with stats replies never (first) and :data:`LATER_S` late."""
    with _stand_in(NEVER_S, LATER_S) as addresses:
        yield addresses


def test_slow_stats_replies_do_not_lengthen_ticks(slower_service, pygame_headless):
    control, frames = slower_service
    settings = FrameSettings(DisplaySettings(zones=3, cols=32, rows=24),
                               RenderSettings(lod=LodSettings(error_px=0.5)))
    backend = ServiceBackend(control, frames, settings=settings)
    backend.lod_poll_s, backend.lod_reply_s = 0.2, REPLY_S
    backend.start(game_scene(1))
    assert backend.connected
    client = GameClient(backend, GameWindow((320, 200)), LoopSettings(tick_hz=TICK_HZ))
    kept_waiting = []  # ticks that returned with their stats request still out

    def tick() -> bool:
        req = backend._stats
        out = None if req is None or not req.waiting else req.sent
        client.tick()
        kept_waiting.append(out is not None and backend._stats.waiting
                            and backend._stats.sent == out)
        return backend.stats_dropped >= 1 and len(client.lod_notes) >= 2

    try:
        if not wait_until(tick, HANG_S, step_s=0.0):
            pytest.fail(f"dropped {backend.stats_dropped}, notes {client.lod_notes}")
    finally:
        backend.close()
    # a tick that waited for the reply would never end with the same request out
    assert sum(kept_waiting) >= 2, kept_waiting
    notes = [n for _, n in client.lod_notes]
    assert "slow note 1" not in notes  # dropped after REPLY_S: its reply never came
    assert notes[:2] == ["slow note 2", "slow note 3"]  # the polls went on


def test_pending_request_never_waits_for_a_reply():
    silent = zmq.Context.instance().socket(zmq.ROUTER)  # takes requests, never answers
    silent.setsockopt(zmq.LINGER, 0)
    port = silent.bind_to_random_port("tcp://127.0.0.1")
    req = PendingRequest(f"tcp://127.0.0.1:{port}", timeout_s=HANG_S)
    try:
        assert req.send("stats") and not req.send("stats")  # one at a time
        wait_for(lambda: silent.poll(0), HANG_S, "the request to arrive")
        # a poll that waited would not come back before the reply or HANG_S
        assert req.poll() is None and req.waiting and req.dropped == 0
    finally:
        req.close()
        silent.close()


def test_pending_request_drops_a_late_reply_and_asks_again(slow_service):
    control, _ = slow_service
    req = PendingRequest(control, timeout_s=0.5)
    try:
        assert req.send("stats")  # the first stats reply never comes
        assert wait_until(lambda: req.poll() is None and not req.waiting, HANG_S)
        assert req.dropped == 1
        req.timeout_s = HANG_S  # the later replies (0.35 s) must all be taken
        assert req.send("stats")
        got = wait_until(req.poll, HANG_S)
        assert got["stats"]["lod"]["chains"]["notes"] == ["slow note 2"]
        assert (req.sent, req.answered, req.dropped) == (2, 1, 1)
        assert req.send("no_such_type")
        with pytest.raises(ServiceError, match="type must be one of"):  # an error reply
            wait_until(req.poll, HANG_S)
        assert not req.waiting
    finally:
        req.close()
