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

from drivers.filters import AlphaBetaGammaSettings, run_filter
from service.base.errors import SettingsError
from service.galilean.fixed_point import (
    FixedPoint,
    bit_budget,
    pixel_of,
    points_fixed,
    propagate_points,
)
from sim_devices.motion import HeadTurn

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


def _chain(r: float, th: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """X = r sin(theta) and its first three derivatives from theta's (d: (3, N))."""
    s, c = np.sin(th), np.cos(th)
    d1, d2, d3 = d
    der = np.stack([r * c * d1, r * (c * d2 - s * d1**2),
                    r * (c * d3 - 3 * s * d1 * d2 - c * d1**3)])
    return r * s, der


def tracker_head_turn(
    estimator: str, frames: int = 240, hz: float = 60.0, noise_deg: float = 0.05,
    radius: float = 100.0, seed: int = 1,
) -> tuple[Case, Callable[[float], np.ndarray]]:
    """A point ``radius`` px from the axis of a head turn, seen through a noisy tracker.

    The head follows :class:`sim_devices.motion.HeadTurn` (yaw); the tracker
    reports yaw at the refresh rate with Gaussian noise of ``noise_deg``.  The
    point's apparent x is ``radius * sin(yaw)``.

    Parameters
    ----------
    estimator : {"raw", "alpha-beta-gamma", "one-euro", "alpha-beta"}
        ``raw``: position, velocity, acceleration and jerk by backward
        differences of the noisy samples (numerical differentiation); otherwise
        the named filter of :mod:`drivers.filters` gives position, velocity and
        acceleration (jerk zero).

    Returns
    -------
    case : Case
        Exact motion (for the error).
    estimate : callable
        t -> (position (1, 1), derivatives (3, 1, 1)): what an update carries
        (the render uses the tracked pose and its estimated derivatives).
    """
    head = HeadTurn(amplitude=60.0, turn_s=1.0, hold_s=0.5)
    t = np.arange(frames + 4) / hz
    yaw = np.radians([head.pose(float(x)).yaw for x in t])
    noisy = yaw + np.radians(noise_deg) * np.random.default_rng(seed).standard_normal(t.size)
    if estimator == "raw":
        est = np.zeros((4, t.size))
        est[0] = noisy
        for k in range(1, 4):
            est[k, k:] = np.diff(est[k - 1], 1)[k - 1:]
    else:
        samples = np.zeros((t.size, 6))
        samples[:, 3] = np.degrees(noisy)
        settings = AlphaBetaGammaSettings.from_theta(0.6) if estimator == "alpha-beta-gamma" \
            else None
        p, v, a = run_filter(estimator, t, samples, settings)
        est = np.radians(np.stack([p[:, 3], v[:, 3] / hz, a[:, 3] / hz**2, 0 * a[:, 3]]))

    def exact(tt: float) -> tuple[np.ndarray, np.ndarray]:
        th = float(np.interp(tt / hz, t, yaw))
        return np.array([[radius * np.sin(th)]]), np.zeros((3, 1, 1))

    def estimate(tt: float) -> tuple[np.ndarray, np.ndarray]:
        k = int(round(tt))
        pos, der = _chain(radius, est[0, k], est[1:, k])
        return np.array([[pos]]), der.reshape(3, 1, 1)

    return exact, estimate


def run_tracker(estimator: str, order: int, interval: int, frames: int = 240,
                noise_deg: float = 0.05, seed: int = 1) -> np.ndarray:
    """Absolute errors (F,) of the head-turn point under ``estimator`` and G(``order``).

    The update paints the estimator's position (the render uses the tracked pose).
    """
    exact, estimate = tracker_head_turn(estimator, frames, noise_deg=noise_deg, seed=seed)
    fixed = FixedPoint.for_order(bit_budget(1024, 16, 16), order)
    shown = np.zeros(frames)
    for t0 in range(0, frames, interval):
        pos, d = estimate(float(t0))
        x, v, a, j = points_fixed(pos, d, fixed, order, subpixel=True)
        n = min(interval, frames - t0)
        path = propagate_points(x, v, a, j, order, fixed.fp, fixed.fm, n - 1)
        shown[t0:t0 + n] = path[:, 0, 0] / 2.0**fixed.fp
    truth = np.array([exact(float(k))[0][0, 0] for k in range(frames)])
    return np.abs(truth - shown)

