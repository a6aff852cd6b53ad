"""Attract-mode bot: plays the game by looking ahead and dodging.

Every ``interval`` seconds the bot tries each of the six moves and standing still
on copies of the game state, lets the attackers run ``horizon`` seconds ahead with
the real rules (bounces included), and picks the choice whose closest approach to
any attacker is largest, with a small pull toward the middle of the arena so it
does not get cornered.  It is deterministic: same state, same choice.  It drives
the demo and the end-to-end tests.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from game.rules import MOVES, GameState, advance, distances, move

#: Choices the bot weighs; ``""`` is standing still.
CHOICES = ("", *MOVES)


@dataclass
class Bot:
    """The attract-mode player.

    Attributes
    ----------
    interval : float
        Seconds between decisions (a move at most this often).
    horizon : float
        Look-ahead in seconds.
    samples : int
        Steps of the look-ahead.
    centre_weight : float
        Weight of the pull toward the arena's middle.
    give_up_after : float or None
        Game seconds after which the bot stops dodging and makes for the nearest
        attacker (so attract mode shows the game over too); None: never.
    """

    interval: float = 0.1
    horizon: float = 0.8
    samples: int = 8
    centre_weight: float = 0.05
    give_up_after: float | None = None
    _wait: float = 0.0

    def act(self, state: GameState, dt: float) -> list[str]:
        """Moves for this tick (at most one), given ``dt`` seconds since the last call."""
        self._wait -= dt
        if self._wait > 0 or state.over or state.paused:
            return []
        self._wait = self.interval
        pick = max if self.give_up_after is None or state.t < self.give_up_after else min
        best = pick(CHOICES, key=lambda name: self.value(state, name))
        return [best] if best else []

    def value(self, state: GameState, name: str) -> float:
        """How good a choice is: closest predicted approach minus the off-centre pull."""
        trial = _clone(state)
        if name:
            move(trial, name)
        closest = float(np.min(distances(trial)))
        dt = self.horizon / self.samples
        for _ in range(self.samples):
            advance(trial, dt)
            closest = min(closest, float(np.min(distances(trial))))
        centre = (np.array(state.settings.lo) + np.array(state.settings.hi)) / 2
        return closest - self.centre_weight * float(np.linalg.norm(trial.player - centre))


def _clone(state: GameState) -> GameState:
    """A copy whose arrays can change without touching ``state``."""
    return replace(
        state,
        player=state.player.copy(),
        attackers=state.attackers.copy(),
        velocities=state.velocities.copy(),
        near=state.near.copy(),
    )
