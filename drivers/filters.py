"""Pose filtering and prediction for a head tracker.

A tracker reports positions and angles only (seed 002, section 2.5): velocity and
acceleration must be estimated from the positions, and every estimator trades lag
for jitter.  This module holds four estimators behind one interface:

``raw``
    Finite differences of the raw samples (no smoothing, the most jitter).
``alpha-beta``
    Constant-velocity tracking filter with fixed gains.
``alpha-beta-gamma``
    Constant-acceleration tracking filter with fixed gains.
``one-euro``
    The One Euro filter (Casiez, Roussel and Vogel, CHI 2012): an adaptive
    low-pass whose cutoff rises with speed, extended with a low-passed
    acceleration estimate.

A pose sample is an array of shape (6,) ordered ``(x, y, z, yaw, pitch, roll)``;
positions are in the tracker's length unit, angles in degrees.  Angles are
unwrapped (a step of more than half a turn between samples is taken as a wrap),
so filtered angles are continuous and may leave +-180; :func:`wrap_angles` brings
them back.  Sample times may be irregular; every step uses the actual interval.

Bad input policy (``on_bad`` in every settings class):

* ``"raise"`` (default): a non-finite time or sample, a time that goes backwards,
  or a duplicate time raises :class:`SampleError` and leaves the state unchanged.
* ``"skip"``: the sample is ignored (the state is unchanged) and counted in
  :attr:`PoseFilter.skipped`.

A gap longer than ``max_gap_s`` re-initialises the filter at the new sample
(velocity and acceleration zero), counted in :attr:`PoseFilter.resets`.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from service.base.errors import SampleError, SettingsError

#: Number of pose channels: x, y, z, yaw, pitch, roll.
POSE_DIM = 6
#: Names of the pose channels, in order.
POSE_NAMES = ("x", "y", "z", "yaw", "pitch", "roll")


_Triple = tuple[np.ndarray, np.ndarray, np.ndarray]


@dataclass(frozen=True)
class FilterState:
    """Filtered pose and its estimated derivatives at one time.

    Attributes
    ----------
    t_s : float
        Sample time in seconds.
    position : ndarray, shape (6,)
        Filtered pose ``(x, y, z, yaw, pitch, roll)``, angles unwrapped.
    velocity : ndarray, shape (6,)
        Estimated first derivative, units per second.
    acceleration : ndarray, shape (6,)
        Estimated second derivative, units per second squared.
    """

    t_s: float
    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray


@dataclass(frozen=True)
class FilterSettings:
    """Settings every filter shares.

    Parameters
    ----------
    angle_axes : tuple of int
        Channels that hold angles and are unwrapped.
    angle_period : float
        One turn in the angle unit (360 for degrees).
    on_bad : {"raise", "skip"}
        What to do with a bad sample (see the module docstring).
    max_gap_s : float
        A gap longer than this re-initialises the filter.
    """

    angle_axes: tuple[int, ...] = (3, 4, 5)
    angle_period: float = 360.0
    on_bad: str = "raise"
    max_gap_s: float = 1.0

    def __post_init__(self) -> None:
        if self.on_bad not in ("raise", "skip"):
            raise SettingsError(f"on_bad must be 'raise' or 'skip', not {self.on_bad!r}")
        if not self.max_gap_s > 0:
            raise SettingsError(f"max_gap_s must be > 0, not {self.max_gap_s}")
        if not self.angle_period > 0:
            raise SettingsError(f"angle_period must be > 0, not {self.angle_period}")
        if any(not 0 <= a < POSE_DIM for a in self.angle_axes):
            raise SettingsError(f"angle_axes must lie in 0..5, not {self.angle_axes}")


def _check_gain(name: str, value: float, lo: float, hi: float) -> None:
    if not lo < value <= hi:
        raise SettingsError(f"{name} must lie in ({lo}, {hi}], not {value}")


def _check_theta(theta: float) -> None:
    if not 0.0 <= theta < 1.0:
        raise SettingsError(f"theta must lie in [0, 1), not {theta}")


@dataclass(frozen=True)
class RawSettings(FilterSettings):
    """Settings of :class:`RawDifference` (only the shared ones)."""


@dataclass(frozen=True)
class AlphaBetaSettings(FilterSettings):
    """Gains of the alpha-beta filter.

    Parameters
    ----------
    alpha : float
        Position gain in (0, 1]; 1 follows the samples exactly.
    beta : float
        Velocity gain in (0, 2]; the velocity correction is ``beta / dt * residual``.
    """

    alpha: float = 0.5
    beta: float = 0.1

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_gain("alpha", self.alpha, 0.0, 1.0)
        _check_gain("beta", self.beta, 0.0, 2.0)

    @classmethod
    def from_theta(cls, theta: float, **common: object) -> AlphaBetaSettings:
        """Critically damped gains from one smoothing factor.

        Parameters
        ----------
        theta : float
            In [0, 1): 0 follows the samples, near 1 smooths hard (more lag).
        **common
            Shared :class:`FilterSettings` fields.
        """
        _check_theta(theta)
        return cls(alpha=1.0 - theta**2, beta=(1.0 - theta) ** 2, **common)


@dataclass(frozen=True)
class AlphaBetaGammaSettings(FilterSettings):
    """Gains of the alpha-beta-gamma filter.

    Parameters
    ----------
    alpha : float
        Position gain in (0, 1].
    beta : float
        Velocity gain in (0, 2]; correction ``beta / dt * residual``.
    gamma : float
        Acceleration gain in (0, 2]; correction ``2 * gamma / dt**2 * residual``.
    """

    alpha: float = 0.5
    beta: float = 0.1
    gamma: float = 0.005

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_gain("alpha", self.alpha, 0.0, 1.0)
        _check_gain("beta", self.beta, 0.0, 2.0)
        _check_gain("gamma", self.gamma, 0.0, 2.0)

    @classmethod
    def from_theta(cls, theta: float, **common: object) -> AlphaBetaGammaSettings:
        """Fading-memory (critically damped) gains from one smoothing factor.

        Parameters
        ----------
        theta : float
            In [0, 1): 0 follows the samples, near 1 smooths hard (more lag).
        **common
            Shared :class:`FilterSettings` fields.
        """
        _check_theta(theta)
        one = 1.0 - theta
        return cls(
            alpha=1.0 - theta**3,
            beta=1.5 * (1.0 - theta**2) * one,
            gamma=0.5 * one**3,
            **common,
        )


@dataclass(frozen=True)
class OneEuroSettings(FilterSettings):
    """Parameters of the One Euro filter.

    Parameters
    ----------
    min_cutoff : float
        Cutoff frequency (Hz) when still; lower means less jitter, more lag.
    beta : float
        Cutoff increase per unit of speed (Hz per unit/s); higher means less
        lag when moving fast.
    d_cutoff : float
        Cutoff (Hz) of the low-pass on the velocity and acceleration estimates.
    """

    min_cutoff: float = 1.0
    beta: float = 0.01
    d_cutoff: float = 1.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (self.min_cutoff > 0 and self.d_cutoff > 0 and self.beta >= 0):
            raise SettingsError("one-euro needs min_cutoff > 0, d_cutoff > 0 and beta >= 0")


def wrap_angles(pose: np.ndarray, settings: FilterSettings | None = None) -> np.ndarray:
    """Wrap the angle channels of poses into [-period/2, period/2).

    Parameters
    ----------
    pose : ndarray, shape (..., 6)
    settings : FilterSettings, optional
        Gives the angle channels and period; defaults to degrees on channels 3..5.

    Returns
    -------
    ndarray, shape (..., 6)
        A copy with wrapped angles.
    """
    s = settings or FilterSettings()
    out = np.array(pose, dtype=np.float64, copy=True)
    axes = list(s.angle_axes)
    half = s.angle_period / 2.0
    out[..., axes] = (out[..., axes] + half) % s.angle_period - half
    return out


class PoseFilter(ABC):
    """Common interface: feed samples with :meth:`update`, extrapolate with :meth:`predict`.

    Parameters
    ----------
    settings : FilterSettings, optional
        The subclass's settings dataclass; its defaults when omitted.
    """

    settings_type: ClassVar[type[FilterSettings]] = FilterSettings

    def __init__(self, settings: FilterSettings | None = None) -> None:
        settings = self.settings_type() if settings is None else settings
        if not isinstance(settings, self.settings_type):
            raise SettingsError(
                f"{type(self).__name__} needs {self.settings_type.__name__}, "
                f"not {type(settings).__name__}"
            )
        self.settings = settings
        self._angle_mask = np.zeros(POSE_DIM, bool)
        self._angle_mask[list(settings.angle_axes)] = True
        self.skipped = 0
        self.resets = 0
        self.reset()

    def reset(self) -> None:
        """Forget all samples (counters are kept)."""
        self._t: float | None = None
        self._last_unwrapped = np.zeros(POSE_DIM)
        self._state: FilterState | None = None
        self._t0_ns: int | None = None

    @property
    def state(self) -> FilterState | None:
        """The latest filtered state, or None before the first sample."""
        return self._state

    def update(self, t_s: float, sample: np.ndarray) -> FilterState:
        """Feed one sample and return the new filtered state.

        Parameters
        ----------
        t_s : float
            Sample time in seconds; must increase strictly.
        sample : ndarray, shape (6,)
            ``(x, y, z, yaw, pitch, roll)``.

        Returns
        -------
        FilterState
            The new state, or the unchanged previous one for a skipped sample
            (None is never returned after the first good sample).

        Raises
        ------
        SampleError
            Bad sample under ``on_bad="raise"``, or a bad first sample.
        """
        z = np.asarray(sample, dtype=np.float64).reshape(-1)
        problem = self._problem(t_s, z)
        if problem is not None:
            if self.settings.on_bad == "skip" and self._state is not None:
                self.skipped += 1
                return self._state
            raise SampleError(problem)
        z_prev = self._last_unwrapped
        z = self._unwrap(z)
        t_s = float(t_s)
        if self._t is None or t_s - self._t > self.settings.max_gap_s:
            self.resets += self._t is not None
            pos, vel, acc = self._first(z)
        else:
            pos, vel, acc = self._step(t_s - self._t, z, z_prev)
        self._t = t_s
        self._state = FilterState(t_s, pos, vel, acc)
        return self._state

    def update_ns(self, t_ns: int, sample: np.ndarray) -> FilterState:
        """:meth:`update` with an integer time in nanoseconds.

        The first time seen is taken as zero, so large monotonic counters keep
        full precision.
        """
        if self._t0_ns is None:
            self._t0_ns = int(t_ns)
        return self.update((int(t_ns) - self._t0_ns) * 1e-9, sample)

    def predict(self, lead_s: float) -> np.ndarray:
        """Extrapolate the latest state ``lead_s`` seconds ahead.

        Returns
        -------
        ndarray, shape (6,)
            ``position + velocity * lead + acceleration * lead**2 / 2``
            (angles unwrapped).
        """
        if self._state is None:
            raise SampleError("predict() before the first sample")
        s = self._state
        return s.position + s.velocity * lead_s + 0.5 * s.acceleration * lead_s**2

    def _problem(self, t_s: float, z: np.ndarray) -> str | None:
        """Why a sample is unusable, or None."""
        if z.shape != (POSE_DIM,):
            return f"sample must have shape (6,), not {z.shape}"
        if not math.isfinite(t_s) or not np.all(np.isfinite(z)):
            return f"non-finite time or sample at t={t_s}: {z}"
        if self._t is not None and t_s <= self._t:
            kind = "duplicate" if t_s == self._t else "backwards"
            return f"{kind} sample time {t_s} after {self._t}"
        return None

    def _unwrap(self, z: np.ndarray) -> np.ndarray:
        """Unwrap angle channels against the previous unwrapped sample."""
        if self._t is not None:
            p = self.settings.angle_period
            m = self._angle_mask
            prev = self._last_unwrapped[m]
            z = z.copy()
            z[m] = prev + ((z[m] - prev + p / 2.0) % p - p / 2.0)
        self._last_unwrapped = z
        return z

    def _first(self, z: np.ndarray) -> _Triple:
        """State after the first sample (or a gap): at the sample, at rest."""
        return z.copy(), np.zeros(POSE_DIM), np.zeros(POSE_DIM)

    @abstractmethod
    def _step(
        self, dt: float, z: np.ndarray, z_prev: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Advance by ``dt`` > 0 s with unwrapped sample ``z`` (previous ``z_prev``), (6,)."""


