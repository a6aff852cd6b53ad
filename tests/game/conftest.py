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
