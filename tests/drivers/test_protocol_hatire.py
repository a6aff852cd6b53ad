"""Hatire decoder and encoders: fixture capture, resync rules, chunk-split invariance."""

from __future__ import annotations

import struct
from collections import Counter

import pytest
from drivers_fixtures import MISSING, hatire_capture
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.events import PoseEvent, StatusEvent
from drivers.protocols import make_decoder
from drivers.protocols.hatire import (
    HatireCommands,
    HatireDecoder,
    encode_command,
    encode_pose,
    encode_text,
)
from service.base.errors import ProtocolError

FIXTURE = hatire_capture()


def feed_split(dec, data: bytes, cuts: list[int], t_ns: int = 0) -> list:
    events, prev = [], 0
    for c in sorted(set(cuts)) + [len(data)]:
        events += dec.feed(data[prev:c], t_ns)
        prev = c
    return events + dec.flush(t_ns)


def statuses(events) -> Counter:
    return Counter(e.event for e in events if isinstance(e, StatusEvent))


def poses(events) -> list[PoseEvent]:
    return [e for e in events if isinstance(e, PoseEvent)]


@pytest.fixture(scope="module")
def capture() -> bytes:
    if not FIXTURE.is_file():
        pytest.skip(MISSING)
    return FIXTURE.read_bytes()


def test_capture_decodes_to_4765_frames_with_two_gaps(capture):
    dec = HatireDecoder()
    events = dec.feed(capture, 1) + dec.flush(2)
    assert len(capture) == 143_090
    assert len(poses(events)) == 4765
    assert dec.stats.frames == 4765
    assert dec.stats.counter_gaps == 2
    gaps = [dict(e.details) for e in events if getattr(e, "event", "") == "counter_gap"]
    assert gaps == [{"expected": 643, "got": 647, "missing": 4},
                    {"expected": 55, "got": 56, "missing": 1}]
    first = events[0]
    assert first.event == "resync" and first.details["discarded"] == 79  # the PuTTY banner
    assert poses(events)[0].seq == 641
    assert dec.stats.truncated == 1  # the torn last frame, reported at flush
    assert dec.stats.out_of_range > 0  # some yaw values beyond +/-180


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(0, 143_090), max_size=60))
def test_capture_same_events_for_any_chunking(capture, cuts):
    whole = HatireDecoder()
    expected = whole.feed(capture, 0) + whole.flush(0)
    assert feed_split(HatireDecoder(), capture, cuts) == expected


@given(st.lists(st.tuples(st.floats(-179, 179, width=32), st.floats(-89, 89, width=32),
                          st.floats(-179, 179, width=32), st.floats(-1e3, 1e3, width=32)),
                min_size=1, max_size=20),
       st.lists(st.integers(0, 600), max_size=10), st.sampled_from(["little", "big"]))
def test_round_trip_any_split(values, cuts, order):
    data = b"".join(encode_pose(i, y, p, r, x, -x, 0.5, byte_order=order)
                    for i, (y, p, r, x) in enumerate(values))
    events = feed_split(HatireDecoder(byte_order=order), data, cuts)
    assert [(e.seq, e.yaw, e.pitch, e.roll, e.x) for e in events] == [
        (i, y, p, r, x) for i, (y, p, r, x) in enumerate(values)]


def test_garbage_between_frames_loses_nothing():
    frames = [encode_pose(i, 1.0, 2.0, 3.0) for i in range(6)]
    junk = [b"\x00\x01", b"\xaa", b"\xaa\xaa\x01\x02\x03\x04\x05", b"\x55\x55", b""]
    data = b"".join(f + j for f, j in zip(frames, junk + [b""], strict=True))
    dec = HatireDecoder()
    events = dec.feed(data, 5) + dec.flush(6)
    assert [e.seq for e in poses(events)] == list(range(6))
    assert dec.stats.bytes_discarded == 2 + 1 + 7 + 2
    assert dec.stats.resyncs + dec.stats.truncated == 4
    assert dec.stats.counter_gaps == 0


def test_truncated_frame_then_intact_frame():
    good = encode_pose(1, 10.0, 0.0, 0.0)
    data = encode_pose(0, 0.0, 0.0, 0.0)[:17] + good
    dec = HatireDecoder()
    events = dec.feed(data, 0)
    assert statuses(events) == Counter({"truncated": 1})
    assert [e.seq for e in poses(events)] == [1]
    assert events[0].details["bytes"] == 17


def test_partial_frame_kept_across_calls_and_flush_reports_it():
    frame = encode_pose(3, 1.0, 2.0, 3.0)
    dec = HatireDecoder()
    assert dec.feed(frame[:29], 1) == []
    assert [e.seq for e in dec.feed(frame[29:], 2)] == [3]
    assert dec.feed(frame[:10], 3) == []
    tail = dec.flush(4)
    assert statuses(tail) == Counter({"truncated": 1}) and dec.stats.truncated == 1


