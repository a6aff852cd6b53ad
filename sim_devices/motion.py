"""Head motions for the simulated tracker: pose as a function of time.

Every motion is an object with ``pose(t) -> Pose`` (``t`` in seconds since the start;
calls with increasing ``t``).  Angles are degrees, positions millimetres.  Random
motions and noise are seeded, so a run is reproducible.

=============  ===============================================================
still          a fixed pose
sway           sums of sinusoids on every axis (a seated person's idle sway)
turn           a head turn: smooth (cosine-eased) yaw to +amplitude, hold, back
               to -amplitude, hold, repeat
walk           a bounded random walk (Ornstein-Uhlenbeck on each axis)
replay         sample-and-hold playback of recorded poses (list or Hatire log)
=============  ===============================================================

``Noisy(motion, ...)`` adds Gaussian sensor noise.  :func:`make_motion` builds one
from a CLI spec such as ``"sway:scale=2"`` or ``"replay:file=capture.log"``.
"""

from __future__ import annotations

import bisect
import math
import random
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Protocol

from drivers.events import PoseEvent
from drivers.protocols.hatire import HatireDecoder
from service.base.errors import SettingsError

AXES = ("yaw", "pitch", "roll", "x", "y", "z")


@dataclass(frozen=True, slots=True)
class Pose:
    """Six degrees of freedom: angles in degrees, position in millimetres."""

    yaw: float = 0.0
    pitch: float = 0.0
    roll: float = 0.0
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0

    def as_tuple(self) -> tuple[float, ...]:
        """``(yaw, pitch, roll, x, y, z)``."""
        return (self.yaw, self.pitch, self.roll, self.x, self.y, self.z)


class Motion(Protocol):
    """Anything with ``pose(t)``."""

    def pose(self, t: float) -> Pose:
        """Pose at ``t`` seconds."""
        ...


@dataclass(frozen=True)
class Still:
    """A fixed pose."""

    at: Pose = Pose()

    def pose(self, t: float) -> Pose:
        """Always ``at``."""
        return self.at


#: axis -> ((amplitude, frequency Hz, phase rad), ...) of the default sway.
SWAY_TERMS = {
    "yaw": ((12.0, 0.21, 0.0), (4.0, 0.53, 1.0)),
    "pitch": ((5.0, 0.31, 0.5), (1.5, 0.87, 2.0)),
    "roll": ((3.0, 0.17, 1.3),),
    "x": ((25.0, 0.11, 0.2), (5.0, 0.43, 0.7)),
    "y": ((8.0, 0.23, 2.1),),
    "z": ((15.0, 0.07, 0.9),),
}


@dataclass(frozen=True)
class Sway:
    """Sum of sinusoids per axis, all amplitudes multiplied by ``scale``."""

    scale: float = 1.0

    def pose(self, t: float) -> Pose:
        """Sum of :data:`SWAY_TERMS` at ``t``."""
        vals = [self.scale * sum(a * math.sin(2 * math.pi * f * t + ph)
                                 for a, f, ph in SWAY_TERMS[ax]) for ax in AXES]
        return Pose(*vals)


@dataclass(frozen=True)
class HeadTurn:
    """Turn to +amplitude, hold, turn to -amplitude, hold; ``turn_s`` per turn."""

    amplitude: float = 60.0
    turn_s: float = 1.0
    hold_s: float = 1.0

    def pose(self, t: float) -> Pose:
        """Cosine-eased yaw; pitch follows a little (people nod as they turn)."""
        seg = self.turn_s + self.hold_s
        k, u = divmod(t, seg)
        start, end = (0.0, self.amplitude) if k == 0 else (
            (self.amplitude, -self.amplitude) if k % 2 else (-self.amplitude, self.amplitude))
        s = min(u / self.turn_s, 1.0)
        yaw = start + (end - start) * (1 - math.cos(math.pi * s)) / 2
        return Pose(yaw=yaw, pitch=-0.05 * abs(yaw))


class RandomWalk:
    """Bounded random walk: an Ornstein-Uhlenbeck process per axis, seeded.

    Parameters
    ----------
    seed : int
        Random seed.
    sigma_deg, sigma_mm : float
        Stationary standard deviation of the angles and positions.
    tau_s : float
        Mean-reversion time.
    dt : float
        Internal step; ``pose(t)`` holds the last step at or before ``t``.
    """

    def __init__(self, seed: int = 0, sigma_deg: float = 10.0, sigma_mm: float = 20.0,
                 tau_s: float = 2.0, dt: float = 0.01) -> None:
        self._rng = random.Random(seed)
        self._sigmas = (sigma_deg,) * 3 + (sigma_mm,) * 3
        self._decay = math.exp(-dt / tau_s)
        self._kick = math.sqrt(1 - self._decay ** 2)
        self._dt = dt
        self._state = [0.0] * 6
        self._steps = 0

    def pose(self, t: float) -> Pose:
        """Advance the walk to ``t`` (never backwards) and return it."""
        target = int(t / self._dt)
        while self._steps < target:
            self._state = [v * self._decay + s * self._kick * self._rng.gauss(0, 1)
                           for v, s in zip(self._state, self._sigmas, strict=True)]
            self._steps += 1
        return Pose(*self._state)


