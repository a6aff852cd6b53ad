"""Gamepads: joysticks are opened, and their events move the player as bound."""

from __future__ import annotations

import ctypes
import re
import sys
from pathlib import Path

import numpy as np
import pygame
import pytest
from game_fakes import RecordingBackend

from game.actions import HAT_BINDINGS, PAD_AXES, PAD_BUTTONS, STICK_DEAD_ZONE, STICK_SPEED
from game.client_loop import GameClient, LoopSettings
from game.display import GameWindow
from game.pads import DEFAULT_LAYOUT, layout_from_mapping
from game.rules import MOVES, GameSettings

STEP = 0.1
DT = 0.05
RAW = {name: raw for raw, name in DEFAULT_LAYOUT.items()}  # SDL name -> "b<n>" / "a<n>"


@pytest.fixture
def game(pygame_headless):
    clock = [0.0]
    client = GameClient(
        RecordingBackend(),
        GameWindow((320, 200)),
        LoopSettings(GameSettings(step=STEP)),
        clock=lambda: clock[0],
    )
    client.state.attackers[:] = [0.7, 0.5, -0.4]  # far from the player

    def tick() -> None:
        clock[0] += DT
        client.tick()

    return client, tick


def post(kind: int, **fields: object) -> None:
    pygame.event.post(pygame.event.Event(kind, joy=0, instance_id=0, **fields))


@pytest.mark.parametrize("name", [n for n, a in PAD_BUTTONS.items() if a in MOVES])
def test_each_pad_button_move_shifts_the_origin(game, name):
    client, tick = game
    before = client.state.player.copy()
    post(pygame.JOYBUTTONDOWN, button=int(RAW[name][1:]))
    tick()
    move = MOVES[PAD_BUTTONS[name]]
    np.testing.assert_allclose(client.state.player, before + STEP * np.array(move))


@pytest.mark.parametrize("value", list(HAT_BINDINGS))
def test_each_hat_direction_moves_as_bound(game, value):
    client, tick = game
    before = client.state.player.copy()
    post(pygame.JOYHATMOTION, hat=0, value=value)
    tick()
    move = MOVES[HAT_BINDINGS[value]]
    np.testing.assert_allclose(client.state.player, before + STEP * np.array(move))


@pytest.mark.parametrize("name", list(PAD_AXES))
def test_a_held_stick_moves_the_player_every_tick_until_released(game, name):
    client, tick = game
    world, sign = PAD_AXES[name]
    axis = int(RAW[name][1:])
    start = client.state.player.copy()
    post(pygame.JOYAXISMOTION, axis=axis, value=0.5)
    for _ in range(3):
        tick()
    expected = start.copy()
    expected[world] += 3 * sign * 0.5 * STICK_SPEED * DT
    np.testing.assert_allclose(client.state.player, expected)
    post(pygame.JOYAXISMOTION, axis=axis, value=STICK_DEAD_ZONE / 2)  # released
    tick()
    np.testing.assert_allclose(client.state.player, expected)


def test_pad_start_button_takes_over_attract_mode(pygame_headless):
    clock = [0.0]
    client = GameClient(
        RecordingBackend(),
        GameWindow((320, 200)),
        LoopSettings(GameSettings(seed=3), attract=True),
        clock=lambda: clock[0],
    )
    post(pygame.JOYBUTTONDOWN, button=int(RAW["a"][1:]))
    clock[0] += DT
    client.tick()
    assert not client.attract and client.games == 2


def test_layout_from_an_sdl_mapping_names_raw_inputs():
    xpad = {"a": "b0", "leftshoulder": "b4", "dpup": "h0.1", "lefty": "a1", "righty": "~a4"}
    layout = layout_from_mapping({**xpad, "crc": "1234", "platform": "Linux"})
    assert layout == {"b0": "a", "b4": "leftshoulder", "a1": "lefty", "a4": "righty"}


def test_device_removed_forgets_the_pad_and_stops_its_stick(game):
    client, tick = game
    post(pygame.JOYAXISMOTION, axis=int(RAW["leftx"][1:]), value=1.0)
    tick()
    assert client.pads.axes
    post(pygame.JOYDEVICEREMOVED)
    tick()
    before = client.state.player.copy()
    tick()
    assert not client.pads.axes
    np.testing.assert_array_equal(client.state.player, before)


def sdl_library() -> ctypes.CDLL:
    """The SDL2 that pygame loaded, for SDL's virtual joysticks (no hardware needed)."""
    maps = Path("/proc/self/maps")
    if not sys.platform.startswith("linux") or not maps.exists():
        pytest.skip("finding pygame's SDL library needs /proc/self/maps")
    paths = sorted(set(re.findall(r"(/\S*libSDL2-2\.0\S*|/\S*libSDL2-2-\S*)", maps.read_text())))
    if not paths:
        pytest.skip("pygame's SDL2 library is not loaded as a file")
    sdl = ctypes.CDLL(paths[0])
    if not hasattr(sdl, "SDL_JoystickAttachVirtual"):
        pytest.skip("this SDL has no virtual joysticks (SDL < 2.0.14)")
    sdl.SDL_JoystickFromInstanceID.restype = ctypes.c_void_p
    return sdl


VIRTUAL_PAD = 1  # SDL_JOYSTICK_TYPE_GAMECONTROLLER


def test_a_joystick_added_at_run_time_is_opened_and_its_buttons_move_the_player(game):
    client, tick = game
    sdl = sdl_library()
    tick()
    assert client.pads.joysticks == {}
    index = sdl.SDL_JoystickAttachVirtual(VIRTUAL_PAD, len(DEFAULT_LAYOUT) - 15, 15, 0)
    assert index >= 0 and pygame.joystick.get_count() > 0
    try:
        tick()  # JOYDEVICEADDED: the loop opens it
        (iid,) = client.pads.joysticks
        assert client.pads.joysticks[iid].get_init()
        pad = ctypes.c_void_p(sdl.SDL_JoystickFromInstanceID(iid))
        assert pad.value  # open in SDL: its events are delivered
        before = client.state.player.copy()
        sdl.SDL_JoystickSetVirtualButton(pad, int(RAW["dpright"][1:]), 1)
        tick()
        np.testing.assert_allclose(
            client.state.player, before + STEP * np.array(MOVES["moveright"])
        )
    finally:
        sdl.SDL_JoystickDetachVirtual(index)
    tick()  # JOYDEVICEREMOVED
    assert client.pads.joysticks == {}


def test_joysticks_present_at_start_are_opened(pygame_headless):
    sdl = sdl_library()
    index = sdl.SDL_JoystickAttachVirtual(VIRTUAL_PAD, 6, 15, 1)
    try:
        client = GameClient(RecordingBackend(), GameWindow((320, 200)), LoopSettings())
        assert len(client.pads.joysticks) == pygame.joystick.get_count() == 1
        (layout,) = client.pads.layouts.values()
        assert layout["b0"] == "a" and layout["a1"] == "lefty"  # from SDL's mapping
    finally:
        sdl.SDL_JoystickDetachVirtual(index)
