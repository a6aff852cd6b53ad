"""The whole loop in real processes: service, simulated devices on ptys, driver, game."""

from __future__ import annotations

import json
import sys

import pytest

from game.commands import make_demo as full_demo
from game.run_folders import read_latest

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="pty pairs need POSIX")


def test_full_loop_with_simulated_devices_and_a_real_service(tmp_path, capsys):
    root = tmp_path / "demo-out"
    # the look adapts (measured through the service), so the rates hold on a busy machine
    rc = full_demo.main(["--out", str(root), "--seconds", "9", "--gives-up", "1.5",
                         "--headless"])
    assert rc == 0, capsys.readouterr().err
    out = read_latest(root)
    assert out.parent == root and out.is_dir()
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
    look = stats["look"]
    assert look["adapted"] and look["measured"] and look["reason"]
    said = capsys.readouterr().out
    assert "holo-service at tcp://127.0.0.1:" in said
    w, h = look["size"]
    assert f" light at {w}x{h} per zone" in said
    assert "chosen by measuring renders/s (" in said and look["reason"] in said


@pytest.mark.parametrize(("argv", "look"), [
    ([], ["--adapt"]),
    (["--light", "ambient", "--size", "96x64"], ["--light", "ambient", "--size", "96x64"]),
    (["--size", "96x64"], ["--light", "blinn", "--size", "96x64"]),
    (["--light", "ambient"], ["--light", "ambient", "--size", "240x180"]),
])
def test_the_demo_adapts_its_look_unless_one_is_given(tmp_path, argv, look):
    args = full_demo.build_parser().parse_args(argv)
    args.run = tmp_path
    cmd = full_demo.game_args(args, "tcp://127.0.0.1:5555", "tcp://127.0.0.1:5560", True)
    assert cmd[cmd.index("--devices") + 2:cmd.index("--bot")] == look
    assert cmd[cmd.index("--out") + 1] == str(tmp_path)


@pytest.mark.parametrize(
    ("refresh_hz", "update_hz", "warned"),
    [(0.0, 0.0, "never got a frame"), (41.8, 7.7, "41.8 refreshes/s (meant: 50) and 7.7 "
     "renders/s (meant: 10)"), (59.9, 4.0, "4.0 renders/s"), (59.9, 15.0, None)],
)
def test_the_summary_warns_when_the_rates_fall_short(refresh_hz, update_hz, warned):
    stats = {"refreshes": int(refresh_hz * 20), "refresh_hz": refresh_hz, "update_hz": update_hz,
             "look": {"light": "blinn", "size": [240, 180]}}
    lines = full_demo.rate_warnings(stats)
    if warned is None:
        assert lines == []
    else:
        assert len(lines) == 1 and warned in lines[0]
        assert refresh_hz == 0 or "--light ambient or --size 160x120" in lines[0]


@pytest.mark.parametrize(("light", "size", "hint"), [
    ("ambient", [240, 180], "; --size 160x120 lightens the load"),
    ("blinn", [160, 120], "; --light ambient lightens the load"),
    ("ambient", [160, 120], None),
])
def test_the_warning_suggests_only_what_the_run_did_not_use(light, size, hint):
    stats = {"refreshes": 600, "refresh_hz": 30.0, "update_hz": 2.0,
             "look": {"light": light, "size": size}}
    (line,) = full_demo.rate_warnings(stats)
    if hint is None:
        assert "lightens" not in line and line.endswith("than two quiet cores")
    else:
        assert line.endswith(hint), line
