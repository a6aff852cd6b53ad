"""holo-render --display lookingglass:CALIBRATION.json (the game's: tests/game)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from service.commands import holo_render as cli_render
from service.lookingglass import Interleaver, load_calibration
from service.png import read_png
from service.render.frame import quilt_name

#: A small made-up panel (the views' 64x40 fill it exactly).
PANEL = {"pitch": 41.0, "slope": -5.2, "center": 0.4, "viewCone": 30.0, "invView": 1,
         "DPI": 120.0, "screenW": 128, "screenH": 80, "flipImageX": 0, "flipSubp": 1}


@pytest.fixture
def calibration(tmp_path):
    path = tmp_path / "visual.json"
    path.write_text(json.dumps({k: {"value": v} for k, v in PANEL.items()}))
    return path


def test_holo_render_writes_the_quilt_and_the_interleaved_panel(tmp_path, calibration, capsys):
    out = tmp_path / "out"
    assert cli_render.main(["builtin:sphere_torus", "--display", f"lookingglass:{calibration}",
                            "--zones", "6", "--size", "64x40", "--out", str(out),
                            "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["settings"]["zones"] == 6 and report["settings"]["angle_deg"] == 30.0
    zones = np.stack([read_png(out / f"zone-{k:02d}.png") for k in range(6)])
    assert (out / quilt_name(3, 2, 64, 40)).is_file()
    panel = read_png(out / "lookingglass-128x80.png")
    want = Interleaver(load_calibration(calibration, views=6))(zones)
    assert np.array_equal(panel, want) and panel.any()


@pytest.mark.parametrize(("extra", "words"), [
    (("--angle", "10"), "--angle: with --display the calibration's viewCone sets it"),
    ((), "calibration has no slope"),
])
def test_holo_render_refuses_in_one_line(tmp_path, calibration, capsys, extra, words):
    if not extra:
        calibration.write_text(json.dumps({"pitch": {"value": 41.0}}))
    out = tmp_path / "out"
    assert cli_render.main(["builtin:sphere_torus", "--display", f"lookingglass:{calibration}",
                            *extra, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0] and err[0].startswith("holo-render: error: ")
    assert not list(out.glob("*.png"))  # nothing written