def test_counter_wraps_without_gap_and_gap_reported():
    data = b"".join(encode_pose(c, 0, 0, 0) for c in (998, 999, 0, 1, 5))
    events = HatireDecoder().feed(data, 0)
    gaps = [e for e in events if isinstance(e, StatusEvent)]
    assert len(gaps) == 1 and dict(gaps[0].details) == {"expected": 2, "got": 5, "missing": 3}


def test_text_frames_become_status_events_and_restart_counter():
    data = (encode_pose(7, 0, 0, 0) + encode_text(3000, "init ok") + encode_pose(0, 0, 0, 0)
            + encode_text(9000, "IMU failure") + encode_text(2000, "x" * 40))
    events = HatireDecoder().feed(data, 0)
    kinds = [(e.kind, getattr(e, "event", None)) for e in events]
    assert kinds == [("pose", None), ("status", "info"), ("pose", None),
                     ("status", "error"), ("status", "info")]
    assert events[1].details == {"code": 3000, "meaning": "init", "text": "init ok"}
    assert events[3].details["text"] == "IMU failure"
    assert events[4].details["text"] == "x" * 24


def test_out_of_range_reported_once_per_run_but_delivered():
    angles = [0, 200, 300, 0, float("nan"), 0]
    data = b"".join(encode_pose(i, a, 0, 0) for i, a in enumerate(angles))
    dec = HatireDecoder()
    events = dec.feed(data, 0)
    assert len(poses(events)) == 6
    assert dec.stats.out_of_range == 3
    assert statuses(events) == Counter({"error": 2})


def test_unknown_code_is_an_error_status():
    frame = bytearray(encode_pose(0, 0, 0, 0))
    struct.pack_into("<H", frame, 2, 1500)
    events = HatireDecoder().feed(bytes(frame), 0)
    assert [e.details["reason"] for e in events] == ["unknown_code"]


def test_commands_configurable_and_validated():
    assert encode_command("start") == b"S"
    assert encode_command("stop", HatireCommands(stop=b"x")) == b"x"
    with pytest.raises(ProtocolError):
        encode_command("jump")
    with pytest.raises(ProtocolError):
        HatireCommands(start=b"ab")
    with pytest.raises(ProtocolError):
        make_decoder("hatire", byte_order="middle")
    with pytest.raises(ProtocolError):
        encode_text(100, "no")


def test_pose_event_json_schema():
    ev = HatireDecoder().feed(encode_pose(4, 1.5, -2.0, 3.0, 4.0, 5.0, 6.0), 2_500_000_000)[0]
    assert ev.to_dict(t0_ns=500_000_000) == {
        "t": 2.0, "device": "tracker", "kind": "pose", "yaw": 1.5, "pitch": -2.0,
        "roll": 3.0, "x": 4.0, "y": 5.0, "z": 6.0, "seq": 4}


@pytest.mark.parametrize(("stub", "event", "details"), [
    (b"\xaa\xaa\x01", "resync", {"discarded": 3}),  # shorter than MIN_TRUNCATED: garbage
    (b"\xaa\xaa\x01\x00", "truncated", {"bytes": 4}),  # MIN_TRUNCATED bytes: a torn frame
])
def test_a_header_stub_before_a_frame_is_garbage_below_four_bytes_and_torn_from_four(
        stub, event, details):
    # mutant: MIN_TRUNCATED 4 -> 5 (a 4-byte torn frame reported as a resync)
    good = encode_pose(7, 1.0, 2.0, 3.0)
    dec = HatireDecoder()
    events = dec.feed(stub + good, 0)
    assert [(e.event, dict(e.details)) for e in events if isinstance(e, StatusEvent)] \
        == [(event, details)]
    assert [e.seq for e in poses(events)] == [7]


@pytest.mark.parametrize(("code", "event", "meaning", "restarts"), [
    (2000, "info", "info", False), (3000, "info", "init", True),
    (5000, "info", "start", True), (9000, "error", "error", False),
    (4000, "info", "text", False),
])
def test_each_text_code_has_its_meaning_and_only_init_and_start_restart_the_counter(
        code, event, meaning, restarts):
    # mutants: TEXT_CODES keys 2000 / 5000 and RESTART_CODES' 5000 changed
    data = encode_pose(7, 0, 0, 0) + encode_text(code, "hi") + encode_pose(0, 0, 0, 0)
    events = HatireDecoder().feed(data, 0)
    status = [e for e in events if isinstance(e, StatusEvent)]
    assert (status[0].event, dict(status[0].details)) \
        == (event, {"code": code, "meaning": meaning, "text": "hi"})
    assert [e.event for e in status[1:]] == ([] if restarts else ["counter_gap"])


@pytest.mark.parametrize(("code", "reason"), [(999, None), (1000, "unknown_code"),
                                              (1999, "unknown_code")])
