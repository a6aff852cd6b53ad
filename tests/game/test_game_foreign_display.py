"""Another client's ``set_display`` can leave the game's frames without colour.

Display settings belong to the service, not to a client: a second client that asks
for ``encodings=["depth"]`` makes the frame stream carry no ``colour`` array.  The
game's backend then shows nothing new and counts the frames it could not draw; it
raised KeyError out of ``frame()`` and the game stopped.
"""

from __future__ import annotations

from testkit import TINY_DISPLAY, wait_until

from game.backends import ServiceBackend
from game.scene import game_scene
from service.display import DisplaySettings
from service.frame_settings import FrameSettings
from service.net.client import ServiceClient


def test_frames_without_colour_are_counted_not_a_crash(service_factory):
    svc = service_factory(*TINY_DISPLAY, "--refresh", "30")
    backend = ServiceBackend(svc.control, svc.frames, settings=FrameSettings(
        DisplaySettings(zones=2, cols=32, rows=24), refresh_hz=30.0), timeout_s=30)
    other = ServiceClient(svc.control, timeout_s=30)
    try:
        backend.start(game_scene(3))
        assert wait_until(lambda: backend.frame(0.5), 120)  # the first render may compile
        other.set_display(encodings=["depth"])
        assert wait_until(lambda: backend.frame(0.2) is None and backend.unusable_frames >= 5,
                          60, step_s=0.0)
        other.set_display(encodings=["colour"])
        got = wait_until(lambda: backend.frame(0.5), 60)
    finally:
        other.close()
        backend.close()
    assert got.colour.shape == (2, 24, 32, 3)
