"""Event dataclasses: schema, immutability, round trip through dicts, registry."""

from __future__ import annotations

import dataclasses
import json

import pytest

from drivers.events import (
    ButtonEvent,
    DecoderStats,
    DialEvent,
    PoseEvent,
    StatusEvent,
    event_from_dict,
)
from drivers.protocols import DECODERS, DEVICE_OF, make_decoder
from service.errors import ProtocolError

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


def test_registry_and_uniform_interface():
    assert set(DECODERS) == {"hatire", "native", "sgi"}
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
