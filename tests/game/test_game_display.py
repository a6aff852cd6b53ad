from __future__ import annotations

import numpy as np
import pytest

from game.display import (
    IMAGES,
    MODES,
    UNAVAILABLE,
    GameWindow,
    Hud,
    choose_mode,
    has_display,
    zone_for_head,
)
from service.display import DisplaySettings


def test_head_position_picks_the_nearest_zone():
    d = DisplaySettings(zones=5, angle_deg=16.0)
    assert zone_for_head(0.0, 0.0, d) == 2
    assert zone_for_head(-500.0, 0.0, d) == 0 and zone_for_head(500.0, 0.0, d) == 4
    assert zone_for_head(-20.0, 0.0, d, 250.0) == 1  # -4.6 degrees: zone 1 (-3.2)


@pytest.mark.parametrize("mode", MODES)
def test_every_mode_draws_its_zones(pygame_headless, mode, tmp_path):
    colour = np.zeros((3, 30, 40, 3), np.uint8)
    for z in range(3):
        colour[z, :, :, z] = 200  # zone 0 red, 1 green, 2 blue
    window = GameWindow((400, 300))
    window.draw(colour, mode, 1, Hud(score=12))
    pixels = window.pixels()
    greens = np.count_nonzero((pixels[..., 1] == 200) & (pixels[..., 0] == 0))
    reds = np.count_nonzero((pixels[..., 0] == 200) & (pixels[..., 1] == 0))
    assert greens > 1000
    assert (reds > 100) == (mode == "strip")
    assert window.screenshot(tmp_path / "s.png").stat().st_size > 0


@pytest.mark.parametrize("mode", ["head", "zone"])
def test_a_zone_past_the_frames_zones_shows_the_last_zone(pygame_headless, mode):
    # another client's set_display can leave frames with fewer zones than the game has
    colour = np.zeros((2, 30, 40, 3), np.uint8)
    colour[1, :, :, 2] = 200  # zone 1 blue
    window = GameWindow((400, 300))
    window.draw(colour, mode, 4, Hud(score=1))  # was an IndexError
    pixels = window.pixels()
    assert np.count_nonzero((pixels[..., 2] == 200) & (pixels[..., 0] == 0)) > 1000


def test_autostereogram_is_a_mode_and_hud_text():
    assert "autostereogram" in MODES and "autostereogram" in IMAGES and not UNAVAILABLE
    text = Hud(score=5, latency_ms=None).text()
    assert text[0].startswith("score 5") and "latency -" in text[1]


@pytest.mark.parametrize("name", ["SDL_VIDEODRIVER", "SDL_VIDEO_DRIVER"])
@pytest.mark.parametrize("driver", ["dummy", "DUMMY", "offscreen"])
def test_has_display_sees_the_sdl2_and_the_sdl3_driver_variable(name, driver):
    x11 = {"DISPLAY": ":0"}
    assert has_display(x11) and has_display({"WAYLAND_DISPLAY": "wayland-0"})
    assert has_display(x11 | {name: "x11"})
    assert not has_display(x11 | {name: driver})
    assert not has_display({}) and not has_display({name: "x11"})


def test_has_display_reads_os_environ(monkeypatch):
    for name in ("SDL_VIDEODRIVER", "SDL_VIDEO_DRIVER"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("DISPLAY", ":0")
    assert has_display()
    monkeypatch.setenv("SDL_VIDEO_DRIVER", "dummy")
    assert not has_display()


def test_choose_mode_keeps_the_current_mode_for_an_unavailable_one():
    assert choose_mode("strip", "zone") == ("strip", "")
    for mode in (*UNAVAILABLE, "no-such-mode"):
        shown, notice = choose_mode(mode, "zone")
        assert shown == "zone" and "not available" in notice and mode in notice
    assert choose_mode("autostereogram") == ("autostereogram", "")


@pytest.mark.parametrize("size", [(400, 300), (200, 80), (64, 48), (30, 20), (1, 1)])
def test_a_window_of_any_size_draws_the_frame(pygame_headless, size):
    # windows under ~90 px tall raised "Cannot scale to negative size"
    colour = np.zeros((3, 36, 48, 3), np.uint8)
    colour[1, :, :, 1] = 200  # zone 1 green
    window = GameWindow(size)
    window.draw(colour, "zone", 1, Hud(lines=["paused"]))
    pixels = window.pixels()
    assert pixels.shape == (size[1], size[0], 3)
    cy, cx = size[1] // 2, size[0] // 2
    assert pixels[cy, cx, 1] == 200 or size[1] < 20  # the picture is there (HUD aside)
    window.draw(None, "zone", 1, Hud())
