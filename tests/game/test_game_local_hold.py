"""The game's local mode holds the last render when renders stop (seed 002 use-by).

:class:`LocalRenderer` runs the service's engine: with renders capped to one every
4 s (``max_update_hz=0.25``, as ``holo-service --max-update-hz``), more than 3 s of
refreshes pass without one.  The frames are propagated for the render's use-by,
then show the last render bit for bit (``held``); the next render ends the hold.
The game over's explosion is a scene of its own whose pieces the renders follow.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from testkit import HANG_S

from game.backends import LocalRenderer
from game.rules import new_game
from game.scene import game_scene, object_states
from service.display import DisplaySettings
from service.frame_settings import FrameSettings

HZ = 30.0
STARVED = int(3 * HZ)  # refreshes without a render
SETTINGS = FrameSettings(display=DisplaySettings(zones=3, angle_deg=16.0, cols=64, rows=48),
                         refresh_hz=HZ)


def _frames(backend: LocalRenderer, until) -> list:
    """Frames as the refresh thread makes them, until ``until(frames)`` (a hang guard)."""
    got, deadline = [], time.monotonic() + HANG_S
    while time.monotonic() < deadline:
        view = backend.frame(timeout_s=1.0)
        if view is not None:
            got.append(view)
            if until(got):
                return got
    pytest.fail(f"the local renderer stopped short: {len(got)} frames")


@pytest.fixture
def starved():
    backend = LocalRenderer(SETTINGS, max_update_hz=0.25)
    backend.start(game_scene(6, True))
    try:
        yield backend
    finally:
        backend.close()


def test_local_mode_holds_the_last_render_when_renders_stop(starved):
    starved.update(object_states(new_game()))
    frames = _frames(starved, lambda f: f[-1].render_id >= 0 and f[-1].since_render >= STARVED)
    mine = [f for f in frames if f.render_id == frames[-1].render_id]
    shown = {f.since_render: f for f in mine}
    assert 0 in shown, "the frame showing the render itself was not taken"
    render, held = shown[0], [f for f in mine if f.held]
    assert not render.held
    first_held = min(f.since_render for f in held)
    # the game's attackers spin 45 degrees in 15.7 refreshes at 30 Hz: use-by 15 (or
    # sooner, when the refresh thread missed ticks on a busy machine)
    assert first_held <= 16
    assert all(f.held for f in mine if f.since_render >= first_held)
    assert len(held) >= STARVED - 16 - 10  # a few frames may be taken late, not many
    for f in held:  # the render itself, not one pixel of an expired galpixel
        assert np.array_equal(f.colour, render.colour), f"held frame {f.since_render}"
    after = _frames(starved, lambda f: f[-1].render_id > render.render_id)
    assert not after[-1].held  # the next render ends the hold


def test_the_game_over_explosion_flies_on_the_local_engine():
    local = LocalRenderer(SETTINGS)
    local.start(game_scene(6, True))
    try:
        local.update(object_states(new_game()))
        _frames(local, lambda f: f[-1].render_id >= 0)
        local.explode(seed=3)
        exploded = local.scene_version
        burst = _frames(local, lambda f: sum(x.scene == exploded for x in f) >= 20)
    finally:
        local.close()
    flying = [f for f in burst if f.scene == exploded]
    assert len({f.render_id for f in flying}) > 1  # renders follow the pieces
    assert not np.array_equal(flying[0].colour, flying[-1].colour)  # the pieces fly
