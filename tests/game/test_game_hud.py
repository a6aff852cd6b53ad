"""The HUD shows score, fps, update rate against refresh rate and latency (issue 6)."""

from __future__ import annotations

import re
from dataclasses import replace

import numpy as np
from game_fakes import RecordingBackend

from game.client_loop import GameClient, LoopSettings
from game.display import HELD_LINE, HUD_COLOUR, GameWindow, Hud
from game.rules import GameSettings


def test_hud_text_shows_the_numbers_it_is_given():
    hud = Hud(
        score=42,
        seconds=12.34,
        fps=59.87,
        update_hz=23.4,
        refresh_hz=60.0,
        latency_ms=37.6,
        mode="strip",
        zone=3,
        lines=["paused"],
    )
    assert hud.text() == [
        "score 42   time  12.3 s",
        "fps 59.9   updates 23.4 Hz / refreshes 60.0 Hz   latency 38 ms",
        "mode strip (zone 3)",
        "paused",
    ]
    assert "latency -" not in " ".join(hud.text())
    assert "latency 0 ms" in Hud(latency_ms=0.0).text()[1]  # zero is a number, not missing


def test_the_window_draws_the_hud_lines(pygame_headless):
    window = GameWindow()  # the game's window: the whole second line fits
    window.draw(None, "head", 0, Hud(score=7, latency_ms=None))
    placeholder = window.pixels()
    window.draw(None, "head", 0, Hud(score=7, latency_ms=125.0))
    numbers = window.pixels()
    text = np.all(numbers == HUD_COLOUR, axis=-1)
    assert text[:70].sum() > 100 and not text[70:].any()  # three lines at the top
    assert text[28:48].any(axis=0).nonzero()[0].max() < text.shape[1] - 10  # not cut off
    second_line = slice(28, 48)
    assert not np.array_equal(placeholder[second_line], numbers[second_line])
    assert np.array_equal(placeholder[:28], numbers[:28])  # score line unchanged


def test_the_game_loop_fills_the_hud_from_its_frames(pygame_headless):
    clock = [0.0]
    client = GameClient(
        RecordingBackend(3),
        GameWindow((320, 200)),
        LoopSettings(GameSettings()),
        clock=lambda: clock[0],
    )
    assert "latency -" in client.hud(0.0).text()[1]
    for _ in range(30):
        clock[0] += 1 / 60
        client.tick()
    hud = client.hud(clock[0])
    assert hud.latency_ms == 5.0  # the test backend's frames say 5 ms
    assert hud.fps > 30 and hud.refresh_hz > 30 and hud.update_hz > 0
    line = hud.text()[1]
    shown = re.fullmatch(
        r"fps +([\d.]+)   updates +([\d.]+) Hz / refreshes +([\d.]+) Hz   latency 5 ms", line
    )
    assert shown is not None, line
    assert [float(x) for x in shown.groups()] == [
        round(hud.fps, 1),
        round(hud.update_hz, 1),
        round(hud.refresh_hz, 1),
    ]


class _HeldAfter(RecordingBackend):
    """Frames that hold the last render from the 10th on (renders stopped)."""

    def frame(self, timeout_s: float = 0.0):
        view = super().frame(timeout_s)
        return replace(view, held=self.seq >= 10)


def test_the_hud_says_when_the_frame_holds_the_last_render(pygame_headless):
    assert HELD_LINE not in Hud().text()
    assert Hud(held=True).text()[3] == HELD_LINE
    clock = [0.0]
    client = GameClient(_HeldAfter(3), GameWindow((320, 200)), LoopSettings(GameSettings()),
                        clock=lambda: clock[0])
    seen = []
    for _ in range(20):
        clock[0] += 1 / 60
        client.tick()
        seen.append(HELD_LINE in client.hud(clock[0]).text())
    assert seen == [False] * 9 + [True] * 11
    assert client.stats(1.0)["held_frames"] == 11


def test_service_frames_carry_held_from_the_header():
    """docs/protocol.md: ``held`` in the frame header; a service older than it: not held."""
    from game.backends import _view

    colour = np.zeros((2, 4, 6, 3), np.uint8)
    base = {"seq": 3, "render_id": 1, "since_render": 20, "t_ns": 5}
    assert _view({**base, "held": True}, {"colour": colour}).held is True
    assert _view({**base, "held": False}, {"colour": colour}).held is False
    assert _view(base, {"colour": colour}).held is False
