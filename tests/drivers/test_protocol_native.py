"""Native tracker protocol: framing, CRC, resync, quaternion conversion, chunking."""

from __future__ import annotations

import math
import random
from collections import Counter

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.events import PoseEvent, StatusEvent
from drivers.protocols.crc import crc16_ccitt, crc16_ccitt_reference, crc32
from drivers.protocols.native import (
    NativeDecoder,
    NativeFramer,
    encode_command,
    encode_frame,
    encode_pose,
    encode_text,
    euler_from_quat,
    quat_from_euler,
)
from service.base.errors import ProtocolError


def feed_split(dec, data: bytes, cuts: list[int]) -> list:
    events, prev = [], 0
    for c in sorted(set(cuts)) + [len(data)]:
        events += dec.feed(data[prev:c], 0)
        prev = c
    return events + dec.flush(0)


def pose_frames(n: int, start: int = 0) -> list[bytes]:
    return [encode_pose(start + i, 1000 * i, (i, -i, 0.5), quat_from_euler(i, 0, 0))
            for i in range(n)]


def test_crc_check_values():
    assert crc16_ccitt(b"123456789") == 0x29B1 == crc16_ccitt_reference(b"123456789")
    assert crc32(b"123456789") == 0xCBF43926


@given(st.binary(max_size=64))
def test_crc16_matches_reference(data):
    assert crc16_ccitt(data) == crc16_ccitt_reference(data)


@given(st.floats(-179, 179), st.floats(-89, 89), st.floats(-179, 179))
def test_euler_quaternion_round_trip(yaw, pitch, roll):
    q = quat_from_euler(yaw, pitch, roll)
    assert math.isclose(sum(c * c for c in q), 1.0, rel_tol=1e-9)
    back = euler_from_quat(q)
    assert back == pytest.approx((yaw, pitch, roll), abs=1e-6)


def test_quaternion_convention_yaw_is_about_y():
    w, x, y, z = quat_from_euler(90, 0, 0)
    assert (w, x, y, z) == pytest.approx((math.sqrt(0.5), 0, math.sqrt(0.5), 0))


@settings(max_examples=50, deadline=None)
@given(st.integers(1, 12), st.lists(st.integers(0, 600), max_size=12))
def test_round_trip_any_split(n, cuts):
    data = b"".join(pose_frames(n, start=2**32 - 3))
    events = feed_split(NativeDecoder(), data, cuts)
    assert [e.seq for e in events] == [(2**32 - 3 + i) % 2**32 for i in range(n)]
    assert all(isinstance(e, PoseEvent) for e in events)  # seq wrap is not a gap
    assert [e.device_t_us for e in events] == [1000 * i for i in range(n)]
    assert events[-1].yaw == pytest.approx(n - 1, abs=1e-4)


@settings(max_examples=40, deadline=None)
@given(st.randoms(use_true_random=False))
def test_single_byte_corruption_loses_only_that_frame(rnd):
    frames = pose_frames(20)
    bad = rnd.randrange(20)
    raw = bytearray(frames[bad])
    raw[rnd.randrange(len(raw))] ^= rnd.randrange(1, 256)
    frames[bad] = bytes(raw)
    dec = NativeDecoder()
    events = dec.feed(b"".join(frames), 0) + dec.flush(0)
    seqs = [e.seq for e in events if isinstance(e, PoseEvent)]
    assert seqs == [i for i in range(20) if i != bad]
    assert dec.stats.frames == 19
    if 0 < bad < 19:
        assert dec.stats.counter_gaps == 1


def test_garbage_runs_counted_exactly():
    rng = random.Random(3)
    frames = pose_frames(10)
    junk = [bytes(rng.randrange(256) for _ in range(k)) for k in (0, 5, 0, 17, 1, 0, 3, 0, 0, 9)]
    data = b"".join(j + f for j, f in zip(junk, frames, strict=True))
    dec = NativeDecoder()
    events = dec.feed(data, 0)
    assert [e.seq for e in events if isinstance(e, PoseEvent)] == list(range(10))
    resyncs = [e.details["discarded"] for e in events if getattr(e, "event", "") == "resync"]
    assert resyncs == [5, 17, 1, 3, 9]
    assert dec.stats.bytes_discarded == 35


