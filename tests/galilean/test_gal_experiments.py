import numpy as np
import pytest

from service.base.errors import SettingsError
from service.bench.galilean_experiments import (
    falling,
    galcube,
    galcube_paper,
    radius_shown,
    rotating_square,
    run_case,
    run_tracker,
    uniform,
)
from service.galilean.fixed_point import FixedPoint, bit_budget


@pytest.mark.parametrize(
    "order, interval, expected",
    [
        (0, 2, [0, 1, 0, 5, 0, 9, 0, 13, 0, 17]),
        (1, 2, [0, 1, 0, 1, 0, 1, 0, 1, 0, 1]),
        (0, 3, [0, 1, 4, 0, 7, 16, 0, 13, 28, 0]),
        (1, 3, [0, 1, 4, 0, 1, 4, 0, 1, 4, 0]),
        (2, 2, [0] * 10),
        (2, 3, [0] * 10),
        (2, 7, [0] * 10),
    ],
)
def test_falling_object_paper_errors(order, interval, expected):
    run = run_case(falling(2.0), order, interval, 10)
    assert run.errors(one_d=True).tolist() == expected


def test_falling_displayed_positions_equation_7():
    run = run_case(falling(2.0), 1, 3, 10)
    assert run.shown[:, 0, 0].tolist() == [0, 0, 0, 9, 15, 21, 36, 48, 60, 81]


def test_g3_exact_for_cubic_motion():
    def cubic(t):
        return (np.array([[0.1 * t**3]]),
                np.array([[[0.3 * t**2]], [[0.6 * t]], [[0.6]]]))
    run = run_case(cubic, 3, 8, 24, subpixel=True)
    assert np.max(np.abs(run.exact - run.subpixel)) < 0.1
    assert np.max(np.abs(run.errors(True))) <= 0.5


def test_rotating_square_grows_under_g1_bounded_under_g2():
    interval, frames = 8, 64
    sq = rotating_square(100.0, 2 * np.pi / 64)
    g1 = run_case(sq, 1, interval, frames)
    r1 = radius_shown(g1).reshape(-1, interval)
    assert np.all(np.diff(r1, axis=1) > 0)  # grows between every pair of refreshes
    assert r1[:, -1].min() > 100 + 10
    g2 = run_case(sq, 2, interval, frames)
    dev1, dev2 = np.abs(radius_shown(g1) - 100), np.abs(radius_shown(g2) - 100)
    assert dev2.max() < 0.2 * dev1.max()
    # G(2)'s error is bounded by the first omitted Taylor term (plus a pixel of rounding)
    # and is the same in every update interval: it does not accumulate.
    k = np.arange(frames) % interval
    e2 = g2.errors(False)
    assert np.all(e2 <= 100 * (2 * np.pi / 64 * k) ** 3 / 6 + 1.0)
    per_interval = e2.reshape(-1, interval).max(axis=1)
    assert np.ptp(per_interval) < 1.0
    assert e2.max() < 0.25 * g1.errors(False).max()


def test_galcube_paper_arithmetic():
    est = galcube_paper()
    assert est[0] == pytest.approx(25.1, abs=0.1)
    assert est[1] == pytest.approx(3.16, abs=0.02)
    assert est[2] == pytest.approx(0.265, abs=0.005)


def test_galcube_measured_errors_after_one_update_interval():
    # Propagate 4 refreshes from an exact (sub-pixel) update: the error at t = 4.
    errs = [run_case(galcube(), n, 5, 5, subpixel=True).subpixel_errors()[4] for n in range(3)]
    assert errs[0] == pytest.approx(25.0, abs=0.5)
    assert errs[1] == pytest.approx(3.2, abs=0.2)
    assert errs[2] == pytest.approx(0.26, abs=0.06)


def test_g3_with_noisy_differentiated_tracker_is_unstable():
    raw3 = run_tracker("raw", 3, 8)
    raw2 = run_tracker("raw", 2, 8)
    filt2 = run_tracker("alpha-beta-gamma", 2, 8)
    assert raw3.max() > 5 * filt2.max()
    assert raw3.max() > 3 * raw2.max()
    # and it gets worse, fast, the longer it propagates
    assert run_tracker("raw", 3, 16).max() > 5 * raw3.max()
    assert run_tracker("alpha-beta-gamma", 2, 4).max() < 2.0


def test_error_grows_past_rating():
    # 1/3 px/refresh is not representable: the velocity error accumulates.
    fx = FixedPoint.for_order(bit_budget(1024, 16, 16), 1)
    run = run_case(uniform(1 / 3), 1, 2000, 2000, fixed=fx, subpixel=True)
    err = np.abs(run.exact - run.subpixel)[:, 0, 0]
    assert err[16] <= 1.0  # within the rating: at most a pixel after N_prop refreshes
    assert err[64] > 1.0  # past it the error keeps growing
    assert err[1999] > 10 * err[16]


def test_bad_case_arguments():
    with pytest.raises(SettingsError):
        run_case(falling(), 4, 2, 10)
    with pytest.raises(ValueError):
        run_case(falling(), 1, 0, 10)
