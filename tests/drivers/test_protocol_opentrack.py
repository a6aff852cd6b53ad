"""opentrack UDP datagrams: layout, axes into the display's, bad datagrams dropped."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.events import PoseEvent, StatusEvent
from drivers.protocols import make_decoder
from drivers.protocols.opentrack import (
    DATAGRAM_LEN,
    OpentrackDecoder,
    encode_pose,
    encode_raw,
)
from service.render.scene import euler_quaternion


def rotate(q, v) -> np.ndarray:
    """``v`` rotated by the unit quaternion ``q`` (w, x, y, z)."""
    w, r = q[0], np.asarray(q[1:], float)
    v = np.asarray(v, float)
    return v + 2 * np.cross(r, np.cross(r, v) + w * v)


def test_a_datagram_is_six_little_endian_doubles_in_opentracks_order():
    # as opentrack's proto-udp writes its double[6] (TX, TY, TZ, Yaw, Pitch, Roll)
    data = struct.pack("<6d", 1.5, -2.0, 60.0, 10.0, 5.0, -3.0)
    assert len(data) == DATAGRAM_LEN == 48
    assert encode_raw(1.5, -2.0, 60.0, 10.0, 5.0, -3.0) == data
    (pose,) = OpentrackDecoder().feed(data, 7)
    # centimetres -> millimetres; opentrack's yaw right / pitch down -> ours left / up
    assert pose == PoseEvent(7, yaw=-10.0, pitch=-5.0, roll=-3.0, x=15.0, y=-20.0, z=600.0,
                             seq=0)


def test_opentrack_head_turns_land_in_the_display_axes():
    """Turning right, looking down, moving right and back, as the display reads them."""
    dec = OpentrackDecoder()
    forward = np.array([0.0, 0.0, -1.0])  # the viewer looks at the display (-z)
    (right,) = dec.feed(encode_raw(0, 0, 0, 30.0, 0, 0), 0)  # opentrack: yaw right
    gaze = rotate(euler_quaternion(*np.radians([right.yaw, right.pitch, right.roll])), forward)
    assert gaze[0] > 0.4 and abs(gaze[1]) < 1e-9  # looks toward +x, the viewer's right
    (down,) = dec.feed(encode_raw(0, 0, 0, 0, 20.0, 0), 0)  # opentrack: pitch down
    gaze = rotate(euler_quaternion(*np.radians([down.yaw, down.pitch, down.roll])), forward)
    assert gaze[1] < -0.3  # looks below the centre
    (moved,) = dec.feed(encode_raw(5.0, 2.0, 10.0, 0, 0, 0), 0)  # right, up, back
    assert (moved.x, moved.y, moved.z) == (50.0, 20.0, 100.0)  # mm, z toward the viewer


@given(st.lists(st.floats(-170, 170, allow_nan=False), min_size=6, max_size=6))
def test_encode_pose_round_trips_through_the_decoder(values):
    x, y, z = (v * 10 for v in values[:3])  # mm, within +/- 500 cm
    yaw, pitch, roll = values[3:]
    (pose,) = OpentrackDecoder().feed(encode_pose(x, y, z, yaw, pitch, roll), 0)
    got = (pose.x, pose.y, pose.z, pose.yaw, pose.pitch, pose.roll)
    assert got == pytest.approx((x, y, z, yaw, pitch, roll), rel=1e-12, abs=1e-9)


@pytest.mark.parametrize("size", [1, 24, 47, 49, 96, 1000])
def test_wrong_sized_datagrams_are_counted_and_dropped(size):
    dec = OpentrackDecoder()
    good = encode_pose(1, 2, 3, 4, 5, 6)
    events = dec.feed(good, 0) + dec.feed((good * 30)[:size], 1) + dec.feed(good, 2)
    assert [type(e) for e in events] == [PoseEvent, StatusEvent, PoseEvent]
    assert events[1].event == "error" and dict(events[1].details) == {
        "reason": "wrong_size", "seq": 1, "bytes": size, "expected": 48}
    assert [e.seq for e in events if isinstance(e, PoseEvent)] == [0, 2]
    s = dec.stats
    assert (s.frames, s.bad_size, s.bytes_discarded, s.bytes_in) == (2, 1, size, 96 + size)


@pytest.mark.parametrize("field", range(6))
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_nan_and_inf_in_any_field_are_dropped(field, bad):
    values = [1.0] * 6
    values[field] = bad
    dec = OpentrackDecoder()
    (status,) = dec.feed(encode_raw(*values), 0)
    assert status.event == "error" and status.details["reason"] == "not_finite"
    assert dec.stats.out_of_range == 1 and dec.stats.frames == 1


@pytest.mark.parametrize(("values", "ok"), [
    ((500.0, -500.0, 500.0, 180.0, -180.0, 180.0), True),  # the limits themselves
    ((500.1, 0, 0, 0, 0, 0), False),
    ((0, 0, -1e300, 0, 0, 0), False),
    ((0, 0, 0, 180.5, 0, 0), False),
    ((0, 0, 0, 0, -181.0, 0), False),
    ((0, 0, 0, 0, 0, 720.0), False),
])
def test_values_out_of_range_are_dropped(values, ok):
    dec = OpentrackDecoder()
    (event,) = dec.feed(encode_raw(*values), 0)
    assert isinstance(event, PoseEvent) == ok
    if not ok:
        assert event.details["reason"] == "out_of_range"
        assert dec.stats.out_of_range == 1


def test_a_run_of_bad_datagrams_is_reported_once_per_run_and_reason():
    dec = OpentrackDecoder()
    good, short = encode_pose(0, 0, 0, 0, 0, 0), b"\0" * 12
    nan = encode_raw(math.nan, 0, 0, 0, 0, 0)
    events = []
    for data in (short, short, short, nan, nan, good, short, good):
        events += dec.feed(data, 0)
    reasons = [e.details["reason"] if isinstance(e, StatusEvent) else "pose" for e in events]
    assert reasons == ["wrong_size", "not_finite", "pose", "wrong_size", "pose"]
    assert dec.stats.resyncs == 2  # two runs of bad datagrams
    assert (dec.stats.bad_size, dec.stats.out_of_range) == (4, 2)


def test_an_empty_datagram_is_not_one():
    dec = OpentrackDecoder()
    assert dec.feed(b"", 0) == [] and dec.stats.bytes_in == 0
    assert dec.feed(encode_pose(0, 0, 0, 0, 0, 0), 0)[0].seq == 0


def test_reset_numbers_datagrams_from_zero_and_limits_are_settings():
    dec = make_decoder("opentrack", angle_limit=90.0, position_limit_cm=50.0)
    assert dec.device == "tracker"
    assert isinstance(dec.feed(encode_raw(0, 0, 0, 89.0, 0, 0), 0)[0], PoseEvent)
    assert isinstance(dec.feed(encode_raw(0, 0, 0, 91.0, 0, 0), 0)[0], StatusEvent)
    assert dec.feed(encode_raw(51.0, 0, 0, 0, 0, 0), 0) == []  # the same run: counted only
    assert dec.stats.out_of_range == 2
    dec.reset()
    (pose,) = dec.feed(encode_raw(0, 0, 0, 0, 0, 0), 0)
    assert pose.seq == 0 and dec.flush(0) == []