def test_crc_error_reported_and_next_frame_recovered():
    frames = pose_frames(3)
    broken = bytearray(frames[1])
    broken[20] ^= 0x40
    dec = NativeDecoder()
    events = dec.feed(frames[0] + bytes(broken) + frames[2], 0)
    kinds = Counter(e.event for e in events if isinstance(e, StatusEvent))
    assert kinds == Counter({"crc_error": 1, "resync": 1, "counter_gap": 1})
    assert dec.stats.crc_errors == 1


def test_truncated_frame_at_flush_and_mid_stream():
    frames = pose_frames(3)
    dec = NativeDecoder()
    events = dec.feed(frames[0][:30] + frames[1] + frames[2][:10], 0) + dec.flush(0)
    assert [e.seq for e in events if isinstance(e, PoseEvent)] == [1]
    assert dec.stats.truncated == 1  # the torn tail
    assert dec.stats.resyncs >= 1   # the torn head is discarded as garbage


def test_text_frames_and_commands():
    data = encode_text(1, 7, "hello") + encode_text(2, 8, "bad", error=True)
    events = NativeDecoder().feed(data, 0)
    assert [(e.event, e.details["text"]) for e in events] == [("info", "hello"), ("error", "bad")]
    framer = NativeFramer()
    out = framer.feed(encode_command("start") + encode_command("reset"))
    assert [f.type for f in out] == [0x10, 0x12]


def test_unit_quaternion_checked():
    data = encode_pose(0, 0, (0, 0, 0), (2.0, 0, 0, 0))
    dec = NativeDecoder()
    events = dec.feed(data, 0)
    assert dec.stats.out_of_range == 1
    assert events[0].details["reason"] == "out_of_range"


def test_encoder_rejects_bad_input():
    with pytest.raises(ProtocolError):
        encode_frame(0x99, b"")
    with pytest.raises(ProtocolError):
        encode_frame(0x01, b"short")
    with pytest.raises(ProtocolError):
        encode_command("fly")


def _raw(msg_type: int, payload: bytes) -> bytes:
    """A frame with a right CRC whatever its type and length (docs/native-protocol.md)."""
    body = bytes((1, msg_type, len(payload))) + payload
    return b"\xa5\x5a" + body + crc16_ccitt_reference(body).to_bytes(2, "little")


@pytest.mark.parametrize(("name", "code"), [("start", 0x10), ("stop", 0x11), ("reset", 0x12)])
def test_command_frames_are_the_documented_bytes(name, code):
    # mutants: START/STOP/RESET type numbers changed
    assert encode_command(name) == _raw(code, b"")


def test_pose_and_text_frames_carry_the_documented_type_bytes():
    # mutants: POSE/INFO/ERROR type numbers changed
    assert encode_pose(1, 2, (0, 0, 0), (1, 0, 0, 0))[3] == 0x01
    assert encode_text(1, 2, "x")[3] == 0x02
    assert encode_text(1, 2, "x", error=True)[3] == 0x03


@pytest.mark.parametrize(("msg_type", "ok", "bad"), [
    (0x01, [40], [39, 41]), (0x02, [12, 255], [11]), (0x03, [12, 255], [11]),
    (0x10, [0], [1]), (0x11, [0], [1]), (0x12, [0], [1]),
])
def test_each_type_takes_exactly_its_payload_lengths(msg_type, ok, bad):
    # mutants: every bound of MSG_TYPES changed (a wrong-length frame with a right CRC
    # must be dropped as garbage, a right-length one delivered; encode_frame agrees)
    end = encode_command("stop")
    for n in ok:
        frames = [f for f in NativeFramer().feed(_raw(msg_type, bytes(n)) + end)
                  if not isinstance(f, tuple)]
        assert [(f.type, len(f.payload)) for f in frames] == [(msg_type, n), (0x11, 0)]
        assert encode_frame(msg_type, bytes(n)) == _raw(msg_type, bytes(n))
    for n in bad:
        framer = NativeFramer()
        out = framer.feed(_raw(msg_type, bytes(n)) + end)
        assert [f.type for f in out if not isinstance(f, tuple)] == [0x11]
        assert framer.stats.bytes_discarded == 7 + n
        with pytest.raises(ProtocolError):
            encode_frame(msg_type, bytes(n))