def test_codes_below_1000_are_poses_and_1000_to_1999_unknown(code, reason):
    # mutant: `code < COUNTER_MODULO` as `<=` (code 1000 decoded as a pose)
    frame = bytearray(encode_pose(0, 0, 0, 0))
    struct.pack_into("<H", frame, 2, code)
    events = HatireDecoder().feed(bytes(frame), 0)
    assert [getattr(e, "seq", None) if reason is None else e.details["reason"]
            for e in events] == [code if reason is None else reason]


def test_text_codes_2000_to_65535_encode_and_others_are_refused():
    # mutant: `code > 0xFFFF` as `>=` (65535 refused)
    assert encode_text(65535, "x")[2:4] == b"\xff\xff"
    for bad in (1999, 65536):
        with pytest.raises(ProtocolError, match="2000..65535"):
            encode_text(bad, "x")


def test_an_out_of_range_first_frame_and_one_after_reset_are_reported():
    # mutant: reset() starting with _in_range False (the first bad frame not reported)
    dec = HatireDecoder()
    for _ in range(2):
        events = dec.feed(encode_pose(0, 500, 0, 0), 0)
        assert [e.details["reason"] for e in events if isinstance(e, StatusEvent)] \
            == ["out_of_range"]
        dec.reset()


def test_a_header_with_no_other_header_within_a_frame_is_dropped_as_garbage():
    # mutant: `nxt < 0 or nxt < j + MIN_TRUNCATED` as `and` (no header ahead: torn)
    junk = b"\xaa\xaa" + bytes(range(1, 41))
    dec = HatireDecoder()
    events = dec.feed(junk + encode_pose(4, 0, 0, 0), 0)
    assert [(e.event, dict(e.details)) for e in events if isinstance(e, StatusEvent)] \
        == [("resync", {"discarded": len(junk)})]
    assert [e.seq for e in poses(events)] == [4] and dec.stats.truncated == 0


def test_a_lone_header_byte_at_the_end_is_garbage_not_a_torn_frame():
    # mutant: flush's `left and startswith(HEADER)` as `or`
    dec = HatireDecoder()
    assert dec.feed(encode_pose(1, 0, 0, 0) + b"\xaa", 0) != []
    assert [(e.event, dict(e.details)) for e in dec.flush(1)] \
        == [("resync", {"discarded": 1})]
    assert dec.stats.truncated == 0


@pytest.mark.parametrize("body", [bytes(range(1, 28)), bytes(range(1, 27)) + b"\x55\x56"])
def test_a_bad_frame_of_29_or_30_bytes_before_a_frame_gives_the_same_events_at_any_split(
        body):
    # mutants: `n - j <= FRAME_LEN` as `<` and its `break` as `continue` (a header at
    # j + 29 not yet visible: the 29 bytes dropped as garbage instead of a torn frame),
    # and the header search window j + FRAME_LEN + 1 widened (a 30-byte bad frame torn)
    # (a frame first, so that the stub does not start the buffer: mutant n - j as n + j)
    data = encode_pose(4, 0, 0, 0) + b"\xaa\xaa" + body + encode_pose(5, 0, 0, 0)
    whole = [(type(e).__name__, dict(getattr(e, "details", {}))) for e in
             feed_split(HatireDecoder(), data, [])]
    stub = 2 + len(body)
    assert whole[1] == (("StatusEvent", {"bytes": 29}) if stub == 29
                        else ("StatusEvent", {"discarded": 30}))
    assert [w[0] for w in whole] == ["PoseEvent", "StatusEvent", "PoseEvent"]
    for cut in range(1, len(data)):
        got = feed_split(HatireDecoder(), data, [cut])
        assert [(type(e).__name__, dict(getattr(e, "details", {}))) for e in got] == whole


@pytest.mark.parametrize(("angle", "reported"), [(180.0, False), (-180.0, False),
                                                 (180.0001, True), (-180.0001, True)])
def test_angles_of_exactly_the_limit_are_in_range(angle, reported):
    # mutants: `-lim <= a <= lim` with either <= as <
    for axis in range(3):
        angles = [0.0, 0.0, 0.0]
        angles[axis] = angle
        events = HatireDecoder().feed(encode_pose(0, *angles), 0)
        assert any(isinstance(e, StatusEvent) for e in events) == reported


def test_a_header_byte_before_a_torn_frame_is_a_one_byte_resync():
    # mutant: the next-header search starting at j + 2 (the torn frame at j + 1 missed)
    data = b"\xaa\xaa\xaa\x01\x02\x03\x04" + encode_pose(5, 0, 0, 0)
    events = HatireDecoder().feed(data, 0)
    assert [(e.event, dict(e.details)) for e in events if isinstance(e, StatusEvent)] \
        == [("resync", {"discarded": 1}), ("truncated", {"bytes": 6})]
