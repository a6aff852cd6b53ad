"""While the render service warms up, the game says so; its play time counts from the first frame.

With SDL's dummy drivers.  One test talks to a real ``holo-service`` on an empty
numba cache (a temp ``NUMBA_CACHE_DIR``), stopped mid-compile.
"""

from __future__ import annotations

import signal
import sys
import time

import numpy as np
import pytest
from real_service import attract_client
from testkit import HANG_S, launch_service

from game.client_loop import GameClient, LoopSettings, waiting_lines
from game.display import GameWindow
from service.display import DisplaySettings
from service.frame_settings import FrameSettings

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")


class SeenWindow(GameWindow):
    """A real window that also remembers the banners it drew."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.banners: list[tuple[str, list[str]]] = []

    def banner(self, title: str, lines=(), dim: bool = True) -> None:
        self.banners.append((title, list(lines)))
        super().banner(title, lines, dim)


class WarmingThenReady:
    """A backend that warms up for ``ticks`` frame requests, then gives grey frames."""

    def __init__(self, ticks: int, total: int = 15) -> None:
        self.settings = FrameSettings(DisplaySettings(zones=3, cols=32, rows=24))
        self.ticks, self.total, self.seq = ticks, total, 0
        self.connected = False
        self.warming: dict | None = {"phase": "compiling", "done": 0, "total": total}

    def update(self, records) -> None:
        pass

    def frame(self, timeout_s: float = 0.0):
        from game.backends import FrameView

        self.seq += 1
        if self.seq <= self.ticks:
            self.warming = {"phase": "compiling", "done": self.seq * self.total // self.ticks,
                            "total": self.total, "elapsed_s": 0.1 * self.seq}
            return None
        self.connected, self.warming = True, None
        d = self.settings.display
        return FrameView(np.full((d.zones, d.rows, d.cols, 3), 90, np.uint8), self.seq, 1, 0)

    def close(self) -> None:
        pass


def test_the_waiting_screen_shows_the_progress_then_the_game(pygame_headless):
    backend = WarmingThenReady(ticks=5)
    client = GameClient(backend, SeenWindow((320, 240)), LoopSettings(attract=True))
    client.tick()
    title, lines = client.window.banners[-1]
    assert title == "waiting for the render service"
    assert lines[0].startswith("compiling (3/15)"), lines
    t0 = client.state.t
    for _ in range(4):
        client.tick()
    assert client.state.t == t0  # the game waits with the service
    assert client.colour is None and client.first_frame_t is None
    client.tick()
    assert client.colour is not None and client.first_frame_t is not None
    n = len(client.window.banners)
    client.tick()
    assert len(client.window.banners) == n  # no banner once frames come
    assert client.disconnects == 0  # waiting for a warm-up is not a disconnect


def test_waiting_lines_name_the_phase_and_count():
    assert waiting_lines({"phase": "loading", "done": 2, "total": 15, "elapsed_s": 61.4})[0] \
        == "loading (2/15), 61 s"
    assert waiting_lines({})[0] == "compiling"


def test_play_time_counts_from_the_first_frame(pygame_headless):
    now = [0.0]

    def clock() -> float:
        now[0] += 0.05  # each look at the clock is 50 ms later
        return now[0]

    backend = WarmingThenReady(ticks=40)
    client = GameClient(backend, GameWindow((320, 240)), LoopSettings(attract=True),
                        clock=clock)
    client.run(seconds=1.0, wait_s=60.0)
    assert client.first_frame_t is not None and client.first_frame_t > 1.0
    assert client.state.t <= 1.5  # the game too started with the first frame
    assert 1.0 <= client.played_s() < 1.5
    assert client.refreshes.count >= 3


def test_no_frame_within_the_wait_ends_the_run(pygame_headless):
    now = [0.0]

    def clock() -> float:
        now[0] += 0.05
        return now[0]

    client = GameClient(WarmingThenReady(ticks=10**6), GameWindow((320, 240)),
                        LoopSettings(attract=True), clock=clock)
    client.run(seconds=1.0, wait_s=2.0)
    assert client.first_frame_t is None and client.played_s() == 0.0
    assert now[0] < 3.0


@pytest.mark.timeout(150)
def test_a_real_cold_service_shows_the_waiting_screen(pygame_headless, tmp_path):
    # ports of its own choosing (a port picked here could be taken before it binds)
    svc = launch_service(env={"NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")})
    backend = None
    try:
        backend, client = attract_client(svc.control, svc.frames, SeenWindow((320, 240)))
        deadline = time.monotonic() + HANG_S

        def heard_it_compile() -> bool:  # the warm-up says "starting" until it has looked
            banners = client.window.banners  # at the cache: a game can hear that first
            return bool(banners) and banners[-1][0] != "reconnecting" and not (
                banners[-1][1] and banners[-1][1][0].startswith("starting"))

        while not heard_it_compile():
            assert time.monotonic() < deadline, "the game never heard the service warm up"
            client.tick()
        title, lines = client.window.banners[-1]
        assert title == "waiting for the render service"
        assert lines[0].startswith("compiling ("), lines
        assert not backend.connected and client.colour is None
    finally:
        if backend is not None:
            backend.close()
        svc.proc.send_signal(signal.SIGTERM)
        status = svc.proc.wait(HANG_S)
        svc.stop()
    assert status == 128 + signal.SIGTERM


def test_a_timed_game_waits_for_its_first_frame_even_when_connected(pygame_headless):
    """Service ready, but its first frame not there yet: the game clock does not run."""
    now = [0.0]

    def clock() -> float:
        now[0] += 0.05
        return now[0]

    backend = WarmingThenReady(ticks=100)
    backend.connected, backend.warming = True, None
    backend.frame = lambda timeout_s=0.0, f=backend.frame: (f(timeout_s), setattr(
        backend, "warming", None))[0]  # connected all along: never "warming"
    client = GameClient(backend, GameWindow((320, 240)), LoopSettings(attract=True),
                        clock=clock)
    client.run(seconds=1.0, wait_s=60.0)
    assert client.first_frame_t is not None and client.first_frame_t > 5.0
    assert client.state.t <= 1.5, client.state.t  # not the 5+ s spent waiting
