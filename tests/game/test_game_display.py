from __future__ import annotations

import numpy as np
import pytest

from game.display import IMAGES, MODES, UNAVAILABLE, GameWindow, Hud, zone_for_head
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


def test_autostereogram_is_listed_unavailable_and_hud_text():
    assert "autostereogram" in UNAVAILABLE and "autostereogram" not in IMAGES
    text = Hud(score=5, latency_ms=None).text()
    assert text[0].startswith("score 5") and "latency -" in text[1]
