"""The dodge game's rules (seed 000, chapter 5), as pure state: no pygame, no transport.

The player's object moves only when the player acts; the attackers move under the
program.  Each tick follows the thesis's order (section 5.3): :func:`overyet` on the
state as last rendered; if the game goes on, the player's moves shift its origin;
then the attackers move (:func:`advance`); then the caller renders.

Moves (section 5.2.1) shift the player's origin by ``step`` world units:

==============  =================  ==========================================
move            origin change      note
==============  =================  ==========================================
``moveup``      y += step          the thesis prints "increments the z-coordinate",
                                   which collides with ``moveout``; up is +y in the
                                   thesis's own axes (Fig. 1-1), so +y it is
``movedown``    y -= step
``moveright``   x += step
``moveleft``    x -= step
``movein``      z -= step          into the display, away from the viewer
``moveout``     z += step          toward the viewer
==============  =================  ==========================================

The player stays inside the arena (moves are clamped to it).  :func:`overyet` is
true when the player's origin is *closer than* ``threshold`` to an attacker's
origin (a distance equal to the threshold is still safe).

Score = 10 points per second survived + 25 per near miss (an attacker passing
within ``near_miss`` of the player and leaving again).  Difficulty rises with time:
the attackers' speed is multiplied by ``1 + ramp * t``.  Everything random comes
from one seeded generator, so a game is deterministic given its seed and inputs.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: move name -> unit direction of the origin shift (see the module table).
MOVES: dict[str, tuple[float, float, float]] = {
    "moveup": (0.0, 1.0, 0.0),
    "movedown": (0.0, -1.0, 0.0),
    "moveright": (1.0, 0.0, 0.0),
    "moveleft": (-1.0, 0.0, 0.0),
    "movein": (0.0, 0.0, -1.0),
    "moveout": (0.0, 0.0, 1.0),
}

POINTS_PER_SECOND = 10
NEAR_MISS_POINTS = 25


@dataclass(frozen=True)
class Difficulty:
    """How hard a game is.

    Attributes
    ----------
    speed : float
        Attackers' starting speed, world units per second.
    ramp : float
        Speed grows as ``1 + ramp * t`` (t in seconds).
    threshold : float
        overyet distance between origins.
    """

    speed: float
    ramp: float
    threshold: float


DIFFICULTIES: dict[str, Difficulty] = {
    "easy": Difficulty(speed=0.12, ramp=0.01, threshold=0.14),
    "normal": Difficulty(speed=0.2, ramp=0.02, threshold=0.17),
    "hard": Difficulty(speed=0.3, ramp=0.04, threshold=0.2),
}


@dataclass(frozen=True)
class GameSettings:
    """Settings of one game.

    Attributes
    ----------
    seed : int
        Seed of the attackers' starting velocities.
    difficulty : str
        A key of :data:`DIFFICULTIES`.
    step : float
        Origin shift of one discrete move (world units).
    lo, hi : tuple of 3 floats
        The arena box the player and the attackers stay in.
    start : tuple of 3 floats
        The player's starting origin.
    attackers : tuple of (x, y, z)
        Attackers' starting origins.
    near_miss : float
        Distance that counts as a near miss (scored when the attacker leaves it).
    """

    seed: int = 0
    difficulty: str = "normal"
    step: float = 0.1
    lo: tuple[float, float, float] = (-0.8, -0.55, -0.45)
    hi: tuple[float, float, float] = (0.8, 0.55, 0.45)
    start: tuple[float, float, float] = (0.0, -0.45, 0.1)
    attackers: tuple[tuple[float, float, float], ...] = (
        (-0.72, 0.48, -0.4),
        (-0.05, 0.55, 0.15),
        (0.68, 0.42, -0.2),
        (-0.55, 0.2, 0.38),
        (0.5, 0.22, 0.4),
        (0.25, 0.35, -0.42),
    )
    near_miss: float = 0.3

    def __post_init__(self) -> None:
        if self.difficulty not in DIFFICULTIES:
            raise ValueError(
                f"difficulty must be one of {sorted(DIFFICULTIES)}, got {self.difficulty!r}"
            )
        if not self.step > 0:
            raise ValueError(f"step must be > 0, got {self.step}")

    @property
    def level(self) -> Difficulty:
        """The :class:`Difficulty` named by ``difficulty``."""
        return DIFFICULTIES[self.difficulty]


@dataclass
class GameState:
    """One game in progress.

    Attributes
    ----------
    settings : GameSettings
    player : ndarray, shape (3,)
        The player's origin.
    attackers : ndarray, shape (N, 3)
        Attackers' origins.
    velocities : ndarray, shape (N, 3)
        Attackers' base velocities (scaled by the difficulty factor when moving).
    t : float
        Seconds played (paused time does not count).
    points : int
        Points from near misses.
    over : bool
        Set by :func:`check_over` once :func:`overyet` is true.
    paused : bool
    near : ndarray, shape (N,), bool
        Attackers now within the near-miss distance.
    """

    settings: GameSettings
    player: np.ndarray
    attackers: np.ndarray
    velocities: np.ndarray
    t: float = 0.0
    points: int = 0
    over: bool = False
    paused: bool = False
    near: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))

    @property
    def speed_factor(self) -> float:
        """Current multiplier of the attackers' speed (rising difficulty)."""
        return 1.0 + self.settings.level.ramp * self.t

    @property
    def score(self) -> int:
        """Survival time plus points."""
        return int(POINTS_PER_SECOND * self.t) + self.points


