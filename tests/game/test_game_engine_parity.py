"""The game's two backends run one engine: the same inputs give the same frames.

:class:`LocalRenderer` (``--local``) and :class:`ServiceBackend` (through a real
``holo-service`` process) are given one scene and one :class:`FrameSettings`; the
frame showing each one's first render is compared pixel for pixel.  The scene is
still, so the render does not depend on when it was aimed, and lit (Blinn-Phong, a
specular highlight, two materials), so a light model, specular mode, background or
stage setting that differed between the two paths would show.  Before the one
engine, the local mode lit the game with another default light model.
"""

from __future__ import annotations

import numpy as np
from testkit import HANG_S, TINY_DISPLAY, wait_until

from game.backends import LocalRenderer, ServiceBackend
from service.display import DisplaySettings
from service.frame_settings import FrameSettings
from service.primitives import cube, sphere
from service.render.scene import Light, Material, Scene, SceneObject, Transform

SETTINGS = FrameSettings(DisplaySettings(zones=2, cols=32, rows=24), refresh_hz=30.0)


def _still_scene() -> Scene:
    """A shiny sphere before a matte cube, one directional light; nothing moves."""
    ball = SceneObject(sphere(0.3, 12, 16), Material((0.9, 0.3, 0.2), ambient=0.2, diffuse=0.6,
                                                      specular=0.6, shininess=24.0),
                       Transform(np.array([-0.2, 0.05, 0.2])), name="ball")
    box = SceneObject(cube(0.5), Material((0.2, 0.5, 0.9), ambient=0.3, diffuse=0.7,
                                          specular=0.0),
                      Transform(np.array([0.25, -0.1, -0.3])), name="box")
    return Scene([ball, box], [Light("directional", np.array([0.4, 0.6, 0.7]))], ambient=0.3)


def _first_render(backend) -> np.ndarray:
    """The colour of the first frame that shows a render of the scene loaded."""
    got: list = []

    def shown() -> bool:
        view = backend.frame(0.2)
        if view is not None and view.render_id >= 0 and view.since_render == 0:
            got.append(view.colour.copy())
        return bool(got)

    assert wait_until(shown, HANG_S, step_s=0.0), "no frame showed a render"
    return got[0]


def test_the_local_engine_and_the_service_show_the_same_frame(service_factory):
    svc = service_factory(*TINY_DISPLAY, "--refresh", "30")
    remote = ServiceBackend(svc.control, svc.frames, settings=SETTINGS, timeout_s=30)
    local = LocalRenderer(SETTINGS)
    try:
        remote.start(_still_scene())
        assert remote.connected
        local.start(_still_scene())
        a, b = _first_render(remote), _first_render(local)
    finally:
        remote.close()
        local.close()
    assert a.shape == b.shape == (2, 24, 32, 3)
    lit = a.reshape(-1, 3)
    assert len(np.unique(lit, axis=0)) > 20  # shaded, not flat: the comparison means something
    assert np.array_equal(a, b)