class RawDifference(PoseFilter):
    """Backward finite differences of the raw samples.

    Position is the sample itself; velocity is ``(z_k - z_{k-1}) / dt_k`` (which
    really belongs half an interval back); acceleration is the difference of the
    last two velocities over the mean of the last two intervals.
    """

    settings_type = RawSettings

    def _step(self, dt: float, z: np.ndarray, z_prev: np.ndarray) -> _Triple:
        prev = self._state
        vel = (z - prev.position) / dt
        acc = np.zeros(POSE_DIM)
        if self._prev_dt is not None:
            acc = (vel - prev.velocity) / (0.5 * (dt + self._prev_dt))
        self._prev_dt = dt
        return z.copy(), vel, acc

    def _first(self, z: np.ndarray) -> _Triple:
        self._prev_dt: float | None = None
        return super()._first(z)


class AlphaBeta(PoseFilter):
    """Alpha-beta (g-h) filter: a constant-velocity model with fixed gains.

    Each step predicts ``x + v dt``, then corrects by the residual ``r``:
    ``x += alpha r``, ``v += beta / dt r``.  Acceleration is reported as zero.
    """

    settings_type = AlphaBetaSettings

    def _step(self, dt: float, z: np.ndarray, z_prev: np.ndarray) -> _Triple:
        s, prev = self.settings, self._state
        xp = prev.position + prev.velocity * dt
        r = z - xp
        return xp + s.alpha * r, prev.velocity + (s.beta / dt) * r, np.zeros(POSE_DIM)


