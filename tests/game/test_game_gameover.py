from __future__ import annotations

import numpy as np

from game.gameover import (
    TIMETABLE,
    Beeper,
    GameOverSequence,
    burst_records,
    tone,
)


def test_three_beeps_then_the_display_then_the_score():
    seq = GameOverSequence(10.0)
    got = []
    for t in np.arange(10.0, 20.0, 0.05):
        got += seq.due(float(t))
    assert got == ["beep", "beep", "beep", "explode", "score"]
    assert [e for _, e in TIMETABLE].count("beep") == 3
    assert seq.phase == "score" and seq.finished(20.0)


def test_tone_and_a_muted_beeper_counts():
    wave = tone(880.0, 0.1, 8000, 2)
    assert wave.shape == (800, 2) and wave.dtype == np.int16
    assert abs(int(wave[0, 0])) < 200 and np.abs(wave).max() > 10_000  # faded in, loud
    beeper = Beeper(muted=True)
    for _ in range(3):
        beeper.beep()
    assert beeper.muted and beeper.count == 3


def test_object_burst_moves_everything_away_from_the_player():
    records = [
        {"name": "player", "position": [0.0, 0.0, 0.0]},
        {"name": "attacker1", "position": [0.5, 0.0, 0.0]},
    ]
    out = burst_records(records, seed=0)
    assert out[1]["velocity"][0] > 0 and out[1]["acceleration"][1] < 0
    assert out[0]["name"] == "player" and records[1].get("velocity") is None
