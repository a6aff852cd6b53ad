"""Head-tracked play with a late render: the ship must not scatter into fragments.

The demo's tracker sways the head (``sway:scale=2``: turns of up to ~60 deg/s).
Each pose's viewer motion goes into every galpixel (the head-motion update), and a
render made with the viewer's pose carries that motion too.  When a render came
late on a loaded machine (gaps of 0.6-1.3 s were measured in ``make demo``), the
stage went on extrapolating the turn far past its rating (``n_prop`` refreshes):
an affine field extrapolated for a second shears the ship, whose galpixels then
land in scattered fragments far from where any render put it (seen in film.png
as the head moved from zone to zone, which is when it moves fastest).

The measure: ship galpixels (object 0, not debris) that lie more than 2 px from
the ship of every fresh render made over the gap.  The service's stage
(:func:`service.engine.refresh.stage_settings`) holds the picture past the rating.
"""

from __future__ import annotations

import numpy as np

from game.rules import new_game
from game.scene import apply_states, game_scene, object_states
from service.display import DisplaySettings
from service.engine.refresh import stage_settings
from service.engine.state import Settings
from service.galilean import GalileanStage
from service.galilean.motion_field import render_with_motion
from service.render.light import LightSettings
from service.render.pipeline import Renderer, RenderSettings
from service.render.scene import MotionState, Transform, euler_quaternion
from sim_devices.motion import Sway

HZ = 50.0
DISPLAY = DisplaySettings(3, 16.0, 160, 120)
SWAY = Sway(scale=2.0)  # the demo's tracker
T0 = 3.0  # seconds into the sway: the head turning fast


def _pose(t: float) -> np.ndarray:
    p = SWAY.pose(t)
    return np.array([p.x, p.y, p.z, p.yaw, p.pitch, p.roll], float)


def _viewer(t: float) -> tuple[Transform, MotionState]:
    """The viewer as the service's tracker gives it (mm to world units, degrees)."""
    s, h = _pose(t), 1e-3
    v = (_pose(t + h) - _pose(t - h)) / (2 * h)
    a = (_pose(t + h) - 2 * s + _pose(t - h)) / h**2
    yaw, pitch, roll = np.radians(s[3:6])
    rates = np.radians(v[3:6])
    pose = Transform((s[:3] - _pose(0.0)[:3]) * 1e-3, euler_quaternion(yaw, pitch, roll))
    return pose, MotionState(v[:3] * 1e-3, a[:3] * 1e-3, np.array([rates[1], rates[0], rates[2]]))


def _near(mask: np.ndarray, r: int) -> np.ndarray:
    out = mask.copy()
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            out |= np.roll(np.roll(mask, dy, -2), dx, -1)
    return out


def test_late_render_under_a_head_turn_leaves_no_scattered_ship_fragments():
    scene = apply_states(game_scene(6, True), object_states(new_game()))
    renderer = Renderer()
    rs = RenderSettings(method="zbuffer", light=LightSettings("blinn"))

    def render(t: float):
        return render_with_motion(renderer, scene, DISPLAY, 0.0, HZ, rs, *_viewer(t))

    svc = Settings(display=DISPLAY, galpixel_order=2, refresh_hz=HZ)
    stage = GalileanStage(DISPLAY, stage_settings(svc))
    first = render(T0)
    stage.update(first)
    stage.refresh()
    ship = first.obj == 0
    assert ship.sum() > 300  # the ship is in view
    for k in range(1, 49):  # ~1 s without a render; the tracker's poses keep coming
        stage.viewer(_viewer(T0 + k / HZ)[1])
        out = stage.refresh()
        if k % 8 == 0:
            ship |= render(T0 + k / HZ).obj == 0
    shown = (stage.map.obj == 0) & (stage.map.debris == 0)
    stray = int((shown & ~_near(ship, 2)).sum())
    # extrapolated all the way: 541 stray galpixels here and the ship 2.5x its size
    assert stray < 40, f"{stray} ship galpixels scattered away from every render's ship"
    assert shown.sum() < 1.5 * (first.obj == 0).sum()
    assert out.flags["held"] and out.flags["age"] == 48
