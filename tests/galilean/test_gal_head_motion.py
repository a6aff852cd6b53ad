"""The head-motion update against the induced-motion formula evaluated per galpixel.

The kernel evaluates the motion change as an affine function of each galpixel's
position and depth (coefficients worked out once per zone); the reference here
reconstructs every galpixel's view-frame point and applies the module's formulas
(q' = -w x q - v, q'' = -alpha x q - a + 2 w x v + w x (w x q)) with numpy.
"""

import numpy as np
import pytest

from service.display import DisplaySettings
from service.galilean.fixed_point import Z_EMPTY, Z_LIMIT
from service.galilean.galpixmap import Galpixmap
from service.galilean.head_motion import _per_refresh, apply_viewer_motion
from service.galilean.stage import GalileanSettings, GalileanStage
from service.render.scene import MotionState

HZ = 60.0


def reference(gp: Galpixmap, display: DisplaySettings, margin: int, old: MotionState,
              new: MotionState) -> tuple:
    """(motion, zmotion, changed, clamped) after the update, by the formulas per galpixel."""
    f = gp.fixed
    z, h, w = gp.depth.shape
    live = (gp.debris == 0) & (gp.depth != Z_EMPTY)
    zz, rr, cc = np.nonzero(live)
    s, sh = display.pixel_size, display.shears()[zz]
    d = gp.depth[live] / 2.0**f.fz
    sx = cc - margin + 0.5 + gp.frac[0][live] / 2.0**f.fp
    sy = rr - margin + 0.5 + gp.frac[1][live] / 2.0**f.fp
    q = np.stack([sx * s - display.width / 2 - d * sh, display.height / 2 - sy * s, -d], -1)

    def induced(m: np.ndarray) -> tuple:
        v, a, wv, al = m
        c = np.cross(wv, q)
        return -c - v, -np.cross(al, q) - a + 2 * np.cross(wv, v) + np.cross(wv, c)

    n, o = induced(_per_refresh(new, HZ)), induced(_per_refresh(old, HZ))
    motion, zmotion = gp.motion.astype(np.float64), gp.zmotion.astype(np.float64)
    clamped = 0
    for k in range(min(gp.order, 2)):
        dq = n[k] - o[k]
        lim = (f.v_max, f.a_max)[k] * 2.0**f.fm
        adds = ((dq[:, 0] - dq[:, 2] * sh) / s * 2.0**f.fm, -dq[:, 1] / s * 2.0**f.fm,
                -dq[:, 2] * 2.0**f.fzm)
        for plane, add, bound in ((motion[2 * k], adds[0], lim), (motion[2 * k + 1], adds[1], lim),
                                  (zmotion[k], adds[2], float(Z_LIMIT))):
            val = plane[live] + np.floor(add + 0.5)
            clamped += int((np.abs(val) > bound).sum())
            plane[live] = np.clip(val, -bound, bound)
    return motion, zmotion, int(live.sum()), clamped


def random_map(st: GalileanStage, rng: np.random.Generator) -> Galpixmap:
    gp = Galpixmap.empty(st.settings.order, st.fixed, st.shape, False)
    unit = 1 << st.fixed.fm
    gp.motion[:] = rng.integers(-3 * unit, 3 * unit, gp.motion.shape)
    gp.zmotion[:] = rng.integers(-1000, 1000, gp.zmotion.shape)
    half = 1 << (st.fixed.fp - 1)
    gp.frac[:] = rng.integers(-half, half, gp.frac.shape)
    gp.depth[:] = st.fixed.depth_fixed(rng.uniform(0.3, 6.0, gp.depth.shape))[0]
    gp.depth[rng.random(gp.depth.shape) < 0.05] = Z_EMPTY
    gp.debris[:] = rng.random(gp.debris.shape) < 0.1
    return gp


CASES = [
    (MotionState(), MotionState(angular_velocity=[0.0, 0.6, 0.0])),
    (MotionState(velocity=[0.2, 0.0, 0.1], angular_velocity=[0.1, -0.3, 0.05]),
     MotionState(velocity=[0.1, 0.3, -0.2], acceleration=[0.5, -0.2, 0.3],
                 angular_velocity=[0.3, 0.5, -0.2], angular_acceleration=[0.4, 1.0, -0.6])),
    (MotionState(), MotionState(velocity=[0.0, 0.0, 1e30])),  # absurd: clamped
    # absurd beyond float64 products (1e300 squared): bounded first, never NaN or wrapped
    (MotionState(), MotionState(velocity=[1e300, -1e300, 1e300], acceleration=[1e300] * 3,
                                angular_velocity=[1e300, 1e300, -1e300],
                                angular_acceleration=[-1e300] * 3)),
]


@pytest.mark.parametrize("order", [1, 2, 3])
@pytest.mark.parametrize("case", range(len(CASES)))
@pytest.mark.parametrize("zones,margin", [(1, 0), (3, 4)])
def test_head_motion_update_matches_the_formula(order, case, zones, margin):
    display = DisplaySettings(zones=zones, cols=48, rows=36)
    st = GalileanStage(display, GalileanSettings(order=order, margin=margin))
    gp = random_map(st, np.random.default_rng(10 * order + case))
    old, new = CASES[case]
    motion, zmotion, changed, clamped = reference(gp, display, margin, old, new)
    got = apply_viewer_motion(gp, display, margin, old, new, HZ)
    assert got == (changed, clamped)
    if case >= 2:
        assert clamped > 0
        live = (gp.debris == 0) & (gp.depth != Z_EMPTY)
        bounds = (st.fixed.v_max, st.fixed.a_max)
        for k in range(min(order, 2)):
            lim = bounds[k] * 2.0**st.fixed.fm
            assert np.abs(gp.motion[2 * k:2 * k + 2][:, live]).max() <= lim
            assert np.abs(gp.zmotion[k][live].astype(np.int64)).max() <= Z_LIMIT
    for fast, slow in ((gp.motion, motion), (gp.zmotion, zmotion)):
        diff = np.abs(fast - slow)
        # the same sums in another order: at most one unit where the rounding is a tie
        assert diff.max() <= 1 and (diff > 0).mean() < 1e-3
