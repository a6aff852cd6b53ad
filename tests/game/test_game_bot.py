from __future__ import annotations

import pytest

from game.bot import Bot
from game.rules import GameSettings, new_game, tick

DT = 1 / 30


def play(bot: Bot, settings: GameSettings, seconds: float) -> float:
    state = new_game(settings)
    while state.t < seconds and not tick(state, bot.act(state, DT), DT):
        pass
    return state.t


@pytest.mark.parametrize("seed", range(4))
def test_the_bot_survives_a_minute_on_easy(seed):
    assert play(Bot(), GameSettings(seed=seed, difficulty="easy"), 60.0) >= 60.0


def test_without_the_bot_the_game_ends_and_a_bot_that_gives_up_ends_it_soon():
    idle = new_game(GameSettings(seed=1, difficulty="hard"))
    while idle.t < 120 and not tick(idle, [], DT):
        pass
    assert idle.over
    assert play(Bot(give_up_after=3.0), GameSettings(seed=1, difficulty="easy"), 60.0) < 30.0


def test_the_bot_is_deterministic():
    a, b = (play(Bot(give_up_after=2.0), GameSettings(seed=5), 60.0) for _ in range(2))
    assert a == b
