"""Behaviour of the pose filters: lag, jitter, unwrapping, bad input."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.filters import (
    FILTERS,
    AlphaBetaGammaSettings,
    AlphaBetaSettings,
    OneEuroSettings,
    RawSettings,
    SampleError,
    make_filter,
    predict_ahead,
    run_filter,
    run_filter_detailed,
    wrap_angles,
)
from service.base.errors import HoloError, SettingsError

DEFAULTS = {
    "raw": RawSettings(),
    "alpha-beta": AlphaBetaSettings.from_theta(0.7),
    "alpha-beta-gamma": AlphaBetaGammaSettings.from_theta(0.7),
    "one-euro": OneEuroSettings(min_cutoff=1.0, beta=0.05, d_cutoff=2.0),
}


def irregular_times(n: int, rate: float, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    dt = (1.0 / rate) * rng.uniform(0.6, 1.4, n)
    return np.cumsum(dt)


@pytest.mark.parametrize("name", sorted(FILTERS))
def test_ramp_tracked_with_bounded_lag_and_true_velocity(name):
    t = irregular_times(800, 80.0)
    slope = np.array([10.0, -5.0, 2.0, 30.0, -20.0, 5.0])
    x = t[:, None] * slope
    pos, vel, acc = run_filter(name, t, x, DEFAULTS[name])
    tail = slice(400, None)
    np.testing.assert_allclose(vel[tail], np.broadcast_to(slope, vel[tail].shape), rtol=0.02)
    lag = (x[tail] - pos[tail]) / slope  # seconds behind truth
    assert np.all(lag > -1e-6) and np.all(lag < 0.25)
    assert np.all(np.abs(acc[tail]) < 0.5 * np.abs(slope) + 1e-6)


@pytest.mark.parametrize("name", ["raw", "alpha-beta-gamma", "one-euro"])
def test_parabola_acceleration_estimated(name):
    t = np.arange(1, 1200) / 100.0
    x = np.zeros((len(t), 6))
    x[:, 0] = 0.5 * 4.0 * t**2
    _, _, acc = run_filter(name, t, x, DEFAULTS[name])
    np.testing.assert_allclose(acc[-200:, 0], 4.0, rtol=0.05)


def test_filters_reduce_jitter_on_noisy_still_input():
    rng = np.random.default_rng(1)
    t = np.arange(2000) / 80.0
    x = rng.normal(0.0, 0.5, (2000, 6))
    rms = {}
    for name in FILTERS:
        pos, vel, _ = run_filter(name, t, x, DEFAULTS[name])
        rms[name] = (np.sqrt(np.mean(pos[100:] ** 2)), np.sqrt(np.mean(vel[100:] ** 2)))
    for name in ("alpha-beta", "alpha-beta-gamma", "one-euro"):
        assert rms[name][0] < 0.8 * rms["raw"][0]
        assert rms[name][1] < 0.3 * rms["raw"][1]
    assert rms["one-euro"][1] < 0.1 * rms["raw"][1]


@pytest.mark.parametrize("name", sorted(FILTERS))
def test_yaw_unwrapped_across_180(name):
    t = np.arange(400) / 80.0
    yaw_true = 150.0 + 40.0 * t  # crosses +180 at 0.75 s, reaches ~350
    x = np.zeros((400, 6))
    x[:, 3] = wrap_angles(np.c_[np.zeros((400, 3)), yaw_true, np.zeros((400, 2))])[:, 3]
    assert x[:, 3].max() < 180 and x[:, 3].min() >= -180
    pos, vel, _ = run_filter(name, t, x, DEFAULTS[name])
    np.testing.assert_allclose(vel[200:, 3], 40.0, rtol=0.02)
    assert np.all(np.abs(pos[:, 3] - yaw_true) < 15.0)
    np.testing.assert_allclose(wrap_angles(pos)[:, 3] % 360, pos[:, 3] % 360)


def test_yaw_beyond_180_reported_by_device_unwraps_to_continuous():
    # the Hatire capture reports yaw near -244 then near +116: the same direction
    f = make_filter("raw")
    f.update(0.0, [0, 0, 0, -244.0, 0, 0])
    st_ = f.update(0.01, [0, 0, 0, 115.9, 0, 0])
    assert st_.position[3] == pytest.approx(-244.1)
    assert st_.velocity[3] == pytest.approx(-10.0)


@pytest.mark.parametrize("name", sorted(FILTERS))
def test_predict_matches_formula_and_extrapolates_ramp(name):
    f = make_filter(name, DEFAULTS[name])
    for k in range(400):
        s = f.update(k / 80.0, np.full(6, 2.0 * k / 80.0))
    np.testing.assert_allclose(
        f.predict(0.05), s.position + s.velocity * 0.05 + 0.5 * s.acceleration * 0.05**2
    )
    np.testing.assert_allclose(
        predict_ahead(s.position[None], s.velocity[None], s.acceleration[None], 0.05)[0],
        f.predict(0.05),
    )
    if name != "one-euro":  # one-euro lags on a ramp by design
        np.testing.assert_allclose(f.predict(0.05), 2.0 * (399 / 80.0 + 0.05), atol=1e-6)


@pytest.mark.parametrize("name", sorted(FILTERS))
def test_online_and_offline_agree(name):
    rng = np.random.default_rng(3)
    t = irregular_times(300, 60.0, seed=4)
    x = np.cumsum(rng.normal(0, 1, (300, 6)), axis=0)
    pos, vel, acc = run_filter(name, t, x, DEFAULTS[name])
    f = make_filter(name, DEFAULTS[name])
    for k in range(300):
        s = f.update(t[k], x[k])
    np.testing.assert_array_equal(s.position, pos[-1])
    np.testing.assert_array_equal(s.velocity, vel[-1])
    np.testing.assert_array_equal(s.acceleration, acc[-1])


@pytest.mark.parametrize(
    ("t2", "sample2", "word"),
    [
        (0.02, [np.nan, 0, 0, 0, 0, 0], "non-finite"),
        (np.inf, [0, 0, 0, 0, 0, 0], "non-finite"),
        (0.005, [0, 0, 0, 0, 0, 0], "backwards"),
        (0.01, [0, 0, 0, 0, 0, 0], "duplicate"),
        (0.02, [0, 0, 0, 0, 0], "shape"),
    ],
)
@pytest.mark.parametrize("name", sorted(FILTERS))
def test_bad_input_raises_clearly_and_keeps_state(name, t2, sample2, word):
    f = make_filter(name)
    f.update(0.0, np.zeros(6))
    before = f.update(0.01, np.ones(6))
    with pytest.raises(SampleError, match=word):
        f.update(t2, sample2)
    assert f.state is before
    after = f.update(0.02, np.full(6, 2.0))  # still usable
    assert after.velocity[0] > 0


def test_sample_error_is_a_holo_error():
    assert issubclass(SampleError, HoloError)


def test_skip_policy_counts_and_marks_rows():
    t = np.array([0.0, 0.01, 0.01, 0.005, 0.03, 0.04])
    x = np.tile(np.arange(6.0)[:, None], (1, 6))
    x[4, 2] = np.nan
    run = run_filter_detailed("raw", t, x, RawSettings(on_bad="skip"))
    assert run.skipped == 3
    assert run.kept.tolist() == [True, True, False, False, False, True]
    assert np.all(np.isnan(run.position[2:5]))
    np.testing.assert_allclose(run.velocity[5], (5.0 - 1.0) / 0.03)


def test_bad_first_sample_raises_even_when_skipping():
    f = make_filter("one-euro", OneEuroSettings(on_bad="skip"))
    with pytest.raises(SampleError):
        f.update(0.0, [np.nan] * 6)


def test_long_gap_reinitialises():
    f = make_filter("alpha-beta")
    f.update(0.0, np.zeros(6))
    f.update(0.01, np.ones(6))
    s = f.update(5.0, np.full(6, 100.0))
    assert f.resets == 1
    np.testing.assert_array_equal(s.position, 100.0)
    np.testing.assert_array_equal(s.velocity, 0.0)


def test_update_ns_keeps_precision_of_large_counters():
    f = make_filter("raw")
    base = 10**18
    f.update_ns(base, np.zeros(6))
    s = f.update_ns(base + 1_000_000, np.ones(6))
    np.testing.assert_allclose(s.velocity, 1000.0)


@pytest.mark.parametrize(
    "build",
    [
        lambda: AlphaBetaSettings(alpha=0.0),
        lambda: AlphaBetaSettings(beta=3.0),
        lambda: AlphaBetaGammaSettings.from_theta(1.0),
        lambda: OneEuroSettings(min_cutoff=0.0),
        lambda: RawSettings(on_bad="ignore"),
        lambda: RawSettings(angle_axes=(6,)),
        lambda: make_filter("kalman"),
        lambda: make_filter("raw", OneEuroSettings()),
    ],
)
def test_bad_settings_rejected(build):
    with pytest.raises(SettingsError):
        build()


@settings(max_examples=40, deadline=None)
@given(
    name=st.sampled_from(sorted(FILTERS)),
    start=st.floats(-720, 720),
    rate=st.floats(-300, 300),
)
def test_constant_rate_rotation_unwrapped_for_any_start(name, start, rate):
    t = np.arange(120) / 60.0
    yaw = start + rate * t
    x = np.zeros((120, 6))
    x[:, 3] = (yaw + 180.0) % 360.0 - 180.0
    _, vel, _ = run_filter(name, t, x, DEFAULTS[name])
    # after settling every filter reports the true rate, never a +-360 jump
    assert np.all(np.abs(vel[1:, 3]) <= abs(rate) * 1.6 + 1e-6)
    if name in ("raw", "alpha-beta", "alpha-beta-gamma"):
        np.testing.assert_allclose(vel[-1, 3], rate, atol=1e-6 + 0.02 * abs(rate))


def test_bench_lag_estimate_recovers_known_delay():
    from service.bench.filters_bench import best_lag

    t = np.arange(2000) / 80.0
    ref = np.c_[np.sin(2 * np.pi * 0.5 * t), np.cos(2 * np.pi * 0.3 * t)]
    delayed = np.c_[np.sin(2 * np.pi * 0.5 * (t - 0.04)), np.cos(2 * np.pi * 0.3 * (t - 0.04))]
    lag, resid = best_lag(t, delayed, ref)
    assert lag == pytest.approx(0.04, abs=0.0011)
    assert resid < 1e-3


def test_bench_simulations_are_seeded_and_cross_180():
    from service.bench.filters_bench import simulated

    a, b = simulated(7), simulated(7)
    for da, db in zip(a, b, strict=True):
        np.testing.assert_array_equal(da.samples, db.samples)
        assert np.all(np.diff(da.t) > 0)
    turn = a[2]
    assert turn.truth[:, 3].max() > 240 and np.abs(turn.samples[:, 3]).max() <= 180
