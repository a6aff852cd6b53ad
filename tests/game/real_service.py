"""The game tests' side of a real ``holo-service``: a game that keeps trying to reach it."""

from __future__ import annotations

from game.backends import ServiceBackend
from game.client_loop import GameClient, LoopSettings
from game.display import GameWindow
from game.rules import GameSettings
from game.scene import game_scene
from service.base.errors import ServiceError
from service.display import DisplaySettings
from service.frame_settings import FrameSettings


def attract_client(
    control: str, frames: str, window: GameWindow
) -> tuple[ServiceBackend, GameClient]:
    """An easy attract-mode game on a service (3 zones of 80x60) that may not be up yet.

    The first ``start`` may fail (the service is not listening yet): the game loop
    keeps trying.  The caller closes the backend.
    """
    settings = FrameSettings(DisplaySettings(zones=3, cols=80, rows=60))
    backend = ServiceBackend(control, frames, settings=settings, timeout_s=0.5)
    try:
        backend.start(game_scene(6))
    except ServiceError:
        pass  # not listening yet: the loop keeps trying
    except BaseException:
        backend.close()
        raise
    settings = LoopSettings(GameSettings(difficulty="easy"), attract=True)
    return backend, GameClient(backend, window, settings)
