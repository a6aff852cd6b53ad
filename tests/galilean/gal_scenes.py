"""Small scenes the Galilean render and shadow tests share: tilted boxes, flat light."""

import numpy as np

from service.display import DisplaySettings
from service.primitives import cube
from service.render.light import LightSettings
from service.render.pipeline import RenderSettings
from service.render.scene import (
    Material,
    MotionState,
    SceneObject,
    Transform,
    axis_angle_quaternion,
)

HZ = 60.0
DISP = DisplaySettings(zones=1, cols=48, rows=32, width=2.0)
FLAT = RenderSettings(light=LightSettings("ambient"))


def box(pos, size=0.5, colour=(0.9, 0.5, 0.2), **motion) -> SceneObject:
    """A cube of edge ``size`` at ``pos``, tilted 0.4 rad about (1, 1, 0), lit by ambient only.

    ``motion``: :class:`service.render.scene.MotionState` fields (velocity, angular_velocity, ...).
    """
    return SceneObject(cube(size), Material(colour=colour, ambient=1.0),
                       Transform(np.array(pos, float), axis_angle_quaternion([1, 1, 0], 0.4)),
                       MotionState(**motion))
