"""``GalileanStage.new_scene``: a scene load is a discontinuity for the stage."""

from __future__ import annotations

import numpy as np

from service.display import DisplaySettings
from service.galilean import GalileanSettings, GalileanStage
from service.galilean.motion_field import render_with_motion
from service.primitives import sphere
from service.render.pipeline import Renderer
from service.render.scene import Material, MotionState, Scene, SceneObject, Transform


def test_new_scene_shows_nothing_of_the_old_one_until_the_next_render():
    display = DisplaySettings(zones=2, cols=32, rows=24)
    stage = GalileanStage(display, GalileanSettings(order=2, refresh_hz=30.0))
    ball = SceneObject(sphere(0.25, 8, 12), Material((1.0, 0.2, 0.2)),
                       Transform(np.array([-0.2, 0.0, 0.0])),
                       MotionState(velocity=np.array([0.5, 0.0, 0.0])))
    ru = render_with_motion(Renderer(), Scene([ball]), display, 0.0, 30.0)
    stage.update(ru)
    assert np.isfinite(stage.refresh().depth).any()
    assert np.isfinite(stage.refresh().depth).any()  # extrapolated
    stage.update(ru, rendezvous=stage.index + 3)  # a render of the old scene, pending
    stage.new_scene()
    for _ in range(5):  # nothing of the old scene: no galpixel, no pending graft
        out = stage.refresh()
        assert not np.isfinite(out.depth).any() and not out.colour.any()
        assert out.debris.all() and not out.flags["updated"]
    stage.update(ru)
    out = stage.refresh()
    assert out.flags["updated"] and np.isfinite(out.depth).any()
