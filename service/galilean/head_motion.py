"""Head-motion update: the viewer's own motion added to every galpixel (section 4.2).

A static world point at view-frame position ``q`` (reconstructed from the
galpixel's pixel position, fraction and depth through the zone's projection), seen
by a viewer moving with velocity ``v``, acceleration ``a``, angular velocity ``w``
and angular acceleration ``alpha`` (all in the viewer's frame, per refresh), moves
in the viewer's frame as

    q'  = -w x q - v
    q'' = -alpha x q - a + 2 w x v + w x (w x q)

(second order in time of ``q(t) = R(t)^T (q0 - p(t))``).  The projection is affine,
so the apparent motion is the projection's linear part applied to these; and since
q is affine in the galpixel's pixel position and depth, so is the motion change:
:func:`pixel_coefficients` works it out once per zone and the per-galpixel kernel
only evaluates it (three multiply-adds per component).  Renders
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
from service.numba_subroutine import subroutine
from service.render.scene import MotionState

#: Bound on every per-refresh viewer motion component (view units or radians per
#: refresh^n): far past anything the format can hold, small enough that the
#: products below stay finite (1e300 squared would overflow and give inf - inf).
MOTION_BOUND = 1e6


def _per_refresh(m: MotionState, hz: float) -> np.ndarray:
    """(4, 3): v, a, w, alpha in per-refresh units, each within :data:`MOTION_BOUND`."""
    t = 1.0 / hz
    per = np.stack([m.velocity * t, m.acceleration * t * t, m.angular_velocity * t,
                    m.angular_acceleration * t * t])
    return np.clip(per, -MOTION_BOUND, MOTION_BOUND)


def _skew(a: np.ndarray) -> np.ndarray:
    """(3, 3) matrix of ``q -> a x q``."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def induced_affine(m: np.ndarray) -> tuple:
    """Velocity q' and acceleration q'' of a static point, affine in its position q.

    Parameters
    ----------
    m : ndarray, shape (4, 3)
        v, a, w, alpha per refresh (:func:`_per_refresh`).

    Returns
    -------
    tuple of ndarray
        ``(M1, m1, M2, m2)``: q' = M1 q + m1, q'' = M2 q + m2; M (3, 3), m (3,).
    """
    v, a, w, al = m
    ww = np.outer(w, w) - np.dot(w, w) * np.eye(3)  # q -> w x (w x q)
    return -_skew(w), -v, -_skew(al) + ww, -a + 2.0 * np.cross(w, v)


def pixel_coefficients(old: np.ndarray, new: np.ndarray, geo: np.ndarray, shears: np.ndarray,
                       scales: np.ndarray) -> np.ndarray:
    """The motion change of a galpixel as affine functions of its position, per zone.

    A galpixel at pixel position (sx, sy) (its column and row from the top left
    of the display, centre 0.5, fraction included) and depth d (depth units) is the
    view-frame point q = (sx s - width / 2 - d shear, height / 2 - sy s, -d); its
    apparent motion is the projection's linear part applied to q' and q''.  Both
    are affine in q, so the change from viewer motion ``old`` to ``new`` is affine
    in (sx, sy, d).

    Parameters
    ----------
    old, new : ndarray, shape (4, 3)
        Viewer motion per refresh, already in the map and new.
    geo : ndarray, shape (4,)
        Pixel size s, display width, height (view units), margin (px).
    shears : ndarray, shape (Z,)
    scales : ndarray, shape (3,)
        Fixed-point units per px (x and y motion) and per depth unit (z motion),
        applied to the outputs: 2^fm, 2^fm, 2^fzm.

    Returns
    -------
    ndarray, shape (Z, 2, 3, 4)
        For zone z, derivative k (velocity, acceleration), output (x, y, z motion in
        fixed-point units): coefficients of (1, sx, sy, d).
    """
    s, width, height = geo[0], geo[1], geo[2]
    n, o = induced_affine(new), induced_affine(old)
    out = np.zeros((len(shears), 2, 3, 4))
    for z, sh in enumerate(shears):
        # q = q0 + qsx sx + qsy sy + qd d
        basis = np.array([[-width / 2, height / 2, 0.0], [s, 0.0, 0.0], [0.0, -s, 0.0],
                          [-sh, 0.0, -1.0]]).T  # (3, 4)
        proj = np.array([[1.0 / s, 0.0, -sh / s], [0.0, -1.0 / s, 0.0], [0.0, 0.0, -1.0]])
        for k in range(2):
            dm, dc = n[2 * k] - o[2 * k], n[2 * k + 1] - o[2 * k + 1]
            lin = dm @ basis
            lin[:, 0] += dc
            out[z, k] = (proj @ lin) * scales[:, None]
    return out


@nb.njit(cache=True, inline="always")
def _add(
    mx_plane: np.ndarray, my_plane: np.ndarray, mz_plane: np.ndarray, z: int, r: int, c: int,
    vx: float, vy: float, vz: float, lim: float, zlim: float,
) -> int:
    """Add (vx, vy, vz) (fixed-point units, rounded) to one derivative's planes; clamped.

    The planes are that derivative's x and y motion and its z motion, (Z, R, C)
    each.  A sum that is not a number (never for a bounded viewer motion) leaves
    the value as it was and counts as clamped.
    """
    if np.isnan(vx) or np.isnan(vy) or np.isnan(vz):
        return 3
    mx = mx_plane[z, r, c] + np.floor(vx + 0.5)
    my = my_plane[z, r, c] + np.floor(vy + 0.5)
    mz = mz_plane[z, r, c] + np.floor(vz + 0.5)
    mx_plane[z, r, c] = min(max(mx, -lim), lim)
    my_plane[z, r, c] = min(max(my, -lim), lim)
    mz_plane[z, r, c] = min(max(mz, -zlim), zlim)
    return (abs(mx) > lim) + (abs(my) > lim) + (abs(mz) > zlim)


