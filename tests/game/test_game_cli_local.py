"""holo-game --local: the in-process renderer (pipeline + Galilean stage), headless."""

from __future__ import annotations

import json

from game import cli


def test_local_headless_bot_run_writes_screenshots_and_stats(tmp_path, capsys):
    out = tmp_path / "out"
    scores = str(tmp_path / "hs.json")
    rc = cli.main(
        [
            "--local",
            "--bot",
            "--bot-gives-up",
            "0.5",
            "--headless",
            "--seconds",
            "5",
            "--size",
            "120x90",
            "--out",
            str(out),
            "--highscores",
            scores,
        ]
    )
    assert rc == 0
    stats = json.loads((out / "stats.json").read_text())
    assert stats == json.loads(capsys.readouterr().out.splitlines()[-1]) | {}
    assert stats["refreshes"] > 20 and stats["renders"] > 2 and stats["beeps"] == 3
    assert (out / "mode-head.png").exists() and (out / "gameover.png").exists()
    assert json.loads((tmp_path / "hs.json").read_text())["scores"][0]["name"] == "bot"


def test_lamp_mask_and_bad_arguments(capsys, tmp_path):
    assert cli.main(["--print-lamps"]) == 0
    assert capsys.readouterr().out.strip() == "0x0000007f"
    bad = tmp_path / "a.obj"
    bad.write_text("this is not a mesh\n")
    assert (
        cli.main(
            [
                "--local",
                "--headless",
                "--seconds",
                "1",
                "--attackers",
                str(bad),
                "--highscores",
                str(tmp_path / "hs.json"),
            ]
        )
        == 2
    )
    assert "holo-game:" in capsys.readouterr().err
