"""The paper's thought experiments, run with the galpixel arithmetic.

Each case gives exact positions and derivatives of a few control points; an
update every ``interval`` refreshes paints them at the nearest pixel (fraction
zero) with their quantised motion, and between updates they are propagated
refresh by refresh with :func:`~service.galilean.fixed_point.advance`, exactly as
galpixels are.  Errors are ``exact - displayed`` in pixels (signed for the 1-D
cases, the largest Euclidean distance over the points for the others).

=================  =======================================================================
case               motion
=================  =======================================================================
falling            1-D, from rest at 2 px/refresh^2 (equations 4-7): y = t^2
uniform            1-D, constant velocity (default 0.3 px/refresh)
rotating-square    square in the display plane, corners 100 px from its centre,
                   2 pi / 64 rad/refresh (section 2.5)
galcube            Costella's GALCUBE: a cube turning a quarter turn per second about
                   the vertical axis at 25 Hz, vertices 100 px from the axis; the error
                   is the apparent 3-D distance (x, y and depth, in px)
=================  =======================================================================
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from service.errors import SettingsError
from service.galilean.fixed_point import FixedPoint, bit_budget, pixel_of, points_fixed, \
    propagate_points

#: A case: t (refreshes) -> (positions (N, K), derivatives (3, N, K)).
Case = Callable[[float], tuple[np.ndarray, np.ndarray]]


def falling(accel: float = 2.0) -> Case:
    """1-D fall from rest: y = accel t^2 / 2 (rows, downward positive)."""
    def at(t: float) -> tuple[np.ndarray, np.ndarray]:
        return np.array([[0.5 * accel * t * t]]), np.array([[[accel * t]], [[accel]], [[0.0]]])
    return at


def uniform(velocity: float = 0.3) -> Case:
    """1-D constant velocity: x = v t."""
    def at(t: float) -> tuple[np.ndarray, np.ndarray]:
        return np.array([[velocity * t]]), np.array([[[velocity]], [[0.0]], [[0.0]]])
    return at


def _circle(radius: float, omega: float, phases: np.ndarray, t: float, y: np.ndarray | None):
    th = omega * t + phases
    c, s = np.cos(th), np.sin(th)
    w = omega
    pos = np.stack([radius * c, radius * s], axis=1)
    der = np.stack([np.stack([-radius * w * s, radius * w * c], 1),
                    np.stack([-radius * w * w * c, -radius * w * w * s], 1),
                    np.stack([radius * w**3 * s, -radius * w**3 * c], 1)])
    if y is None:
        return pos, der
    # (x, y, depth): x = r sin, depth = r cos, y fixed.
    pos3 = np.stack([pos[:, 1], y, pos[:, 0]], axis=1)
    der3 = np.stack([np.stack([d[:, 1], np.zeros_like(y), d[:, 0]], 1) for d in der])
    return pos3, der3


def rotating_square(radius: float = 100.0, omega: float = 2 * math.pi / 64) -> Case:
    """Corners of a square rotating in the display plane about its centre."""
    phases = np.pi / 4 + np.arange(4) * np.pi / 2
    return lambda t: _circle(radius, omega, phases, t, None)


def galcube(radius: float = 100.0, turn_per_s: float = 0.25, hz: float = 25.0) -> Case:
    """Vertices of a cube turning about the vertical axis, ``radius`` px from it."""
    omega = 2 * math.pi * turn_per_s / hz
    phases = np.repeat(np.pi / 4 + np.arange(4) * np.pi / 2, 2)
    half = radius / math.sqrt(2)
    y = np.tile([-half, half], 4)
    return lambda t: _circle(radius, omega, phases, t, y)


CASES: dict[str, Callable[..., Case]] = {
    "falling": falling, "uniform": uniform, "rotating-square": rotating_square, "galcube": galcube,
}

#: Cases whose errors are signed 1-D values.
ONE_D = ("falling", "uniform")


@dataclass
class Run:
    """Result of :func:`run_case`.

    Attributes
    ----------
    exact : ndarray, shape (F, N, K)
    shown : ndarray, shape (F, N, K), int64
        Displayed pixel (symmetric rounding of the fixed-point position).
    subpixel : ndarray, shape (F, N, K)
        Fixed-point position in px (before rounding to a pixel).
    updated : ndarray, shape (F,), bool
        Refreshes that received an update.
    """

    exact: np.ndarray
    shown: np.ndarray
    subpixel: np.ndarray
    updated: np.ndarray

    def errors(self, one_d: bool) -> np.ndarray:
        """Signed errors (F,) for 1-D runs, else max Euclidean distance (F,)."""
        d = self.exact - self.shown
        return d[:, 0, 0] if one_d else np.linalg.norm(d, axis=-1).max(axis=-1)

    def subpixel_errors(self) -> np.ndarray:
        """Max distance (F,) between exact and fixed-point positions."""
        return np.linalg.norm(self.exact - self.subpixel, axis=-1).max(axis=-1)


def run_case(case: Case, order: int, interval: int, frames: int, fixed: FixedPoint | None = None,
             derivatives: Callable[[float], np.ndarray] | None = None,
             subpixel: bool = False) -> Run:
    """Update every ``interval`` refreshes, propagate in between, for ``frames`` refreshes.

    ``derivatives`` optionally replaces the exact derivatives an update carries
    (e.g. numerically differentiated tracker data), as (3, N, K) at time t.
    ``subpixel`` paints updates at their fixed-point position instead of the
    nearest pixel (isolates the extrapolation error from the pixel grid).
    """
    if interval < 1 or frames < 1 or order not in (0, 1, 2, 3):
        raise SettingsError(f"need interval >= 1, frames >= 1, order 0..3; got "
                            f"{interval}, {frames}, {order}")
    fixed = fixed or FixedPoint.for_order(bit_budget(1024, 16, 16), order)
    exact, shown, sub, upd = [], [], [], np.zeros(frames, bool)
    for t0 in range(0, frames, interval):
        pos, der = case(float(t0))
        if derivatives is not None:
            der = derivatives(float(t0))
        x, v, a, j = points_fixed(pos, der, fixed, order, subpixel)
        n = min(interval, frames - t0)
        path = propagate_points(x, v, a, j, order, fixed.fp, fixed.fm, n - 1)
        upd[t0] = True
        for k in range(n):
            exact.append(case(float(t0 + k))[0])
            shown.append(pixel_of(path[k], fixed.fp))
            sub.append(path[k] / 2.0**fixed.fp)
    return Run(np.array(exact), np.array(shown), np.array(sub), upd)


def galcube_paper(radius: float = 100.0, turn_per_s: float = 0.25, hz: float = 25.0,
                  interval: int = 4) -> dict[int, float]:
    """The paper-style error estimate ``r (w K)^(n+1) / (n+1)!`` for G(0), G(1), G(2).

    The first omitted Taylor term of a point ``r`` px from the axis after a whole
    update interval K: about 25, 3.2 and 0.26 px for GALCUBE's numbers.
    """
    wk = 2 * math.pi * turn_per_s / hz * interval
    return {n: radius * wk ** (n + 1) / math.factorial(n + 1) for n in range(3)}


def radius_shown(run: Run) -> np.ndarray:
    """Mean distance (F,) of the displayed sub-pixel points from the origin (square size)."""
    return np.linalg.norm(run.subpixel, axis=-1).mean(axis=-1)
