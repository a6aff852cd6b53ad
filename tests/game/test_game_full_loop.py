"""The whole loop in real processes: service, simulated devices on ptys, driver, game."""

from __future__ import annotations

import json
import sys

import pytest

from game import full_demo

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="pty pairs need POSIX")


def test_full_loop_with_simulated_devices_and_a_real_service(tmp_path, capsys):
    out = tmp_path / "demo-out"
    rc = full_demo.main(["--out", str(out), "--seconds", "9", "--gives-up", "1.5", "--headless"])
    assert rc == 0, capsys.readouterr().err
    stats = json.loads((out / "stats.json").read_text())
    assert set(stats) >= {
        "refreshes",
        "renders",
        "refresh_hz",
        "update_hz",
        "score",
        "modes",
        "tracker_events",
        "dial_events",
    }
    assert stats["refreshes"] > 50 and stats["renders"] > 3
    assert stats["tracker_events"] > 50 and stats["dial_events"] > 5
    assert stats["beeps"] == 3 and stats["scores"]  # the bot gave up: one game over
    assert stats["modes"] == ["autostereogram", "head", "strip", "zone"]
    for name in ("mode-head.png", "mode-strip.png", "mode-zone.png", "mode-autostereogram.png",
                 "film.png", "gameover.png"):
        assert (out / name).stat().st_size > 1000
    assert "holo-service at tcp://127.0.0.1:" in capsys.readouterr().out
