"""Headless SDL for every game test (set before pygame opens a display)."""

from __future__ import annotations

import os

import pytest

from game.display import SDL_HEADLESS

os.environ.update(SDL_HEADLESS)


@pytest.fixture
def pygame_headless():
    import pygame

    pygame.init()
    try:
        yield pygame
    finally:
        pygame.quit()


@pytest.fixture
def setup_from_args(tmp_path, monkeypatch):
    """Parse a ``holo-game --local --headless`` command line and run ``cli._setup`` on it.

    ``setup(*extra)`` returns ``(game, backend)``; every backend is closed at the end.
    ``local=False`` leaves ``--local`` out (the game then uses ``--service``).
    The level-of-detail cache goes to a temporary folder.
    """
    from game.commands import holo_game as cli

    monkeypatch.setenv("HOLO_LOD_CACHE", str(tmp_path / "lod"))
    opened = []

    def setup(*extra: str, local: bool = True):
        parser = cli.build_parser()
        args = parser.parse_args([*(["--local"] if local else []), "--headless", "--size",
                                  "120x90",
                                  "--highscores", str(tmp_path / "hs.json"), *extra])
        cli.check_args(parser, args)
        game, backend, *_ = cli._setup(args)
        opened.append(backend)
        return game, backend

    try:
        yield setup
    finally:
        import pygame

        for backend in opened:
            backend.close()
        pygame.quit()
