"""Replay scheduling on a fake clock: no drift, speed, skip, loop."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.recording import Record
from drivers.replay_clock import ReplayScheduler, ReplaySettings, replay
from service.base.errors import SettingsError


class FakeClock:
    """A clock whose sleep advances time by the request plus a fixed overshoot."""

    def __init__(self, start_ns: int = 1_000_000_000, overshoot_ns: int = 0) -> None:
        self.now = start_ns
        self.overshoot = overshoot_ns
        self.slept: list[float] = []

    def clock_ns(self) -> int:
        return self.now

    def sleep(self, seconds: float) -> None:
        assert seconds > 0
        self.slept.append(seconds)
        self.now += round(seconds * 1e9) + self.overshoot


def records(times_ns) -> list[Record]:
    return [Record("tracker", int(t), b"x") for t in times_ns]


def play(recs, clock: FakeClock, **kw) -> tuple[list[Record], list[int], ReplayScheduler]:
    sched = ReplayScheduler(ReplaySettings(**kw), clock_ns=clock.clock_ns, sleep=clock.sleep)
    got, at = [], []
    for r in sched.play(recs):
        got.append(r)
        at.append(clock.now)
    return got, at, sched


def test_no_drift_over_10000_records_with_oversleeping_clock():
    rng = np.random.default_rng(0)
    t = 5_000_000 + np.cumsum(rng.integers(1_000_000, 25_000_000, 10_000))  # irregular, 1-25 ms
    clock = FakeClock(overshoot_ns=700_000)  # every sleep wakes 0.7 ms late
    got, at, sched = play(records(t), clock)
    assert len(got) == 10_000
    target = at[0] + (t - t[0])
    late = np.array(at) - target
    assert late.min() >= 0
    assert late.max() <= 700_000  # one oversleep at most, never accumulated
    assert sched.stats.max_late_ns == late.max()
    # a naive "sleep the gap since the previous record" would end ~7 s late here
    assert at[-1] - at[0] == pytest.approx(t[-1] - t[0], abs=700_000)


def test_speed_factor_scales_timing():
    t = np.arange(0, 1000) * 10_000_000  # 10 ms apart
    clock = FakeClock()
    _, at, _ = play(records(t), clock, speed=4.0)
    np.testing.assert_array_equal(np.diff(at), 2_500_000)


def test_as_fast_as_possible_never_sleeps():
    clock = FakeClock()
    got, at, sched = play(records(np.arange(500) * 10**9), clock, as_fast_as_possible=True)
    assert len(got) == 500 and clock.slept == [] and set(at) == {clock.now}
    assert sched.stats.sleeps == 0


@pytest.mark.parametrize("mode", ["drop", "fast"])
def test_skip_starts_at_the_skip_point(mode):
    t = np.arange(100) * 100_000_000  # 0.1 s apart, 9.9 s long
    clock = FakeClock()
    t0 = clock.now
    got, at, _ = play(records(t), clock, skip_s=2.0, skip_mode=mode)
    assert len(got) == (80 if mode == "drop" else 100)
    first_paced = got[-80]
    assert first_paced.t_ns == 2 * 10**9 and at[-80] == t0
    assert at[-1] - t0 == 7_900_000_000  # the skipped 2 s are not waited for
    if mode == "fast":
        assert at[:20] == [t0] * 20


def test_loop_repeats_without_drift():
    t = np.arange(10) * 50_000_000  # 0.45 s per pass
    clock = FakeClock(overshoot_ns=123_456)
    got, at, sched = play(records(t), clock, loop=True, max_passes=3, loop_gap_s=0.05)
    assert len(got) == 30 and sched.stats.passes == 3
    target = at[0] + np.concatenate([t, t + 500_000_000, t + 1_000_000_000])
    late = np.array(at) - target
    assert late.min() >= 0 and late.max() <= 123_456


def test_stop_ends_playback():
    clock = FakeClock()
    sched = ReplayScheduler(ReplaySettings(loop=True), clock_ns=clock.clock_ns, sleep=clock.sleep)
    got = []
    for r in sched.play(records(np.arange(5) * 1000)):
        got.append(r)
        if len(got) == 12:
            sched.stop()
    assert len(got) == 12


def test_out_of_order_times_are_handed_out_at_once():
    clock = FakeClock()
    got, at, _ = play(records([0, 10**9, 5 * 10**8, 2 * 10**9]), clock)
    assert [a - at[0] for a in at] == [0, 10**9, 10**9, 2 * 10**9]


def test_replay_shorthand_and_custom_time_accessor():
    clock = FakeClock()
    items = [(0.0, "a"), (0.5, "b"), (1.5, "c")]
    out = []
    for item in replay(
        items,
        ReplaySettings(speed=0.5),
        clock_ns=clock.clock_ns,
        sleep=clock.sleep,
        time_of=lambda it: round(it[0] * 1e9),
    ):
        out.append((item[1], clock.now))
    assert [(name, now - out[0][1]) for name, now in out] == [
        ("a", 0),
        ("b", 10**9),
        ("c", 3 * 10**9),
    ]


@pytest.mark.parametrize(
    "kw",
    [
        {"speed": 0.0},
        {"speed": float("inf")},
        {"skip_s": -1.0},
        {"skip_mode": "seek"},
        {"max_passes": 0},
    ],
)
def test_bad_settings_rejected(kw):
    with pytest.raises(SettingsError):
        ReplaySettings(**kw)


@settings(max_examples=50, deadline=None)
@given(
    gaps=st.lists(st.integers(0, 10**8), min_size=1, max_size=200),
    speed=st.floats(0.1, 20.0),
    overshoot=st.integers(0, 5_000_000),
)
def test_lateness_bounded_by_one_oversleep(gaps, speed, overshoot):
    t = np.cumsum([0, *gaps])
    clock = FakeClock(overshoot_ns=overshoot)
    _, at, _ = play(records(t), clock, speed=speed)
    target = at[0] + np.round((t - t[0]) / speed)
    late = np.array(at) - target
    assert late.min() >= 0 and late.max() <= overshoot + 1


def test_replays_a_log_file_at_recorded_times(tmp_path):
    from drivers.recording import DeviceInfo, LogHeader, LogReader, LogWriter

    path = tmp_path / "s.hlog"
    t = 7_000_000_000 + np.arange(200) * 12_500_000
    with LogWriter(path, LogHeader((DeviceInfo("tracker", "hatire"),))) as w:
        for k, tk in enumerate(t):
            w.write("tracker", int(tk), bytes([k % 256]))
    clock = FakeClock(overshoot_ns=50_000)
    got, at, _ = play(LogReader(path), clock, speed=2.0, loop=True, max_passes=2)
    assert [r.data[0] for r in got] == [k % 256 for k in range(200)] * 2
    late = np.array(at[:200]) - (at[0] + (t - t[0]) // 2)
    assert 0 <= late.min() and late.max() <= 50_000
