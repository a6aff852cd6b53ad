"""The game's ``stats`` polls (level-of-detail notes) never stall a tick.

A stand-in service (``slow_stats_service.py``, a real process on 127.0.0.1) answers
every request at once but ``stats`` late: the first reply after 2 s, later ones
after 0.35 s (0.9 s in the tick test).  Waiting inside the tick (the backend's
request timeout) made such ticks as long as the reply's delay; now the request goes
out, a later tick picks the reply up, and one that never comes in time is dropped
without stopping the polls.
"""

from __future__ import annotations

import contextlib
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from testkit import ROOT, wait_until

from game.backends import BackendSettings, ServiceBackend
from game.client_loop import GameClient, LoopSettings
from game.display import GameWindow
from game.scene import game_scene
from service.display import DisplaySettings
from service.errors import ServiceError
from service.net.client import PendingRequest

TICK_HZ = 30.0
#: The tick test's stats replies: 2 s late (first, dropped at REPLY_S) then LATER_S.
LATER_S, REPLY_S = 0.9, 1.5
#: the longest tick allowed: a 33 ms tick plus room for a loaded machine (a tick of
#: 0.25 s was seen at load 12), well under the LATER_S a blocking request would add
LONGEST_TICK_S = 0.6


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
    """The stand-in service with stats replies 2 s (first) and 0.35 s (later) late."""
    with _stand_in(2.0, 0.35) as addresses:
        yield addresses


@pytest.fixture
def slower_service():
    """The stand-in with stats replies 2 s (first) and :data:`LATER_S` late."""
    with _stand_in(2.0, LATER_S) as addresses:
        yield addresses


def test_slow_stats_replies_do_not_lengthen_ticks(slower_service, pygame_headless):
    control, frames = slower_service
    settings = BackendSettings(DisplaySettings(zones=3, cols=32, rows=24), lod_error=0.5)
    backend = ServiceBackend(control, frames, settings=settings)
    backend.lod_poll_s, backend.lod_reply_s = 0.2, REPLY_S
    backend.start(game_scene(1))
    assert backend.connected
    client = GameClient(backend, GameWindow((320, 200)), LoopSettings(tick_hz=TICK_HZ))
    ticks: list[float] = []

    def tick() -> bool:
        t0 = time.monotonic()
        client.tick()
        ticks.append(time.monotonic() - t0)
        return backend.stats_dropped >= 1 and len(client.lod_notes) >= 2

    try:
        if not wait_until(tick, 30, step_s=0.0):
            pytest.fail(f"dropped {backend.stats_dropped}, notes {client.lod_notes}")
    finally:
        backend.close()
    assert max(ticks) < LONGEST_TICK_S, sorted(ticks)[-5:]
    notes = [n for _, n in client.lod_notes]
    assert "slow note 1" not in notes  # dropped after REPLY_S: its reply came after 2 s
    assert notes[:2] == ["slow note 2", "slow note 3"]  # the polls went on


def test_pending_request_drops_a_late_reply_and_asks_again(slow_service):
    control, _ = slow_service
    req = PendingRequest(control, timeout_s=0.5)
    try:
        assert req.send("stats") and not req.send("stats")  # one at a time
        t0 = time.monotonic()
        assert req.poll() is None and time.monotonic() - t0 < 0.05  # never waits
        assert wait_until(lambda: req.poll() is None and not req.waiting, 5)
        assert req.dropped == 1
        assert req.send("stats")
        got = wait_until(req.poll, 5)  # the second is answered in 0.35 s
        assert got["stats"]["lod"]["chains"]["notes"] == ["slow note 2"]
        assert (req.sent, req.answered, req.dropped) == (2, 1, 1)
        assert req.send("no_such_type")
        with pytest.raises(ServiceError, match="type must be one of"):  # an error reply
            wait_until(req.poll, 5)
        assert not req.waiting
    finally:
        req.close()
