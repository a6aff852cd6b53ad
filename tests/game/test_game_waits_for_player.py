"""The rig waits for the player: "press SPACE to start", one line without sound, a clean film."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pygame
import pytest
from game_fakes import RecordingBackend

from game.capture import Capture
from game.client_loop import GameClient, LoopSettings
from game.display import GameWindow
from game.rules import GameSettings

ROOT = Path(__file__).resolve().parents[2]


class SeenWindow(GameWindow):
    """A real window that also remembers the banners it drew."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.banners: list[str] = []

    def banner(self, title: str, lines=(), dim: bool = True) -> None:
        self.banners.append(title)
        super().banner(title, lines, dim)


class GapBackend(RecordingBackend):
    """No frame while ``gap`` is set (a new game's first render not there yet)."""

    gap = False

    def frame(self, timeout_s: float = 0.0):
        return None if self.gap else super().frame(timeout_s)


def key(k: int) -> None:
    pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=k, mod=0, unicode="", scancode=0))


def client_for(settings: LoopSettings, clock: list[float]) -> GameClient:
    client = GameClient(GapBackend(), SeenWindow((320, 200)), settings,
                        clock=lambda: clock[0])
    client.state.attackers[:] = [0.7, 0.5, -0.4]  # far from the player
    return client


def test_a_players_game_opens_on_press_space_and_nothing_moves_before(pygame_headless):
    clock = [0.0]
    client = client_for(LoopSettings(GameSettings(), press_start=True), clock)
    attackers = client.state.attackers.copy()
    for _ in range(30):  # 3 s of ticks, arrows pressed too: only SPACE starts
        clock[0] += 0.1
        key(pygame.K_LEFT)
        client.tick()
    assert client.state.t == 0.0 and client.waiting_start
    np.testing.assert_array_equal(client.state.attackers, attackers)
    assert client.window.banners[-1] == "press SPACE to start"
    shown = len(client.window.banners)
    key(pygame.K_SPACE)
    for _ in range(5):
        clock[0] += 0.1
        client.tick()
    assert not client.waiting_start and client.state.t > 0.3
    assert "press SPACE to start" not in client.window.banners[shown:]


def test_the_bot_starts_at_once(pygame_headless):
    clock = [0.0]
    client = client_for(LoopSettings(GameSettings(), attract=True, press_start=True), clock)
    for _ in range(5):
        clock[0] += 0.1
        client.tick()
    assert client.state.t > 0.3 and "press SPACE to start" not in client.window.banners


def test_the_film_leaves_out_get_ready_and_starts_at_the_first_render(pygame_headless, tmp_path):
    clock = [0.0]
    client = client_for(LoopSettings(GameSettings(), attract=True), clock)
    capture = Capture(tmp_path, 0.0, film_every_s=0.1, tour=False)
    for k in range(35):  # FILM_FRAMES (40) is not reached
        clock[0] += 0.1
        if k == 10:
            client.new_game()  # its first ticks show GET READY until a frame comes
        client.backend.gap = k in (10, 11, 12)
        client.tick()
        capture(client)
    assert client.window.banners.count("GET READY") == 3
    assert len(capture.film) == 35 - 3
    assert all(f.reshape(-1, 3).max(axis=0).sum() > 0 for f in capture.film)


@pytest.mark.skipif(not sys.platform.startswith("linux") or Path("/proc/asound/cards").exists(),
                    reason="needs a Linux machine without a sound card")
def test_no_sound_device_is_one_line_not_library_noise():
    env = dict(os.environ, SDL_VIDEODRIVER="dummy", SDL_AUDIODRIVER="alsa")
    code = ("from game.sound import start_pygame; b, why, other = start_pygame(False); "
            "print(b.muted, why is not None, other)")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=60)
    assert done.stdout.strip() == "True True []", done.stdout + done.stderr
    assert "ALSA lib" not in done.stderr and done.stderr.strip() == ""
