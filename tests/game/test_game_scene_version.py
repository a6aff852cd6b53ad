"""A new scene is a clean cut: the game shows no frame of the scene before it.

Frames carry the version of the scene they were rendered from (``scene`` in the
frame header, ``docs/protocol.md`` 2); the backends hand out no frame of an older
version once a new scene is loaded, and the Galilean stage carries none of the old
galpixels over.  Before, the first 0.2-1.7 s of a new game showed the game over's
pieces flying on.
"""

from __future__ import annotations

import numpy as np
import pytest
from testkit import TINY_DISPLAY, wait_until

from game.backends import ServiceBackend
from game.client_loop import GameClient, LoopSettings
from game.display import GameWindow
from game.gameover import GameOverSequence
from service.display import DisplaySettings
from service.frame_settings import FrameSettings
from service.primitives import sphere
from service.render.scene import Material, MotionState, Scene, SceneObject, Transform

DISPLAY = DisplaySettings(zones=2, cols=32, rows=24)


def _ball(colour: tuple, x: float, vx: float) -> Scene:
    """One ball of ``colour`` at ``x``, moving at ``vx`` (the stage extrapolates it)."""
    ball = SceneObject(sphere(0.25, 8, 12), Material(colour, ambient=1.0, diffuse=0.0,
                                                      specular=0.0),
                       Transform(np.array([x, 0.0, 0.0])),
                       MotionState(velocity=np.array([vx, 0.0, 0.0])), name="ball")
    return Scene(objects=[ball], ambient=1.0)


def _red(colour: np.ndarray) -> int:
    """Pixels of scene A's red ball."""
    c = colour.astype(int)
    return int(np.count_nonzero((c[..., 0] > 60) & (c[..., 0] > 2 * c[..., 1] + 30)))


def _green(colour: np.ndarray) -> int:
    c = colour.astype(int)
    return int(np.count_nonzero((c[..., 1] > 60) & (c[..., 1] > 2 * c[..., 0] + 30)))



def _next_frames(backend, n: int) -> list:
    """The next ``n`` frames the backend shows (it may hold some back), within 120 s."""
    shown = []

    def enough() -> bool:
        got = backend.frame(0.2)
        if got is not None:
            shown.append(got)
        return len(shown) >= n

    assert wait_until(enough, 120, step_s=0.0), f"{len(shown)} of {n} frames shown"
    return shown

def test_after_a_scene_load_every_frame_is_of_the_new_scene(service_factory):
    svc = service_factory(*TINY_DISPLAY, "--refresh", "30")
    backend = ServiceBackend(svc.control, svc.frames, settings=FrameSettings(
        DISPLAY, refresh_hz=30.0), timeout_s=30)
    try:
        backend.start(_ball((1.0, 0.1, 0.1), -0.3, 0.4))
        a = backend.scene_version
        assert backend.connected and isinstance(a, int)
        got = wait_until(lambda: backend.frame(0.5), 120)  # the first render may compile
        assert got and got.scene == a and _red(got.colour) > 0
        backend.load_scene(_ball((0.1, 1.0, 0.1), 0.3, -0.4))
        b = backend.scene_version
        assert b == a + 1
        shown = _next_frames(backend, 15)
    finally:
        backend.close()
    assert [f.scene for f in shown] == [b] * len(shown)
    assert [_red(f.colour) for f in shown] == [0] * len(shown)  # nothing of A
    assert all(_green(f.colour) > 0 for f in shown)


def test_a_new_game_shows_get_ready_then_only_its_own_frames(setup_from_args):
    game, backend = setup_from_args()
    client = GameClient(backend, GameWindow((320, 200)), LoopSettings(game))
    if not wait_until(lambda: client.tick() or client.colour is not None, 180, step_s=0.0):
        pytest.fail("no frame from the local renderer")
    client.over = GameOverSequence(client.clock())
    backend.explode(1)  # game over: the player's mesh in flying pieces (a scene of its own)
    exploded = backend.scene_version
    assert wait_until(lambda: getattr(backend.frame(0.1), "scene", None) == exploded, 60)
    taken = []
    frame = backend.frame

    def recorded(timeout_s: float = 0.0):
        got = frame(timeout_s)
        taken.append(got)
        return got

    backend.frame = recorded  # what the game is handed, as it is handed
    client.new_game()
    assert client.colour is None and client._get_ready
    t0 = client.state.t
    seen = []

    def tick() -> bool:
        client.tick()
        seen.append((client._get_ready, client.colour, client.state.t))
        return not client._get_ready and client.state.t > t0

    assert wait_until(tick, 60, step_s=0.0)
    # cleared and the game held while it waits (no tick at all when the render is quick)
    assert all(c is None and t == t0 for ready, c, t in seen if ready)
    assert seen[-1][1] is not None  # then it goes on, with the new game's frames
    shown = [f for f in taken if f is not None]
    # the new game's scene only: nothing rendered or refreshed from the explosion
    assert shown and all(f.scene == backend.scene_version == exploded + 1 for f in shown)


def _record(x: float) -> dict:
    still = [0.0, 0.0, 0.0]
    return {"name": "ball", "position": [x, 0.0, 0.0], "orientation": [1.0, 0, 0, 0],
            "velocity": still, "acceleration": still, "angular_velocity": still}


def test_a_new_game_is_loaded_with_its_objects_in_place(service_factory):
    """The new game's scene goes with its first states: no frame with the old places.

    Loading the scene first and sending the states after it left a window in which a
    render could start on the old places (the loaded demo's first frames showed every
    object at the origin for a second); on a quiet machine the update usually wins
    that race, so this checks the property rather than forcing the race.
    """
    svc = service_factory(*TINY_DISPLAY, "--refresh", "30")
    backend = ServiceBackend(svc.control, svc.frames, settings=FrameSettings(
        DISPLAY, refresh_hz=30.0), timeout_s=30, shatter=False)
    half = DISPLAY.cols // 2
    try:
        backend.start(_ball((1.0, 0.1, 0.1), 0.0, 0.0))
        backend.update([_record(-0.3)])  # the game before: the ball on the left
        assert wait_until(lambda: (f := backend.frame(0.5)) is not None
                          and _red(f.colour[..., :half, :]) > 0, 120)
        backend.explode(1)  # flung (update_objects), then a new game
        backend.resume()
        backend.update([_record(0.3)])  # the new game's ball on the right
        shown = _next_frames(backend, 15)
    finally:
        backend.close()
    assert {f.scene for f in shown} == {backend.scene_version}
    assert [_red(f.colour[..., :half, :]) for f in shown] == [0] * len(shown)
    assert all(_red(f.colour[..., half:, :]) > 0 for f in shown)
