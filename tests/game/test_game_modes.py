"""Display modes and the fixed zone: unavailable modes and zones out of range never crash."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pygame
import pytest
from game_fakes import RecordingBackend

from game.client_loop import GameClient, LoopSettings
from game.display import UNAVAILABLE, GameWindow, headless_env
from game.rules import GameSettings

ROOT = Path(__file__).resolve().parents[2]


def holo_game(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    """``holo-game`` in a real process, headless."""
    return subprocess.run(
        [sys.executable, "-m", "game.commands.holo_game", *args],
        cwd=ROOT,
        env=headless_env(),
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def test_autostereogram_mode_on_the_command_line_shows_dots(tmp_path):
    run = holo_game(
        "--local", "--headless", "--mode", "autostereogram", "--seconds", "3",
        "--size", "80x60", "--highscores", str(tmp_path / "hs.json"),
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert "Traceback" not in run.stderr and "not available" not in run.stderr
    stats = json.loads(run.stdout.splitlines()[-1])
    assert stats["modes"] == ["autostereogram"] and stats["refreshes"] > 0


@pytest.mark.parametrize("zone", ["9", "5", "-1"])
def test_zone_out_of_range_is_a_usage_error(tmp_path, zone):
    run = holo_game(
        "--local", "--headless", "--mode", "zone", "--zone", zone, "--zones", "5",
        "--seconds", "1", "--highscores", str(tmp_path / "hs.json"),
    )  # fmt: skip
    assert run.returncode == 2
    assert "Traceback" not in run.stderr and run.stderr.startswith("usage: holo-game")
    assert f"--zone {zone}: the display has 5 zones, 0 to 4" in run.stderr


def test_zero_zones_is_a_usage_error():
    run = holo_game("--local", "--zones", "0")
    assert run.returncode == 2 and "--zones: must be from 1 to 64, got 0" in run.stderr


def client_with(settings: LoopSettings, zones: int = 3) -> GameClient:
    clock = [0.0]
    return GameClient(
        RecordingBackend(zones), GameWindow((640, 300)), settings, clock=lambda: clock[0]
    )


def press(client: GameClient, key: int) -> None:
    pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=key, mod=0, unicode="", scancode=0))
    client.tick()


def test_the_autostereogram_key_shows_the_frames_stereogram_with_a_readable_hud(
        pygame_headless):
    client = client_with(LoopSettings(GameSettings(), mode="strip"))
    client.tick()
    press(client, pygame.K_4)  # mode_autostereogram
    assert client.mode == "autostereogram" and not client.notice
    assert client.modes_shown == {"strip", "autostereogram"}
    # the fake frame's stereogram is a ramp: the picture shows it, not the grey zones
    pixels = client.window.pixels()
    assert len(np.unique(pixels[150:250, 200:440, 0])) > 20
    # the HUD's dark backing: its text is light on near-black behind every line
    hud_box = pixels[6:20, 6:200]
    assert (hud_box.max(axis=2) < 60).mean() > 0.5 and (hud_box > 200).any()
    press(client, pygame.K_3)
    assert client.mode == "zone"


@pytest.mark.parametrize("mode", [*UNAVAILABLE, "no-such-mode"])
def test_unavailable_initial_mode_shows_head_with_a_notice(pygame_headless, mode):
    client = client_with(LoopSettings(GameSettings(), mode=mode))
    client.tick()  # draws a frame: no KeyError
    assert client.mode == "head" and "not available" in client.notice
    assert client.modes_shown == {"head"}


@pytest.mark.parametrize("zone", [3, -1])
def test_loop_refuses_a_zone_the_display_lacks(pygame_headless, zone):
    with pytest.raises(ValueError, match=f"zone {zone} is not one of the display's 3 zones"):
        client_with(LoopSettings(GameSettings(), mode="zone", zone=zone))
