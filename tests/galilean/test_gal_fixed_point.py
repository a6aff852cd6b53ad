import numpy as np
import pytest

from service.errors import SettingsError
from service.galilean.fixed_point import (
    FixedPoint,
    bit_budget,
    pixel_of,
    points_fixed,
    propagate_points,
)


def test_bit_budget_paper_example():
    b = bit_budget(1024, 16, 16)
    assert (b.frac_position, b.frac_velocity, b.frac_acceleration) == (4, 7, 7)
    assert (b.int_velocity, b.int_acceleration) == (8, 5)
    assert b.total == 31
    assert b.int_position == 10


def test_bit_budget_rules_of_thumb():
    base = bit_budget(1024, 16, 16).total
    assert bit_budget(2048, 16, 16).total == base + 2
    assert bit_budget(1024, 32, 16).total == base + 5
    assert bit_budget(1024, 16, 8).total == base + 3
    assert bit_budget(512, 16, 16).total == 29 and bit_budget(256, 16, 16).total == 27


def test_bit_budget_rejects_bad_input():
    with pytest.raises(SettingsError):
        bit_budget(0, 16, 16)
    with pytest.raises(SettingsError):
        bit_budget(1024, 2, 16)
    with pytest.raises(ValueError):
        bit_budget(float("nan"), 16, 16)


def _jumps(velocity: float, steps: int = 40) -> list[int]:
    fx = FixedPoint.for_order(bit_budget(1024, 16, 16), 1)
    x, v, a, j = points_fixed(np.zeros((1, 1)), np.array([[[velocity]], [[0.0]], [[0.0]]]), fx, 1)
    path = propagate_points(x, v, a, j, 1, fx.fp, fx.fm, steps)
    px = [int(pixel_of(int(p), fx.fp)) for p in path[:, 0, 0]]
    return [t for t in range(1, steps + 1) if px[t] != px[t - 1]]


def test_symmetric_rounding_one_sixteenth():
    # Moving right at 1/16 px/refresh it jumps at refresh 8, then every 16.
    assert _jumps(1 / 16) == [8, 24, 40]
    # Moving left it jumps at refresh 9 (-8/16 is still this pixel).
    assert _jumps(-1 / 16) == [9, 25]


def test_step_sums_velocity_and_half_acceleration_before_rounding():
    fx = FixedPoint.for_order(bit_budget(1024, 16, 16), 2)
    # v = 3/128 and a/2 = 3/256: each alone rounds to 0 at 1/16 px, the sum 9/256 rounds to 1/16.
    motion = np.array([[[3 / 128]], [[6 / 256]], [[0.0]]])
    x, v, a, j = points_fixed(np.zeros((1, 1)), motion, fx, 2)
    path = propagate_points(x, v, a, j, 2, fx.fp, fx.fm, 1)
    assert path[1, 0, 0] == 1  # one 1/16 px step


def test_quantise_clamps_and_flags_bad_values():
    fx = FixedPoint.for_order(bit_budget(640, 16, 16), 2)
    q, bad = fx.quantise(np.array([np.nan, np.inf, -1e9, 0.5]), fx.v_max)
    assert bad.tolist() == [True, True, True, False]
    assert q[0] == 0 and q[1] == int(fx.v_max * 2**fx.fm) and q[2] == -q[1]
    assert q[3] == 2 ** (fx.fm - 1)
