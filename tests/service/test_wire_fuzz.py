"""Any bytes or any JSON in a message's header make the parsers raise ``MessageError``.

The service's request loop, the broker (band replies from workers) and every frame
subscriber catch ``MessageError`` and nothing else: any other exception from a
parser would be a crash (or, in the broker, a garbled reply that hid a bug).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.base.errors import MessageError
from service.net import protocol, wire

ARRAYS = [np.arange(12, dtype=np.float32).reshape(3, 4), np.zeros(5, np.uint8)]


def _frames(header: dict) -> list[bytes]:
    return [bytes(memoryview(f)) for f in wire.encode(header, ARRAYS, ["a", "b"])]


#: parser, a good message, the index of its JSON header frame
CASES = {
    "reply": (protocol.parse_reply, _frames({"ok": True, "job": 1, "band": 0}), 0),
    "frame": (protocol.parse_frame, [b"frame", *_frames(
        {"v": 1, "kind": "frame", "session": "s", "seq": 3, "render_id": 1})], 1),
    "request": (protocol.parse_request, _frames(
        {"v": 1, "id": "r1", "type": "render", "a": {"$array": 0}, "b": {"$array": 1}}), 0),
}
JSON = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=6), inner,
                                                                max_size=3),
    max_leaves=8)
KEYS = ("arrays", "v", "kind", "session", "seq", "render_id", "id", "type", "job", "ok", "a")
DESC_KEYS = ("dtype", "shape", "encoding", "name")


def _parse(kind: str, frames: list[bytes]) -> None:
    parse = CASES[kind][0]
    try:
        parse(frames)
    except MessageError:
        pass


def test_the_good_messages_parse():
    for parse, frames, _ in CASES.values():
        parse(frames)


@settings(max_examples=300, deadline=None)
@given(kind=st.sampled_from(sorted(CASES)), key=st.sampled_from(KEYS), value=JSON,
       desc_key=st.none() | st.sampled_from(DESC_KEYS))
def test_any_json_value_in_the_header_is_a_message_error(kind, key, value, desc_key):
    _, good, at = CASES[kind]
    header = json.loads(good[at])
    if desc_key is None:
        header[key] = value
    else:  # inside the first array descriptor
        header["arrays"][0][desc_key] = value
    frames = list(good)
    frames[at] = json.dumps(header).encode()
    _parse(kind, frames)


@settings(max_examples=300, deadline=None)
@given(kind=st.sampled_from(sorted(CASES)), data=st.data())
def test_cut_or_flipped_bytes_and_lost_frames_are_message_errors(kind, data):
    frames = [bytearray(f) for f in CASES[kind][1]]
    k = data.draw(st.integers(0, len(frames) - 1))
    op = data.draw(st.sampled_from(("flip", "cut", "drop")))
    if op == "drop":
        del frames[k]
    elif frames[k]:
        i = data.draw(st.integers(0, len(frames[k]) - 1))
        if op == "cut":
            del frames[k][i:]
        else:
            frames[k][i] ^= data.draw(st.integers(1, 255))
    _parse(kind, [bytes(f) for f in frames])


def test_a_huge_quaternion_is_refused_without_a_warning(recwarn):
    from service.render.scene import Transform

    with pytest.raises(MessageError, match="viewer.orientation must be a unit quaternion"):
        wire.transform_from_wire({"orientation": [1e308] * 4}, "viewer", Transform())
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]


def test_a_pending_request_past_the_size_caps_is_not_sent():
    from service.net.client import PendingRequest, RequestTooLargeError

    req = PendingRequest("tcp://127.0.0.1:9", timeout_s=0.1)  # nothing listens: not reached
    try:
        with pytest.raises(RequestTooLargeError, match=r"stats: header has \d+ bytes"):
            req.send("stats", note="x" * (2 << 20))  # a 2 MiB header (cap 1 MiB)
        assert not req.waiting and req.sent == 0
        assert req.send("stats") and req.waiting  # a small one still goes out
    finally:
        req.close()
