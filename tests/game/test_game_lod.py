"""``holo-game --lod``: the game's renderer draws each object at its level of detail."""

from __future__ import annotations

import pygame
import pytest

from game import cli
from game.backends import LocalRenderer
from game.rules import new_game
from game.scene import object_states


@pytest.fixture
def backend_from(tmp_path, monkeypatch):
    monkeypatch.setenv("HOLO_LOD_CACHE", str(tmp_path / "lod"))
    opened = []

    def setup(*extra: str):
        parser = cli.build_parser()
        args = parser.parse_args(["--local", "--headless", "--size", "120x90",
                                  "--highscores", str(tmp_path / "hs.json"), *extra])
        cli.check_args(parser, args)
        game, backend, *_ = cli._setup(args)
        opened.append(backend)
        return game, backend

    try:
        yield setup
    finally:
        for backend in opened:
            backend.close()
        pygame.quit()


def test_lod_on_reaches_the_local_renderer(backend_from, tmp_path):
    game, backend = backend_from("--lod-error", "0.75")
    assert isinstance(backend, LocalRenderer)
    assert backend.render_settings.lod is not None
    assert backend.render_settings.lod.error_px == 0.75
    backend.update(object_states(new_game(game)))
    for _ in range(200):  # frame() waits on the refresh thread
        view = backend.frame(timeout_s=1.0)
        if view is not None and view.render_id >= 0:
            break
    else:
        pytest.fail("the local renderer showed no render")
    levels = backend._renderer.lod.previous  # the render thread chose a level per object
    assert levels is not None and levels.size == len(backend._scene.objects)
    assert any((tmp_path / "lod").glob("*.json"))  # the attackers' chain was cached


def test_lod_off_by_default_and_bad_budget_refused(backend_from, capsys):
    _, backend = backend_from()
    assert backend.render_settings.lod is None
    with pytest.raises(SystemExit) as stop:
        cli.build_parser().parse_args(["--lod-error", "0"])
    assert stop.value.code == 2
    assert "--lod-error" in capsys.readouterr().err