def new_game(settings: GameSettings | None = None) -> GameState:
    """A fresh game: the player at its start, attackers heading off in seeded directions."""
    s = settings or GameSettings()
    rng = np.random.default_rng(s.seed)
    n = len(s.attackers)
    direction = rng.normal(size=(n, 3))
    direction[:, 1] = -np.abs(direction[:, 1]) - 0.5  # start by coming down at the player
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    return GameState(
        settings=s,
        player=np.array(s.start, float),
        attackers=np.array(s.attackers, float).reshape(n, 3),
        velocities=direction * s.level.speed,
        near=np.zeros(n, bool),
    )


def distances(state: GameState) -> np.ndarray:
    """Distance from the player's origin to each attacker's origin, shape (N,)."""
    return np.linalg.norm(state.attackers - state.player, axis=1)


def overyet(state: GameState) -> bool:
    """True when the player's origin is closer than the threshold to an attacker's."""
    return bool(np.any(distances(state) < state.settings.level.threshold))


def check_over(state: GameState) -> bool:
    """Run :func:`overyet` and latch ``state.over``; returns ``state.over``."""
    state.over = state.over or overyet(state)
    return state.over


def clamp(state: GameState, point: np.ndarray) -> np.ndarray:
    """``point`` clamped into the arena box."""
    return np.clip(point, state.settings.lo, state.settings.hi)


def move(state: GameState, name: str) -> np.ndarray:
    """Shift the player's origin by one move (see :data:`MOVES`); returns the new origin.

    Raises
    ------
    KeyError
        For an unknown move name.
    """
    if not (state.over or state.paused):
        shift = np.array(MOVES[name]) * state.settings.step
        state.player = clamp(state, state.player + shift)
    return state.player


def nudge(state: GameState, delta: np.ndarray) -> np.ndarray:
    """Shift the player's origin by ``delta`` (continuous input: dials, sticks)."""
    if not (state.over or state.paused):
        state.player = clamp(state, state.player + np.asarray(delta, float).reshape(3))
    return state.player


def attacker_velocities(state: GameState) -> np.ndarray:
    """Attackers' current velocities (base velocity times the speed factor)."""
    return state.velocities * state.speed_factor


def advance(state: GameState, dt: float) -> None:
    """Move the attackers by ``dt`` seconds, bouncing off the arena walls; score."""
    if state.over or state.paused or dt <= 0:
        return
    pos = state.attackers + attacker_velocities(state) * dt
    lo, hi = np.array(state.settings.lo), np.array(state.settings.hi)
    below, above = pos < lo, pos > hi
    pos = np.where(below, 2 * lo - pos, np.where(above, 2 * hi - pos, pos))
    state.velocities = np.where(below | above, -state.velocities, state.velocities)
    state.attackers = np.clip(pos, lo, hi)
    state.t += dt
    near = distances(state) < state.settings.near_miss
    left = state.near & ~near
    state.points += NEAR_MISS_POINTS * int(np.count_nonzero(left))
    state.near = near


def tick(state: GameState, moves: list[str], dt: float) -> bool:
    """One game step in the thesis's order; returns True when the game is over.

    overyet first (on the state as last rendered); if not over, the player's moves;
    then the attackers move.
    """
    if check_over(state):
        return True
    for name in moves:
        move(state, name)
    advance(state, dt)
    return False