class AlphaBetaGamma(PoseFilter):
    """Alpha-beta-gamma (g-h-k) filter: a constant-acceleration model with fixed gains.

    Predicts ``x + v dt + a dt^2/2`` and ``v + a dt``, then corrects with
    ``alpha r``, ``beta / dt r`` and ``2 gamma / dt^2 r``.
    """

    settings_type = AlphaBetaGammaSettings

    def _step(self, dt: float, z: np.ndarray, z_prev: np.ndarray) -> _Triple:
        s, prev = self.settings, self._state
        xp = prev.position + prev.velocity * dt + 0.5 * prev.acceleration * dt**2
        vp = prev.velocity + prev.acceleration * dt
        r = z - xp
        pos = xp + s.alpha * r
        vel = vp + (s.beta / dt) * r
        acc = prev.acceleration + (2.0 * s.gamma / dt**2) * r
        return pos, vel, acc


def _lowpass_alpha(cutoff: np.ndarray | float, dt: float) -> np.ndarray | float:
    """Smoothing factor of a first-order low-pass at ``cutoff`` Hz for step ``dt``."""
    tau = 1.0 / (2.0 * math.pi * cutoff)
    return 1.0 / (1.0 + tau / dt)


class OneEuro(PoseFilter):
    """One Euro filter (Casiez et al. 2012), per channel, plus an acceleration estimate.

    ``dx = (z - z_prev) / dt`` (previous *raw* sample, as in the authors' reference
    code, so a ramp's speed is estimated without bias) is low-passed at
    ``d_cutoff`` into the velocity; the
    position low-pass uses ``min_cutoff + beta * |velocity|``.  Acceleration (an
    extension, not in the paper) is the difference of successive velocities,
    low-passed at ``d_cutoff``.
    """

    settings_type = OneEuroSettings

    def _step(self, dt: float, z: np.ndarray, z_prev: np.ndarray) -> _Triple:
        s, prev = self.settings, self._state
        a_d = _lowpass_alpha(s.d_cutoff, dt)
        vel = prev.velocity + a_d * ((z - z_prev) / dt - prev.velocity)
        a_x = _lowpass_alpha(s.min_cutoff + s.beta * np.abs(vel), dt)
        pos = prev.position + a_x * (z - prev.position)
        acc = prev.acceleration + a_d * ((vel - prev.velocity) / dt - prev.acceleration)
        return pos, vel, acc


