import numpy as np
import pytest

from service.base.errors import SettingsError
from service.galilean.fixed_point import (
    Z_EMPTY,
    Z_LIMIT,
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


def _awkward_values(rng, scale, limit):
    """Random values with NaN, +-inf, values past the limit and exact half steps."""
    v = rng.normal(0, limit / 4, 4000)
    v[:200] = (rng.integers(-1000, 1000, 200) + 0.5) / scale  # ties round half up
    v[200:260] = np.nan
    v[260:300] = np.inf
    v[300:340] = -np.inf
    v[340:400] = rng.choice([-1, 1], 60) * limit * rng.uniform(1.0, 10.0, 60)
    v[400:420] = [limit, -limit] * 10
    return rng.permutation(v).reshape(40, 100)


def test_fixed_point_conversions_match_their_numpy_definitions():
    fx = FixedPoint.for_order(bit_budget(640, 16, 16), 2)
    rng = np.random.default_rng(8)
    # motion: NaN -> 0, +-inf -> +-limit, clamped, all flagged
    v = _awkward_values(rng, 2.0**fx.fm, fx.v_max)
    want_bad = ~np.isfinite(v) | (np.abs(v) > fx.v_max)
    for values in (v, v.astype(np.float32).astype(np.float64)):
        q, bad = fx.quantise(values, fx.v_max)
        w = np.clip(np.nan_to_num(values, nan=0.0, posinf=fx.v_max, neginf=-fx.v_max),
                    -fx.v_max, fx.v_max)
        assert q.dtype == np.int32 and q.shape == v.shape
        assert (q == np.floor(w * 2.0**fx.fm + 0.5).astype(np.int32)).all()
        assert (bad == want_bad).all()
    assert (fx.quantise(v.astype(np.float32), fx.v_max)[0]
            == fx.quantise(v.astype(np.float32).astype(np.float64), fx.v_max)[0]).all()
    # z motion: non-finite -> 0
    lim = Z_LIMIT / 2.0**fx.fzm
    z = _awkward_values(rng, 2.0**fx.fzm, lim)
    q, bad = fx.zmotion_fixed(z)
    w = np.clip(np.nan_to_num(z, nan=0.0, posinf=0.0, neginf=0.0), -lim, lim)
    assert (q == np.floor(w * 2.0**fx.fzm + 0.5).astype(np.int32)).all()
    assert (bad == (~np.isfinite(z) | (np.abs(z) > lim))).all()
    # depth: NaN and +inf empty (not flagged); -inf and beyond the format clamped, flagged
    d = _awkward_values(rng, 2.0**fx.fz, Z_LIMIT / 2.0**fx.fz)
    q, bad = fx.depth_fixed(d)
    empty = np.isnan(d) | (d == np.inf)
    f = np.floor(np.where(empty, 0.0, d) * 2.0**fx.fz + 0.5)
    assert (q == np.where(empty, Z_EMPTY, np.clip(f, -Z_LIMIT, Z_LIMIT)).astype(np.int32)).all()
    assert (bad == (~empty & (np.abs(f) > Z_LIMIT))).all()
    assert (q[empty] == Z_EMPTY).all() and bad[d == -np.inf].all()


def test_quantise_where_masks_pixels_to_zero_unflagged():
    fx = FixedPoint.for_order(bit_budget(640, 16, 16), 2)
    v = np.array([[[1.0, np.nan], [np.inf, 0.25]], [[-1.0, 2.0], [np.nan, -0.25]]])
    where = np.array([[True, False], [False, True]])
    q, bad = fx.quantise(v, fx.v_max, where)
    assert q[:, ~where].tolist() == [[0, 0], [0, 0]] and not bad[:, ~where].any()
    assert (q[:, where] == fx.quantise(v[:, where], fx.v_max)[0]).all()
    z, zbad = fx.zmotion_fixed(v, where)
    assert (z[:, ~where] == 0).all() and zbad.tolist() == [[[False, False], [False, False]],
                                                           [[False, False], [False, False]]]
    with pytest.raises(ValueError, match="where has shape"):
        fx.quantise(v, fx.v_max, where[:1])
