"""Game over against a real service: the player shatters (a new scene) and play resumes."""

from __future__ import annotations

import time

import pytest
from testkit import launch_service

from game.backends import ServiceBackend
from game.rules import GameSettings, new_game
from game.scene import game_scene, object_states
from service.display import DisplaySettings
from service.frame_settings import FrameSettings
from service.net.client import ServiceClient


def frames_after(backend: ServiceBackend, render_id: int, count: int, timeout: float) -> list:
    """``count`` frames grafted from renders newer than ``render_id``."""
    got: list = []
    deadline = time.monotonic() + timeout
    while len(got) < count:
        assert time.monotonic() < deadline, f"only {len(got)} new frames"
        f = backend.frame(0.2)
        if f is not None and f.render_id > render_id:
            got.append(f)
    return got


@pytest.mark.timeout(120)
def test_shatter_then_resume_keeps_the_service_rendering():
    svc = launch_service("--workers", "0")  # on ports of its own choosing
    control, frames, proc = svc.control, svc.frames, svc.proc
    backend = ServiceBackend(control, frames, settings=FrameSettings(
        DisplaySettings(zones=2, cols=48, rows=36)), timeout_s=2.0)
    state = new_game(GameSettings(difficulty="easy"))
    n_attackers = len(object_states(state)) - 1
    try:
        deadline = time.monotonic() + 60
        while not backend.connected:
            assert time.monotonic() < deadline and proc.poll() is None, "service did not start"
            try:
                backend.start(game_scene(n_attackers))
            except Exception:  # not listening yet
                backend.frame(0.1)
        assert backend.shatter  # the default
        backend.update(object_states(state))
        before = frames_after(backend, -1, 3, 30)[-1]
        backend.explode(seed=1)
        pieces = frames_after(backend, before.render_id, 5, 30)
        backend.resume()
        again = frames_after(backend, pieces[-1].render_id, 5, 30)
        assert again[-1].colour.any()
        with ServiceClient(control, timeout_s=5) as c:
            stats = c.stats()
        assert stats["refresh_errors"] == 0 and stats["last_refresh_error"] == "", stats
    finally:
        backend.close()
        svc.stop()