class Replay:
    """Sample-and-hold playback of ``(t, Pose)`` samples, looping when ``loop``."""

    def __init__(self, samples: Sequence[tuple[float, Pose]], loop: bool = True) -> None:
        if not samples:
            raise SettingsError("replay needs at least one pose")
        self._times = [t for t, _ in samples]
        self._poses = [p for _, p in samples]
        self._loop = loop
        self._span = self._times[-1] + (self._times[1] - self._times[0]
                                        if len(samples) > 1 else 1.0)

    @classmethod
    def from_hatire_file(cls, path: str | Path, rate_hz: float = 60.0,
                         loop: bool = True) -> Replay:
        """Poses of a raw Hatire capture, spaced at ``rate_hz``."""
        try:
            data = Path(path).read_bytes()
        except OSError as exc:
            # "PATH: cannot read the replay file: REASON", not str(exc)'s "[Errno 2] ..."
            raise SettingsError(f"{path}: cannot read the replay file: "
                                f"{exc.strerror or exc}") from exc
        events = [e for e in HatireDecoder().feed(data, 0) if isinstance(e, PoseEvent)]
        return cls([(i / rate_hz, Pose(e.yaw, e.pitch, e.roll, e.x, e.y, e.z))
                    for i, e in enumerate(events)], loop)

    def pose(self, t: float) -> Pose:
        """The last sample at or before ``t``."""
        if self._loop:
            t = t % self._span
        i = bisect.bisect_right(self._times, t) - 1
        return self._poses[max(i, 0)]


class Noisy:
    """Adds Gaussian noise (seeded) to another motion."""

    def __init__(self, motion: Motion, sigma_deg: float = 0.2, sigma_mm: float = 0.5,
                 seed: int = 0) -> None:
        self._motion = motion
        self._sigmas = (sigma_deg,) * 3 + (sigma_mm,) * 3
        self._rng = random.Random(seed)

    def pose(self, t: float) -> Pose:
        """The wrapped pose plus noise."""
        base = self._motion.pose(t).as_tuple()
        return Pose(*(v + self._rng.gauss(0, s) for v, s in zip(base, self._sigmas,
                                                                 strict=True)))


def _replay(seed: int, file: str = "", rate_hz: float = 60.0) -> Motion:
    if not file:
        raise SettingsError("replay needs file=PATH (a raw Hatire capture)")
    return Replay.from_hatire_file(file, rate_hz)


#: motion name -> factory(seed, **options).
MOTIONS: dict[str, Callable[..., Motion]] = {
    "still": lambda seed, **kw: Still(Pose(**kw)),
    "sway": lambda seed, **kw: Sway(**kw),
    "turn": lambda seed, **kw: HeadTurn(**kw),
    "walk": lambda seed, **kw: RandomWalk(seed, **kw),
    "replay": _replay,
}
_FLOAT_FIELDS = {f.name for f in fields(Pose)} | {"scale", "amplitude", "turn_s", "hold_s",
                                                  "sigma_deg", "sigma_mm", "tau_s", "dt",
                                                  "rate_hz"}


def parse_spec(spec: str) -> tuple[str, dict[str, float | str]]:
    """Split ``"name:key=value,key=value"`` into a name and typed options."""
    name, _, rest = spec.partition(":")
    opts: dict[str, float | str] = {}
    for item in filter(None, rest.split(",")):
        key, sep, value = item.partition("=")
        if not sep:
            raise SettingsError(f"option {item!r} in {spec!r} needs key=value")
        try:
            opts[key] = float(value) if key in _FLOAT_FIELDS else value
        except ValueError:
            raise SettingsError(f"option {key} in {spec!r} needs a number") from None
    return name, opts


def make_motion(spec: str = "sway", seed: int = 0, noise_deg: float = 0.0,
                noise_mm: float = 0.0) -> Motion:
    """Build a motion from a spec (see module docstring), optionally noisy.

    Raises
    ------
    SettingsError
        For an unknown motion or bad options.
    """
    name, opts = parse_spec(spec)
    if name not in MOTIONS:
        raise SettingsError(f"unknown motion {name!r}; known: {', '.join(MOTIONS)}")
    try:
        motion = MOTIONS[name](seed, **opts)
    except TypeError as exc:
        raise SettingsError(f"bad options for motion {name!r}: {exc}") from None
    if noise_deg or noise_mm:
        motion = Noisy(motion, noise_deg, noise_mm, seed + 1)
    return motion