def test_a_frame_of_another_version_is_dropped_even_with_a_right_crc():
    # mutant: the candidate check's `or`s as `and` (version 2 frames accepted)
    good = encode_command("stop")
    body = bytes((2,)) + good[3:5]
    other = b"\xa5\x5a" + body + crc16_ccitt(body).to_bytes(2, "little")
    framer = NativeFramer()
    out = framer.feed(other + good)
    assert out == [("garbage", 7), out[1]] and out[1].type == 0x11


def test_a_bad_five_byte_header_at_the_end_is_garbage_not_a_torn_frame():
    # mutant: `n - j < HEADER_LEN` as `<=` (a whole bad header waited on, then torn)
    dec = NativeDecoder()
    events = dec.feed(b"\xa5\x5a\x07\x01\x00", 0) + dec.flush(1)
    assert [(e.event, dict(e.details)) for e in events] == [("resync", {"discarded": 5})]
    assert dec.stats.truncated == 0


def test_reset_forgets_dropped_bytes_and_re_arms_the_out_of_range_report():
    # mutants: reset's scan.run = 0 -> 1 (a phantom resync), _in_range True -> False
    bad = encode_pose(0, 0, (0, 0, 0), (2.0, 0, 0, 0))
    dec = NativeDecoder()
    dec.feed(b"\x00\x01" + bad, 0)
    dec.reset()
    dec.feed(b"\x00\x01", 0)
    dec.reset()
    events = dec.feed(bad, 0)
    assert [e.details.get("reason") for e in events if isinstance(e, StatusEvent)] \
        == ["out_of_range"]


def test_text_frames_keep_seq_and_time_and_cut_long_text_to_243_bytes():
    # mutants: encode_text's `seq % SEQ_MODULO`, `t_us % 2**64` and 255 - 12 changed
    events = NativeDecoder().feed(encode_text(5, 7, "é" + "x" * 300), 0)
    assert [dict(e.details) for e in events] \
        == [{"seq": 5, "device_t_us": 7, "text": "é" + "x" * 241}]
    events = NativeDecoder().feed(encode_text(2**32 + 1, 2**64 + 3, "a"), 0)
    assert (events[0].details["seq"], events[0].details["device_t_us"]) == (1, 3)


def test_pose_frames_wrap_seq_and_device_time():
    # mutants: encode_pose's `t_us % (1 << 64)` changed (2**64 + 3 then cannot be packed)
    frame = encode_pose(2**32 + 2, 2**64 + 3, (0, 0, 0), (1, 0, 0, 0))
    (event,) = NativeDecoder().feed(frame, 0)
    assert (event.seq, event.device_t_us) == (2, 3)


def test_a_seq_jump_says_what_was_expected_and_how_many_are_missing_and_wraps_quietly():
    # mutants: the counter_gap's expected/missing arithmetic changed
    seqs = (2**32 - 2, 2**32 - 1, 0, 1, 5)
    data = b"".join(encode_pose(s, 0, (0, 0, 0), (1, 0, 0, 0)) for s in seqs)
    events = NativeDecoder().feed(data, 0)
    assert [dict(e.details) for e in events if isinstance(e, StatusEvent)] \
        == [{"expected": 2, "got": 5, "missing": 3}]
    data = b"".join(encode_pose(s, 0, (0, 0, 0), (1, 0, 0, 0)) for s in (2**32 - 2, 1))
    events = NativeDecoder().feed(data, 0)
    assert [dict(e.details) for e in events if isinstance(e, StatusEvent)] \
        == [{"expected": 2**32 - 1, "got": 1, "missing": 2}]


def test_a_crc_error_names_the_frame_type():
    # mutant: the crc_error's type read from the wrong byte
    bad = bytearray(encode_text(1, 2, "x", error=True))
    bad[-1] ^= 0xFF
    events = [e for e in NativeDecoder().feed(bytes(bad) + pose_frames(1)[0], 0)
              if isinstance(e, StatusEvent)]
    # and its bytes are counted once, as one resync (mutant: the crc branch's drop(1))
    assert [(e.event, dict(e.details)) for e in events] \
        == [("crc_error", {"type": 3}), ("resync", {"discarded": len(bad)})]
