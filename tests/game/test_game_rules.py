from __future__ import annotations

import numpy as np
import pytest

from game.rules import (
    DIFFICULTIES,
    MOVES,
    NEAR_MISS_POINTS,
    GameSettings,
    advance,
    check_over,
    move,
    new_game,
    nudge,
    overyet,
    tick,
)

EXPECTED = {  # thesis 5.2.1 (moveup on +y, see the module notes)
    "moveup": (1, 1),
    "movedown": (1, -1),
    "moveright": (0, 1),
    "moveleft": (0, -1),
    "movein": (2, -1),
    "moveout": (2, 1),
}


@pytest.mark.parametrize("name", sorted(MOVES))
def test_each_move_shifts_one_origin_coordinate_by_the_step(name):
    state = new_game(GameSettings(step=0.1))
    before = state.player.copy()
    move(state, name)
    axis, sign = EXPECTED[name]
    expected = before.copy()
    expected[axis] += sign * 0.1
    np.testing.assert_allclose(state.player, expected)


def test_moves_stay_in_the_arena_and_do_nothing_when_paused_or_over():
    s = GameSettings()
    state = new_game(s)
    for _ in range(50):
        move(state, "moveleft")
    assert state.player[0] == pytest.approx(s.lo[0])
    state.paused = True
    move(state, "moveright")
    assert state.player[0] == pytest.approx(s.lo[0])
    state.paused, state.over = False, True
    nudge(state, [0.3, 0, 0])
    assert state.player[0] == pytest.approx(s.lo[0])


@pytest.mark.parametrize("difficulty", sorted(DIFFICULTIES))
def test_overyet_at_its_threshold(difficulty):
    state = new_game(GameSettings(difficulty=difficulty))
    threshold = DIFFICULTIES[difficulty].threshold
    state.attackers[:] = state.player + np.array([0.0, 0.5, 0.0])  # all far away
    assert not overyet(state)
    direction = np.array([1.0, 2.0, -2.0]) / 3.0
    state.attackers[3] = state.player + direction * (threshold + 1e-9)  # just outside
    assert not overyet(state)
    state.attackers[3] = state.player + [threshold, 0.0, 0.0]  # exactly at it: still safe
    assert np.linalg.norm(state.attackers[3] - state.player) == threshold
    assert not overyet(state)
    state.attackers[3] = state.player + direction * (threshold - 1e-9)  # just inside
    assert overyet(state)
    assert check_over(state) and state.over


def test_tick_checks_overyet_before_the_moves():
    state = new_game()
    state.attackers[0] = state.player + [0.0, 0.05, 0.0]
    before = state.player.copy()
    assert tick(state, ["moveleft"], 0.1)
    np.testing.assert_array_equal(state.player, before)  # over first: no move


def test_same_seed_same_game_and_attackers_stay_in_the_arena():
    a, b, c = (new_game(GameSettings(seed=s)) for s in (7, 7, 8))
    for _ in range(300):
        for st in (a, b, c):
            advance(st, 0.05)
    np.testing.assert_array_equal(a.attackers, b.attackers)
    assert not np.array_equal(a.attackers, c.attackers)
    lo, hi = np.array(a.settings.lo), np.array(a.settings.hi)
    assert np.all(a.attackers >= lo) and np.all(a.attackers <= hi)


def test_difficulty_rises_and_score_counts_time_and_near_misses():
    state = new_game(GameSettings(difficulty="normal"))
    f0 = state.speed_factor
    advance(state, 10.0)
    assert state.speed_factor > f0
    assert state.score >= 100
    state = new_game()
    state.attackers[:] = state.player + [0.0, 0.6, 0.0]
    state.velocities[:] = 0.0
    state.velocities[0] = [0.0, 0.0, 0.0]
    state.attackers[0] = state.player + [0.25, 0.0, 0.0]  # inside the near-miss ring
    advance(state, 0.01)
    state.velocities[0] = [1.0, 0.0, 0.0]  # and away
    advance(state, 0.5)
    assert state.points == NEAR_MISS_POINTS
