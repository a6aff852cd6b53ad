"""The frame stream's header codec (``protocol.parse_frame``, ``docs/protocol.md`` 2.2).

Every malformed message gives a ``MessageError`` whose message says what is wrong;
the subscriber drops it, counts it and goes on with the next good frame.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import zmq
from testkit import wait_until

from service.base.errors import MessageError
from service.net import protocol, wire
from service.net.client import FrameSubscriber

COLOUR = np.zeros((2, 3, 4, 3), np.uint8)
GOOD = {"v": 1, "kind": "frame", "session": "ab12", "seq": 7, "render_id": 3,
        "since_render": 2, "scene": 5, "refresh": 40, "t_ns": 123}


def _message(header: dict, arrays=(COLOUR,), names=("colour",), topic=b"frame") -> list:
    return [topic, *wire.encode(header, list(arrays), list(names))]


def test_a_good_frame_and_heartbeat_are_read():
    got = protocol.parse_frame(_message(GOOD))
    assert got["scene"] == 5 and got["seq"] == 7
    assert got["arrays"]["colour"].shape == COLOUR.shape
    hb = protocol.parse_frame([b"hb", json.dumps({"v": 1, "kind": "hb", "session": "ab12",
                                                  "seq": 7, "status": "ready"}).encode()])
    assert hb["kind"] == "hb" and "arrays" not in hb
    old = {k: v for k, v in GOOD.items() if k != "scene"}  # a service older than `scene`
    assert "scene" not in protocol.parse_frame(_message(old))


@pytest.mark.parametrize("cut", [1, 10, 40, -1])
def test_a_torn_header_is_a_clear_bad_json(cut):
    frames = _message(GOOD)
    frames[1] = bytes(frames[1])[:cut]
    with pytest.raises(MessageError, match=r"frame header: .*\(torn or cut short\?\)") as err:
        protocol.parse_frame(frames)
    assert err.value.code == "bad_json"


BROKEN = [
    ({**GOOD, "v": 2}, "bad_version", "v must be one of"),
    ({**GOOD, "kind": "hb"}, "bad_message", "kind 'hb' under topic 'frame'"),
    ({**GOOD, "session": 5}, "bad_message", "session must be a string"),
    ({**GOOD, "seq": "7"}, "bad_message", "seq must be an integer >= 0"),
    ({**GOOD, "scene": -1}, "bad_message", "scene must be an integer >= 0"),
    ({**GOOD, "scene": 1.5}, "bad_message", "scene must be an integer"),
    ({**GOOD, "scene": True}, "bad_message", "scene must be an integer"),
    ({**GOOD, "render_id": None}, "bad_message", "render_id must be an integer >= -1"),
    ({k: v for k, v in GOOD.items() if k != "render_id"}, "bad_message", "render_id missing"),
]


@pytest.mark.parametrize(("header", "code", "words"), BROKEN)
def test_a_malformed_header_names_what_is_wrong(header, code, words):
    with pytest.raises(MessageError, match=words) as err:
        protocol.parse_frame(_message(header))
    assert err.value.code == code


def test_broken_framing_is_refused():
    with pytest.raises(MessageError, match="topic and a header") as err:
        protocol.parse_frame([b"frame"])
    assert err.value.code == "bad_frames"
    with pytest.raises(MessageError, match="unknown topic"):
        protocol.parse_frame(_message(GOOD, topic=b"junk"))
    frames = _message(GOOD)
    with pytest.raises(MessageError, match="1 array descriptors but 0 buffer frames"):
        protocol.parse_frame(frames[:2])  # the colour buffer lost
    frames[2] = bytes(frames[2])[:-1]
    with pytest.raises(MessageError, match="needs 72 bytes, got 71") as err:
        protocol.parse_frame(frames)
    assert err.value.code == "bad_array"
    with pytest.raises(MessageError, match="every array needs a name"):
        protocol.parse_frame([b"frame", *wire.encode(GOOD, [COLOUR])])


def test_the_subscriber_drops_counts_and_goes_on():
    ctx = zmq.Context.instance()
    pub = ctx.socket(zmq.PUB)
    pub.setsockopt(zmq.LINGER, 0)
    pub.bind("tcp://127.0.0.1:*")
    sub = FrameSubscriber(pub.getsockopt_string(zmq.LAST_ENDPOINT))
    hb = [b"hb", json.dumps({"v": 1, "kind": "hb", "session": "ab12", "seq": 0}).encode()]
    try:
        # the subscription takes a moment to reach the PUB: heartbeats until one is heard
        assert wait_until(lambda: pub.send_multipart(hb) or sub.next(0.05) is None
                          and sub.session == "ab12", 10)
        torn = _message(GOOD)
        torn[1] = bytes(torn[1])[:30]
        pub.send_multipart(torn)
        pub.send_multipart([bytes(f) for f in _message({**GOOD, "seq": 8})])
        got = sub.next(5.0)
        assert got is not None and got[0]["seq"] == 8 and got[0]["scene"] == 5
        assert sub.malformed == 1 and "torn or cut short" in sub.last_error
    finally:
        sub.close()
        pub.close(0)
