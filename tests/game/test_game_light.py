"""The game is lit like the demo by default (the service's light, Blinn-Phong);
``--light ambient`` draws flat ambient silhouettes (thesis 5.1.1).

The settings are taken from what :func:`game.commands.holo_game._setup` hands the backend, and the
frames from the real renderer with those settings (issue 6, thesis 5.1.1).
"""

from __future__ import annotations

import numpy as np
import pytest

from game.backends import LocalRenderer
from game.rules import new_game
from game.scene import apply_states, object_states
from service.render.pipeline import Renderer
from service.render.scene import Scene


def _player_only(backend: LocalRenderer, game) -> Scene:
    """The scene the backend was given, placed at the game's start, player alone."""
    scene = apply_states(backend._scene, object_states(new_game(game)))
    return Scene(
        objects=[o for o in scene.objects if o.name == "player"],
        lights=scene.lights,
        ambient=scene.ambient,
    )


def _first_render(backend: LocalRenderer, game):
    """The backend's first refresh showing a render of the game's start."""
    backend.update(object_states(new_game(game)))
    for _ in range(200):  # frame() waits on the refresh thread, no sleeping here
        view = backend.frame(timeout_s=1.0)
        if view is not None and view.render_id >= 0:
            return view
    pytest.fail("the local renderer showed no render")


def _colours(pixels: np.ndarray) -> np.ndarray:
    return np.unique(pixels.reshape(-1, 3), axis=0)


def test_light_ambient_draws_flat_silhouettes(setup_from_args):
    game, backend = setup_from_args("--light", "ambient")
    assert isinstance(backend, LocalRenderer)
    assert backend.settings.render.light.model == "ambient"

    frame = Renderer().render(
        _player_only(backend, game), backend.settings.display, backend.settings.render
    )
    player = np.isfinite(frame.depth)
    assert player.sum() > 100
    assert len(_colours(frame.colour[player])) == 1  # flat: one colour for the whole ship

    # the displayed frame: only the background and one colour per object
    view = _first_render(backend, game)
    assert len(_colours(view.colour)) <= 1 + len(backend._scene.objects)


@pytest.mark.parametrize("argv", [(), ("--full-light",), ("--light", "blinn")])
def test_blinn_phong_is_the_default_and_shades(setup_from_args, argv):
    game, backend = setup_from_args(*argv)
    assert backend.settings.render.light.model == "blinn"

    frame = Renderer().render(
        _player_only(backend, game), backend.settings.display, backend.settings.render
    )
    player = np.isfinite(frame.depth)
    assert player.sum() > 100
    assert len(_colours(frame.colour[player])) > 20  # faces lit differently

    view = _first_render(backend, game)
    assert len(_colours(view.colour)) > 100