@subroutine(nrt=True)
def _apply_row(
    z: int, r: int, f0: np.ndarray, f1: np.ndarray, depth: np.ndarray, debris: np.ndarray,
    m0: np.ndarray, m1: np.ndarray, m2: np.ndarray, m3: np.ndarray, z0: np.ndarray,
    z1: np.ndarray, coef: np.ndarray, margin: float, fp: int, fz: int, limits: np.ndarray,
    order: int,
) -> tuple:
    """:func:`_apply` for row ``r`` of zone ``z``: (changed, clamped).

    The coefficients go into scalars first: taking a view of ``coef`` per galpixel
    (a reference-counted object in numba) made the kernel 2.7-3x slower, and
    indexing ``coef`` per galpixel 2.3-2.8x slower (the loads cannot be hoisted
    past the stores into ``motion``).
    """
    unit_z, unit_p = 2.0**-fz, 2.0**-fp
    zlim = np.float64(Z_LIMIT)
    sy0 = r - margin + 0.5
    # (derivative k, output x/y/z): constant, per sx, per sy, per d; the row's sy0 folded in
    a = np.empty((2, 3, 3))
    for k in range(2):
        for o in range(3):
            a[k, o, 0] = coef[z, k, o, 0] + coef[z, k, o, 2] * sy0
            a[k, o, 1] = coef[z, k, o, 1]
            a[k, o, 2] = coef[z, k, o, 3]
    ax0, ax1, ax2, ay0, ay1, ay2, az0, az1, az2 = a[0].ravel()
    bx0, bx1, bx2, by0, by1, by2, bz0, bz1, bz2 = a[1].ravel()
    cy0, cy1, cy2 = coef[z, 0, 0, 2], coef[z, 0, 1, 2], coef[z, 0, 2, 2]
    dy0, dy1, dy2 = coef[z, 1, 0, 2], coef[z, 1, 1, 2], coef[z, 1, 2, 2]
    vlim, alim = limits[0], limits[1]
    count = clamped = 0
    for c in range(depth.shape[2]):
        if debris[z, r, c] == 1 or depth[z, r, c] == Z_EMPTY:
            continue
        sx = c - margin + 0.5 + f0[z, r, c] * unit_p
        fy = f1[z, r, c] * unit_p  # sy = sy0 + fy
        d = depth[z, r, c] * unit_z
        clamped += _add(m0, m1, z0, z, r, c, ax0 + ax1 * sx + cy0 * fy + ax2 * d,
                        ay0 + ay1 * sx + cy1 * fy + ay2 * d, az0 + az1 * sx + cy2 * fy + az2 * d,
                        vlim, zlim)
        if order >= 2:
            clamped += _add(m2, m3, z1, z, r, c, bx0 + bx1 * sx + dy0 * fy + bx2 * d,
                            by0 + by1 * sx + dy1 * fy + by2 * d,
                            bz0 + bz1 * sx + dy2 * fy + bz2 * d, alim, zlim)
        count += 1
    return count, clamped


@nb.njit(cache=True, nogil=True, parallel=True)
def _apply(
    f0: np.ndarray, f1: np.ndarray, depth: np.ndarray, debris: np.ndarray, m0: np.ndarray,
    m1: np.ndarray, m2: np.ndarray, m3: np.ndarray, z0: np.ndarray, z1: np.ndarray,
    coef: np.ndarray, margin: float, fp: int, fz: int, limits: np.ndarray, order: int,
) -> tuple:
    """Add the motion change (:func:`pixel_coefficients`) to every galpixel, rows in parallel.

    The map's fields come as (Z, R, C) planes (:func:`_planes`): ``f0, f1`` the
    fraction, ``m0..m3`` velocity x, y and acceleration x, y, ``z0, z1`` the z
    velocity and acceleration; planes an order lacks are empty and never read.
    Planes of a map are C-contiguous whatever its order or allocation, so numba
    compiles this kernel once (whole 4-D fields typed 'C' with 0-1 planes and 'A'
    with more: G(1)'s single z plane compiled a second kernel, 6 s, and a service
    at G(1) compiled it inside its refresh loop at the first head motion).
    ``limits`` (2,): the velocity and acceleration bounds in fixed-point units.
    Returns (galpixels changed, values clamped): sums beyond the bounds, or z motion
    beyond the depth format, are clamped there rather than wrapped.
    """
    nz, h = depth.shape[0], depth.shape[1]
    count = clamped = 0
    for row in nb.prange(nz * h):
        z, r = row // h, row % h
        n, k = _apply_row(z, r, f0, f1, depth, debris, m0, m1, m2, m3, z0, z1, coef, margin,
                          fp, fz, limits, order)
        count += n
        clamped += k
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
    f = gp.fixed
    scales = np.array([2.0**f.fm, 2.0**f.fm, 2.0**f.fzm])
    coef = pixel_coefficients(_per_refresh(old, refresh_hz), _per_refresh(new, refresh_hz), geo,
                              display.shears(), scales)
    limits = np.array([f.v_max, f.a_max], np.float64) * 2.0**f.fm
    changed, clamped = _apply(*_planes(gp.frac, 2), gp.depth, gp.debris, *_planes(gp.motion, 4),
                              *_planes(gp.zmotion, 2), coef, float(margin), f.fp, f.fz, limits,
                              gp.order)
    return int(changed), int(clamped)


def _planes(field: np.ndarray, k: int) -> tuple:
    """The first ``k`` planes of a (P, Z, R, C) field, each (Z, R, C); empty past P."""
    return tuple(field[i] if i < field.shape[0] else np.empty((0, 0, 0), field.dtype)
                 for i in range(k))
