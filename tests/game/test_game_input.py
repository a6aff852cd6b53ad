"""The headless game driven by posted pygame events and dial-box events."""

from __future__ import annotations

import numpy as np
import pygame
import pytest
from game_fakes import FakeDevices, RecordingBackend

from drivers.events import ButtonEvent, DialEvent, PoseEvent
from game.actions import BUTTON_BINDINGS, DIAL_AXES, KEY_BINDINGS, lamp_mask
from game.client_loop import GameClient, LoopSettings
from game.display import GameWindow
from game.rules import MOVES, GameSettings

STEP = 0.1


@pytest.fixture
def game(pygame_headless):
    clock = [0.0]
    backend = RecordingBackend()
    devices = FakeDevices()
    client = GameClient(
        backend,
        GameWindow((320, 200)),
        LoopSettings(GameSettings(step=STEP)),
        devices,
        clock=lambda: clock[0],
    )
    client.state.attackers[:] = [0.7, 0.5, -0.4]  # far from the player
    return client, backend, devices, clock


def post_key(key: int) -> None:
    pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=key, mod=0, unicode="", scancode=0))


@pytest.mark.parametrize("key", [k for k, a in KEY_BINDINGS.items() if a in MOVES])
def test_each_key_move_shifts_the_origin_as_specified(game, key):
    client, backend, _, _ = game
    before = client.state.player.copy()
    post_key(key)
    client.tick()
    expected = before + STEP * np.array(MOVES[KEY_BINDINGS[key]])
    np.testing.assert_allclose(client.state.player, expected)
    assert backend.updates[-1][0]["name"] == "player"
    np.testing.assert_allclose(backend.updates[-1][0]["position"], expected)


def test_dials_move_continuously_and_buttons_make_the_discrete_moves(game):
    client, _, devices, _ = game
    before = client.state.player.copy()
    devices.queue = [DialEvent(1, index, 10, 10) for index in DIAL_AXES]
    client.tick()
    gains = np.array([DIAL_AXES[i][1] for i in sorted(DIAL_AXES)])
    np.testing.assert_allclose(client.state.player, before + 10 * gains)
    for button, name in BUTTON_BINDINGS.items():
        if name not in MOVES:
            continue
        before = client.state.player.copy()
        devices.queue = [ButtonEvent(2, button, True), ButtonEvent(3, button, False)]
        client.tick()
        np.testing.assert_allclose(client.state.player, before + STEP * np.array(MOVES[name]))
    assert client.dial_events == 3 + 2 * 6
    assert lamp_mask() == sum(1 << b for b in BUTTON_BINDINGS)


def test_pause_modes_zone_keys_head_zone_and_quit(game):
    client, _, devices, clock = game
    post_key(pygame.K_p)
    client.tick()
    assert client.state.paused
    before = client.state.player.copy()
    post_key(pygame.K_LEFT)
    clock[0] += 0.05
    client.tick()
    np.testing.assert_array_equal(client.state.player, before)
    assert client.state.t == 0.0
    for key, mode in ((pygame.K_2, "strip"), (pygame.K_3, "zone"), (pygame.K_1, "head")):
        post_key(key)
        client.tick()
        assert client.mode == mode
    post_key(pygame.K_4)
    client.tick()
    assert client.mode == "autostereogram" and not client.notice
    post_key(pygame.K_RIGHTBRACKET)
    client.tick()
    assert client.zone == 0  # 2 + 1 wraps on 3 zones
    devices.pose = PoseEvent(5, 0, 0, 0, -200.0, 0.0, 0.0, 1)  # head far left
    client.tick()
    assert client.shown_zone() == 0
    pygame.event.post(pygame.event.Event(pygame.QUIT))
    client.tick()
    assert client.quit


def test_attract_mode_bot_plays_until_a_key(pygame_headless):
    clock = [0.0]
    backend = RecordingBackend()
    client = GameClient(
        backend,
        GameWindow((320, 200)),
        LoopSettings(GameSettings(seed=3), attract=True),
        clock=lambda: clock[0],
    )
    for _ in range(40):
        clock[0] += 0.05
        client.tick()
    assert client.attract and client.state.t > 1.5
    post_key(pygame.K_SPACE)
    clock[0] += 0.05
    client.tick()
    assert not client.attract and client.games == 2 and client.state.t < 0.1


def test_game_over_beeps_three_times_explodes_and_shows_the_score(game):
    client, backend, _, clock = game
    client.state.attackers[0] = client.state.player + [0.05, 0.0, 0.0]
    client.tick()
    assert client.over is not None
    for _ in range(80):
        clock[0] += 0.05
        client.tick()
    assert client.beeper.count == 3 and backend.explosions == [client.seed]
    assert client.over.phase == "score"
    post_key(pygame.K_SPACE)
    client.tick()
    assert client.over is None and client.games == 2 and backend.resumes == 1
