"""Head-motion update: the viewer's own motion added to every galpixel (section 4.2).

A static world point at view-frame position ``q`` (reconstructed from the
galpixel's pixel position, fraction and depth through the zone's projection), seen
by a viewer moving with velocity ``v``, acceleration ``a``, angular velocity ``w``
and angular acceleration ``alpha`` (all in the viewer's frame, per refresh), moves
in the viewer's frame as

    q'  = -w x q - v
    q'' = -alpha x q - a + 2 w x v + w x (w x q)

(second order in time of ``q(t) = R(t)^T (q0 - p(t))``).  The projection is affine,
so the apparent motion is the projection's linear part applied to these.  Renders
already contain the viewer motion they were made with; a head-motion update adds
the *difference* between the new filtered viewer motion and the one already in the
map, evaluated at each galpixel's own depth.  Empty (depth +inf) and debris pixels
are left alone; results beyond the integral bits are clamped.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from service.display import DisplaySettings
from service.galilean.fixed_point import Z_EMPTY, Z_LIMIT
from service.galilean.galpixmap import Galpixmap
from service.scene import MotionState


def _per_refresh(m: MotionState, hz: float) -> np.ndarray:
    """(4, 3): v, a, w, alpha in per-refresh units."""
    t = 1.0 / hz
    return np.stack([m.velocity * t, m.acceleration * t * t, m.angular_velocity * t,
                     m.angular_acceleration * t * t])


@nb.njit(cache=True, inline="always")
def _cross(a0: float, a1: float, a2: float, b0: float, b1: float, b2: float) -> tuple:
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@nb.njit(cache=True, inline="always")
def _induced(m: np.ndarray, q0: float, q1: float, q2: float) -> tuple:
    """(q', q'') of a static point at q for viewer motion m (4, 3)."""
    v, a, w, al = m[0], m[1], m[2], m[3]
    c = _cross(w[0], w[1], w[2], q0, q1, q2)
    d1 = (-c[0] - v[0], -c[1] - v[1], -c[2] - v[2])
    e = _cross(al[0], al[1], al[2], q0, q1, q2)
    f = _cross(w[0], w[1], w[2], v[0], v[1], v[2])
    g = _cross(w[0], w[1], w[2], c[0], c[1], c[2])
    d2 = (-e[0] - a[0] + 2 * f[0] + g[0], -e[1] - a[1] + 2 * f[1] + g[1],
          -e[2] - a[2] + 2 * f[2] + g[2])
    return d1, d2


@nb.njit(cache=True)
def _apply(
    frac: np.ndarray, depth: np.ndarray, debris: np.ndarray, motion: np.ndarray,
    zmotion: np.ndarray, old: np.ndarray, new: np.ndarray, geo: np.ndarray, shears: np.ndarray,
    fp: int, fm: int, limits: np.ndarray, order: int, fz: int, fzm: int,
) -> tuple:
    """Add the induced-motion difference to every galpixel.

    ``geo`` is (pixel size, width, height, margin); ``limits`` (2,) the velocity and
    acceleration bounds in px per refresh^n.  Returns (galpixels changed, values
    clamped): sums beyond the bounds, or z motion beyond the depth format, are
    clamped there rather than wrapped.
    """
    s, width, height, margin = geo[0], geo[1], geo[2], geo[3]
    scale = 2.0**fm
    zlim = np.float64(Z_LIMIT)
    count = clamped = 0
    nz, h, w = depth.shape
    for z in range(nz):
        sh = shears[z]
        for r in range(h):
            for c in range(w):
                if debris[z, r, c] == 1 or depth[z, r, c] == Z_EMPTY:
                    continue
                d = depth[z, r, c] / 2.0**fz
                sx = c - margin + 0.5 + frac[0, z, r, c] / 2.0**fp
                sy = r - margin + 0.5 + frac[1, z, r, c] / 2.0**fp
                qz = -d
                qx = sx * s - width / 2 + qz * sh
                qy = height / 2 - sy * s
                n1, n2 = _induced(new, qx, qy, qz)
                o1, o2 = _induced(old, qx, qy, qz)
                for k in range(min(order, 2)):
                    dq = (n1[0] - o1[0], n1[1] - o1[1], n1[2] - o1[2]) if k == 0 else \
                        (n2[0] - o2[0], n2[1] - o2[1], n2[2] - o2[2])
                    dx = (dq[0] - dq[2] * sh) / s
                    dy = -dq[1] / s
                    lim = limits[k] * scale
                    mx = motion[2 * k, z, r, c] + np.floor(dx * scale + 0.5)
                    my = motion[2 * k + 1, z, r, c] + np.floor(dy * scale + 0.5)
                    mz = zmotion[k, z, r, c] + np.floor(-dq[2] * 2.0**fzm + 0.5)
                    clamped += (abs(mx) > lim) + (abs(my) > lim) + (abs(mz) > zlim)
                    motion[2 * k, z, r, c] = min(max(mx, -lim), lim)
                    motion[2 * k + 1, z, r, c] = min(max(my, -lim), lim)
                    zmotion[k, z, r, c] = min(max(mz, -zlim), zlim)
                count += 1
    return count, clamped


def apply_viewer_motion(
    gp: Galpixmap, display: DisplaySettings, margin: int, old: MotionState, new: MotionState,
    refresh_hz: float,
) -> int:
    """Replace the viewer motion in every galpixel's apparent motion, in place.

    Parameters
    ----------
    gp : Galpixmap
        Map of shape (Z, R + 2 margin, C + 2 margin).
    display : DisplaySettings
    margin : int
    old, new : MotionState
        Viewer motion already in the map and the new one (viewer frame, per second).
    refresh_hz : float

    Returns
    -------
    changed : int
        Galpixels changed (0 for a G(0) map, which has no motion).
    clamped : int
        Motion values that went past the format's velocity, acceleration or z
        bounds and were clamped there (an absurd viewer motion never wraps).
    """
    if gp.order == 0:
        return 0, 0
    geo = np.array([display.pixel_size, display.width, display.height, margin], np.float64)
    limits = np.array([gp.fixed.v_max, gp.fixed.a_max], np.float64)
    changed, clamped = _apply(gp.frac, gp.depth, gp.debris, gp.motion, gp.zmotion,
                              _per_refresh(old, refresh_hz), _per_refresh(new, refresh_hz), geo,
                              display.shears(), gp.fixed.fp, gp.fixed.fm, limits, gp.order,
                              gp.fixed.fz, gp.fixed.fzm)
    return int(changed), int(clamped)
