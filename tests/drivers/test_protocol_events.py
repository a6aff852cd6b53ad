"""Event dataclasses: schema, immutability, round trip through dicts, registry."""

from __future__ import annotations

import dataclasses
import json

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.events import (
    ButtonEvent,
    DecoderStats,
    DialEvent,
    PoseEvent,
    StatusEvent,
    event_from_dict,
)
from drivers.protocols import DATAGRAM_PROTOCOLS, DECODERS, DEVICE_OF, make_decoder
from service.base.errors import ProtocolError

EVENTS = [
    PoseEvent(1_500_000_000, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7),
    PoseEvent(2, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8, (1.0, 0.0, 0.0, 0.0), 99),
    DialEvent(3, 2, -5, 100),
    ButtonEvent(4, 31, True),
    StatusEvent(5, "dials", "resync", {"discarded": 3}),
]


@pytest.mark.parametrize("ev", EVENTS)
def test_round_trip_through_json(ev):
    back = event_from_dict(json.loads(ev.to_json(t0_ns=1)), t0_ns=1)
    assert back == ev


def test_events_are_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        EVENTS[2].delta = 1
    with pytest.raises(TypeError):
        EVENTS[4].details["x"] = 1


def test_status_schema_and_validation():
    d = StatusEvent(2_000_000_000, "tracker", "reconnect", {"port": "loop://"}).to_dict()
    assert d == {"t": 2.0, "device": "tracker", "kind": "status", "event": "reconnect",
                 "details": {"port": "loop://"}}
    with pytest.raises(ProtocolError):
        StatusEvent(0, "tracker", "exploded")
    with pytest.raises(ProtocolError):
        event_from_dict({"kind": "pose", "t": 0})
    with pytest.raises(ProtocolError, match="not a device event"):  # json reads 1e400 as inf
        event_from_dict({**d, "t": float("inf")})


def test_registry_and_uniform_interface():
    assert set(DECODERS) == {"hatire", "native", "sgi", "opentrack"}
    for name, cls in DECODERS.items():
        dec = make_decoder(name)
        assert isinstance(dec, cls) and dec.device == DEVICE_OF[name]
        assert dec.feed(b"", 0) == [] and dec.flush(0) == []
        dec.reset()
        assert isinstance(dec.stats, DecoderStats)
        assert set(dec.stats.as_dict()) >= {"frames", "bytes_discarded", "resyncs",
                                            "counter_gaps", "crc_errors", "truncated"}
    with pytest.raises(ProtocolError):
        make_decoder("morse")


@pytest.mark.parametrize("name", sorted(DECODERS))
def test_random_bytes_never_raise(name):
    import random
    rng = random.Random(name)
    dec = make_decoder(name)
    for _ in range(200):
        dec.feed(bytes(rng.randrange(256) for _ in range(rng.randrange(64))), 0)
    dec.flush(0)
    assert dec.stats.bytes_in > 0


def _valid_frames(name: str) -> list[bytes]:
    from drivers.protocols import hatire, native, sgi_dialbox
    table = {
        "hatire": [hatire.encode_pose(i, 1.0, 2.0, 3.0) for i in range(3)],
        "native": [native.encode_pose(i, i, (0, 0, 0), (1, 0, 0, 0)) for i in range(3)],
        "sgi": [sgi_dialbox.encode_dial(1, 5), sgi_dialbox.encode_button(3, True), b"\x20"],
    }
    return table[name]


@pytest.mark.parametrize("name", sorted(set(DECODERS) - DATAGRAM_PROTOCOLS))
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_garbage_and_frames_any_split_same_events(name, data):
    frames = _valid_frames(name)
    parts = data.draw(st.lists(st.one_of(st.binary(max_size=12), st.sampled_from(frames)),
                               max_size=12))
    stream = b"".join(parts)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=8)))
    whole = make_decoder(name)
    expected = whole.feed(stream, 7) + whole.flush(7)
    split = make_decoder(name)
    got, prev = [], 0
    for c in cuts + [len(stream)]:
        got += split.feed(stream[prev:c], 7)
        prev = c
    got += split.flush(7)
    assert got == expected
    assert split.stats.as_dict() == whole.stats.as_dict()
    if name != "sgi":  # framed protocols: every intact frame is found, none invented
        assert sum(1 for e in expected if e.kind == "pose") == sum(p in frames for p in parts)


def test_native_frame_behind_bogus_length_survives_flush():
    from drivers.protocols import native
    frame = native.encode_pose(9, 0, (0, 0, 0), (1, 0, 0, 0))
    dec = make_decoder("native")
    events = dec.feed(b"\xa5\x5a\x01\x02\xff" + frame, 0)
    assert events == []  # waiting for the 255-byte text payload
    tail = dec.flush(0)
    assert [e.kind for e in tail] == ["status", "pose"] and tail[1].seq == 9
    assert dec.stats.truncated == 1
