"""holo-game --display lookingglass:CALIBRATION.json: the panel full screen, interleaved."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from testkit import ROOT

from service.lookingglass import Interleaver, load_calibration

PANEL = {"pitch": 41.0, "slope": -5.2, "center": 0.4, "viewCone": 30.0, "invView": 1,
         "DPI": 120.0, "screenW": 240, "screenH": 150, "flipImageX": 0, "flipSubp": 1}


@pytest.fixture
def calibration(tmp_path):
    path = tmp_path / "visual.json"
    path.write_text(json.dumps({k: {"value": v} for k, v in PANEL.items()}))
    return path


def test_the_game_takes_views_and_angle_from_the_calibration(setup_from_args, calibration):
    _, backend = setup_from_args("--display", f"lookingglass:{calibration}", "--zones", "4")
    display = backend.settings.display
    assert (display.zones, display.angle_deg) == (4, 30.0)


def test_the_game_refuses_a_malformed_calibration_in_one_line(tmp_path):
    bad = tmp_path / "visual.json"
    bad.write_text("{not json")
    proc = subprocess.run([sys.executable, "-m", "game.commands.holo_game", "--local", "--headless",
                           "--seconds", "1", "--display", f"lookingglass:{bad}"],
                          cwd=ROOT, text=True, capture_output=True, timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("holo-game: error: ") and "not a JSON calibration" in last


def test_the_game_window_fills_the_panel_with_the_interleaved_views(pygame_headless,
                                                                    calibration):
    from game.display import GameWindow, Hud

    il = Interleaver(load_calibration(calibration, views=4))
    window = GameWindow(panel=il)
    assert window.screen.get_size() == (240, 150)
    rng = np.random.default_rng(5)
    colour = rng.integers(0, 256, (4, 40, 64, 3), np.uint8)
    window.draw(colour, "head", 0, Hud(lines=[]))
    shown = window.pixels()
    want = il(colour)
    # the HUD's text is drawn over the top rows; below it the panel is the interleave
    assert np.array_equal(shown[110:], want[110:])
    # a frame with another view count (another client's set_display) is drawn as before
    window.draw(colour[:2], "strip", 0, Hud())
    assert not np.array_equal(window.pixels()[110:], want[110:])
