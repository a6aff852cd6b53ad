"""Display modes and the fixed zone: unavailable modes and zones out of range never crash."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

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
        [sys.executable, "-m", "game.cli", *args],
        cwd=ROOT,
        env=headless_env(),
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def test_unavailable_mode_on_the_command_line_falls_back_to_head(tmp_path):
    run = holo_game(
        "--local", "--headless", "--mode", "autostereogram", "--seconds", "3",
        "--size", "80x60", "--highscores", str(tmp_path / "hs.json"),
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert "Traceback" not in run.stderr
    assert "autostereogram mode is not available" in run.stderr and "showing head" in run.stderr
    stats = json.loads(run.stdout.splitlines()[-1])
    assert stats["modes"] == ["head"] and stats["refreshes"] > 0  # frames drawn in head mode


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
    assert run.returncode == 2 and "at least one zone" in run.stderr


def client_with(settings: LoopSettings, zones: int = 3) -> GameClient:
    clock = [0.0]
    return GameClient(
        RecordingBackend(zones), GameWindow((640, 300)), settings, clock=lambda: clock[0]
    )


def press(client: GameClient, key: int) -> None:
    pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=key, mod=0, unicode="", scancode=0))
    client.tick()


def test_unavailable_mode_key_keeps_the_mode_and_says_so_in_the_hud(pygame_headless):
    client = client_with(LoopSettings(GameSettings(), mode="strip"))
    client.tick()
    press(client, pygame.K_4)  # mode_autostereogram
    assert client.mode == "strip" and client.modes_shown == {"strip"}
    hud = client.hud(0.0).text()
    assert any("autostereogram mode is not available" in line for line in hud)
    assert any("showing strip" in line for line in hud)
    press(client, pygame.K_3)  # a mode that can be shown clears the notice
    assert client.mode == "zone" and not client.notice


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
