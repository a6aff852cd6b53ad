"""The game's local mode holds the last render when renders stop (seed 002 use-by).

:class:`LocalRenderer` renders only when the game hands it new object states: a
game that stops updating starves its Galilean stage.  For 3 s of refreshes the
frames are propagated for the stage's rating, then show the last render bit for
bit (``held``); the game-over burst, whose motion is exact and which no render
follows, is carried to the score screen instead.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from testkit import HANG_S

from game.backends import LocalRenderer
from game.gameover import BURST_SECONDS
from game.rules import new_game
from game.scene import apply_states, game_scene, object_states
from service.display import DisplaySettings
from service.frame_settings import FrameSettings
from service.galilean.local_update import render_use_by

HZ = 30.0
SETTINGS = FrameSettings(display=DisplaySettings(zones=3, angle_deg=16.0, cols=64, rows=48),
                           refresh_hz=HZ)


@pytest.fixture
def local():
    backend = LocalRenderer(SETTINGS)
    backend.start(game_scene(6, True))
    try:
        yield backend
    finally:
        backend.close()


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


def test_local_mode_holds_the_last_render_when_renders_stop(local):
    state = new_game()
    scene = apply_states(local._scene, object_states(state))
    use_by = render_use_by(scene, HZ, local.stage.settings.n_prop)
    assert use_by == 15  # the attackers spin 45 degrees in 15.7 refreshes at 30 Hz
    for _attempt in range(3):  # a frame showing the render itself may be missed under load
        local.update(object_states(state))
        frames = _frames(local, lambda f: f[-1].render_id >= 0 and f[-1].since_render >= 3 * HZ)
        last = frames[-1].render_id
        mine = [f for f in frames if f.render_id == last]
        if mine[0].since_render == 0:
            break
        state.t += 0.5  # another render, and watch again
    else:
        pytest.fail("never saw the frame that shows a render itself")
    render = mine[0]
    held = [f for f in mine if f.held]
    # held past the use-by; sooner when the refresh thread missed ticks (a busy machine)
    assert all(f.held for f in mine if f.since_render > use_by)
    assert not render.held
    assert len(held) >= 3 * HZ - use_by - 10  # a few frames may be taken late, not many
    for f in held:  # the render itself, not one pixel of an expired galpixel
        assert np.array_equal(f.colour, render.colour), f"held frame {f.since_render}"


def test_the_game_over_burst_is_carried_to_the_score_screen(local):
    local.update(object_states(new_game()))
    _frames(local, lambda f: f[-1].render_id >= 0)
    local.explode(seed=3)
    burst = _frames(local, lambda f: f[-1].render_id >= 1
                    and f[-1].since_render >= local.stage.settings.n_prop + 10)
    flying = [f for f in burst if f.render_id >= 1]
    assert not any(f.held for f in flying)  # past the rating, and not held
    assert not np.array_equal(flying[0].colour, flying[-1].colour)  # the pieces fly
    assert local._burst_use_by == int(np.ceil(BURST_SECONDS * HZ))


def test_the_local_refresh_loop_counts_the_ticks_it_missed():
    from game.backends import _next_tick

    assert _next_tick(0.0, 0.1, 0.05) == (0.1, 0)
    assert _next_tick(0.0, 0.1, 0.15) == (0.1, 0)  # late, less than a period: no skip
    t, missed = _next_tick(0.0, 0.1, 0.35)
    assert missed == 2 and t == pytest.approx(0.3)
