"""holo-game --local: the in-process renderer (pipeline + Galilean stage), headless."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pygame

from game.actions import (
    BUTTON_BINDINGS,
    DIAL_AXES,
    HAT_BINDINGS,
    HAT_NAMES,
    KEY_BINDINGS,
    PAD_AXES,
    PAD_BUTTONS,
)
from game.commands import holo_game as cli
from game.display import headless_env

ROOT = Path(__file__).resolve().parents[2]


def test_local_headless_bot_run_writes_screenshots_and_stats(tmp_path, capsys):
    # it ends on a condition, the first game's score screen (--games 1), not after 5 s:
    # on a loaded machine the game runs slower than the clock (a tick advances it at
    # most 0.1 s) and its game over came too late for gameover.png (2 s into it)
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
            "120",
            "--games",
            "1",
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
    assert stats["games"] == 1 and stats["seconds"] < 60  # stopped by --games, not the time
    assert (out / "mode-head.png").exists() and (out / "gameover.png").exists()
    assert (out / "score.png").exists()
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


def help_sections(text: str) -> dict[str, dict[str, set[str]]]:
    """The epilog's sections: title -> action -> its inputs."""
    sections: dict[str, dict[str, set[str]]] = {}
    current = None
    bindings = text[text.index("\nkeys:") + 1 :].split("\nExit status:")[0]  # the rule ends it
    for line in bindings.splitlines():
        if line and not line.startswith(" "):
            current = sections.setdefault(line.split(" ")[0].rstrip(":"), {})
        elif line.strip() and current is not None:
            action, inputs = re.split(r"\s{2,}", line.strip(), maxsplit=1)
            current[action.split(" (")[0]] = set(inputs.split(", "))
    return sections


def expected(pairs) -> dict[str, set[str]]:
    out: dict[str, set[str]] = {}
    for name, action in pairs:
        out.setdefault(action, set()).add(name)
    return out


def test_help_lists_every_key_dial_box_and_gamepad_binding():
    run = subprocess.run(
        [sys.executable, "-m", "game.commands.holo_game", "--help"],
        cwd=ROOT, env=headless_env(), capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    got = help_sections(run.stdout)
    assert set(got) == {"keys", "dial", "gamepad"}
    assert got["keys"] == expected((pygame.key.name(k), a) for k, a in KEY_BINDINGS.items())
    assert "mode_autostereogram" in run.stdout and "not available" not in run.stdout
    buttons = expected((f"button {b}", a) for b, a in BUTTON_BINDINGS.items())
    assert {a: got["dial"][a] for a in buttons} == buttons
    assert {f"dial {i}" for i in DIAL_AXES} == set().union(
        *(v for a, v in got["dial"].items() if a.startswith("along"))
    )
    pad = expected([*PAD_BUTTONS.items(), *((HAT_NAMES[v], a) for v, a in HAT_BINDINGS.items())])
    assert {a: got["gamepad"][a] for a in pad} == pad
    sticks = set().union(*(v for a, v in got["gamepad"].items() if a.startswith("along")))
    assert sticks == set(PAD_AXES)