#: Filter classes by name.
FILTERS: dict[str, type[PoseFilter]] = {
    "raw": RawDifference,
    "alpha-beta": AlphaBeta,
    "alpha-beta-gamma": AlphaBetaGamma,
    "one-euro": OneEuro,
}


def make_filter(name: str, settings: FilterSettings | None = None) -> PoseFilter:
    """Build a filter by registry name.

    Parameters
    ----------
    name : str
        A key of :data:`FILTERS`.
    settings : FilterSettings, optional
        The filter's settings dataclass; defaults when omitted.

    Raises
    ------
    SettingsError
        Unknown name, or settings of the wrong class.
    """
    try:
        cls = FILTERS[name]
    except KeyError:
        raise SettingsError(f"unknown filter {name!r}; known: {sorted(FILTERS)}") from None
    return cls(settings)


@dataclass
class FilterRun:
    """Result of :func:`run_filter_detailed`.

    Attributes
    ----------
    position, velocity, acceleration : ndarray, shape (N, 6)
        Filtered state after each sample (NaN rows for skipped samples).
    skipped : int
        Samples skipped under ``on_bad="skip"``.
    resets : int
        Re-initialisations after gaps.
    """

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    skipped: int = 0
    resets: int = 0
    kept: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))


def run_filter_detailed(
    name: str, t: np.ndarray, samples: np.ndarray, settings: FilterSettings | None = None
) -> FilterRun:
    """Run a filter over a whole recording (same arithmetic as :meth:`PoseFilter.update`).

    Parameters
    ----------
    name : str
        A key of :data:`FILTERS`.
    t : ndarray, shape (N,)
        Sample times in seconds.
    samples : ndarray, shape (N, 6)
    settings : FilterSettings, optional

    Returns
    -------
    FilterRun
        Rows of skipped samples are NaN and ``kept`` is False there.
    """
    t = np.asarray(t, dtype=np.float64)
    samples = np.asarray(samples, dtype=np.float64)
    if samples.ndim != 2 or samples.shape[1] != POSE_DIM or t.shape != samples.shape[:1]:
        raise SampleError(f"need t (N,) and samples (N, 6), got {t.shape} and {samples.shape}")
    f = make_filter(name, settings)
    out = np.full((3, len(t), POSE_DIM), np.nan)
    kept = np.zeros(len(t), bool)
    for k in range(len(t)):
        before = f.skipped
        st = f.update(t[k], samples[k])
        if f.skipped == before:
            out[:, k] = st.position, st.velocity, st.acceleration
            kept[k] = True
    return FilterRun(out[0], out[1], out[2], f.skipped, f.resets, kept)


def run_filter(
    name: str, t: np.ndarray, samples: np.ndarray, settings: FilterSettings | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Run a filter offline over arrays.

    Parameters
    ----------
    name : str
        A key of :data:`FILTERS`.
    t : ndarray, shape (N,)
        Sample times in seconds, strictly increasing (see the bad input policy).
    samples : ndarray, shape (N, 6)
    settings : FilterSettings, optional

    Returns
    -------
    position, velocity, acceleration : ndarray, shape (N, 6)
        State after each sample; NaN rows where a sample was skipped.
    """
    r = run_filter_detailed(name, t, samples, settings)
    return r.position, r.velocity, r.acceleration


def predict_ahead(
    position: np.ndarray, velocity: np.ndarray, acceleration: np.ndarray, lead_s: float
) -> np.ndarray:
    """Vectorised prediction ``p + v lead + a lead^2 / 2``.

    Parameters
    ----------
    position, velocity, acceleration : ndarray, shape (N, 6)
    lead_s : float

    Returns
    -------
    ndarray, shape (N, 6)
    """
    return position + velocity * lead_s + 0.5 * acceleration * lead_s**2
