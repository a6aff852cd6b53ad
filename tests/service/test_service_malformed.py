"""Every malformed-message class gets an error reply; other clients keep being served."""

from __future__ import annotations

import json

import numpy as np
import pytest
import zmq
from testkit import raw_request

HELLO = {"v": 1, "type": "hello", "id": 1, "versions": [1]}


def _send(address: str, frames: list[bytes], with_delimiter: bool = True) -> list[bytes] | None:
    s = zmq.Context.instance().socket(zmq.DEALER)
    s.setsockopt(zmq.LINGER, 0)
    s.connect(address)
    try:
        s.send_multipart(([b""] if with_delimiter else []) + frames)
        if not s.poll(5000):
            return None
        return s.recv_multipart()
    finally:
        s.close(0)


def _j(obj: dict) -> bytes:
    return json.dumps(obj).encode()


def _obj() -> dict:
    return {
        "v": 1,
        "type": "load_object",
        "id": 9,
        "object": {"name": "x", "mesh": {"vertices": {"$array": 0}, "triangles": {"$array": 1}}},
    }


TRI = np.array([[0, 1, 2]], np.int32).tobytes()
V3 = np.zeros((3, 3), np.float32)
V3[1, 0] = V3[2, 1] = 1.0
NAN_V = V3.copy()
NAN_V[0, 0] = np.nan


def _arrays(*descs: tuple) -> list:
    return [{"dtype": d, "shape": list(s)} for d, s in descs]


CASES = {
    "garbage_bytes": ([b"\x00\xff\xfegarbage"], "bad_json"),
    "garbage_no_delimiter": ([b"\x89PNG\r\n"], "bad_json"),
    "empty_body": ([], "bad_frames"),
    "buffers_without_descriptors": ([_j(HELLO), b"abc", b"def"], "bad_frames"),
    "missing_buffer": (
        [_j({**_obj(), "arrays": _arrays(("float32", (3, 3)), ("int32", (1, 3)))}), V3.tobytes()],
        "bad_frames",
    ),
    "bad_json": ([b'{"v": 1, "type": "hello",'], "bad_json"),
    "json_not_object": ([b"[1, 2, 3]"], "bad_json"),
    "unknown_type": ([_j({"v": 1, "type": "explode", "id": 2})], "unknown_type"),
    "missing_version": ([_j({"type": "hello", "id": 2})], "bad_version"),
    "unknown_version": ([_j({"v": 2, "type": "ping", "id": 2})], "bad_version"),
    "string_version": ([_j({"v": "1", "type": "ping", "id": 2})], "bad_version"),
    "float_version": ([_j({"v": 1.0, "type": "ping", "id": 2})], "bad_version"),
    "bool_version": ([_j({"v": True, "type": "ping", "id": 2})], "bad_version"),
    "wrong_dtype_name": (
        [
            _j({**_obj(), "arrays": _arrays(("float16", (3, 3)), ("int32", (1, 3)))}),
            V3.astype(np.float16).tobytes(),
            TRI,
        ],
        "bad_array",
    ),
    "int_vertices": (
        [
            _j({**_obj(), "arrays": _arrays(("int32", (3, 3)), ("int32", (1, 3)))}),
            V3.astype(np.int32).tobytes(),
            TRI,
        ],
        "bad_array",
    ),
    "wrong_shape": (
        [
            _j({**_obj(), "arrays": _arrays(("float32", (3, 2)), ("int32", (1, 3)))}),
            V3[:, :2].copy().tobytes(),
            TRI,
        ],
        "bad_array",
    ),
    "byte_count": (
        [
            _j({**_obj(), "arrays": _arrays(("float32", (3, 3)), ("int32", (1, 3)))}),
            V3.tobytes()[:-4],
            TRI,
        ],
        "bad_array",
    ),
    "nan_in_array": (
        [
            _j({**_obj(), "arrays": _arrays(("float32", (3, 3)), ("int32", (1, 3)))}),
            NAN_V.tobytes(),
            TRI,
        ],
        "not_finite",
    ),
    "nan_in_json": (
        [
            b'{"v": 1, "type": "update_objects", "id": 4, '
            b'"objects": [{"index": 0, "position": [NaN, 0, 0]}]}'
        ],
        "not_finite",
    ),
    "infinity_in_json": (
        [b'{"v": 1, "type": "set_viewer", "id": 4, "velocity": [Infinity, 0, 0]}'],
        "not_finite",
    ),
    "wrong_field_type": (
        [_j({"v": 1, "type": "update_objects", "id": 5, "objects": "all"})],
        "bad_message",
    ),
    # an index is malformed (bad_message) unless it is a non-negative integer; a
    # well-formed one past the scene's end names no object (not_found)
    "unknown_index": (
        [_j({"v": 1, "type": "update_objects", "id": 5, "objects": [{"index": 999}]})],
        "not_found",
    ),
    "negative_index": (
        [_j({"v": 1, "type": "update_objects", "id": 5, "objects": [{"index": -1}]})],
        "bad_message",
    ),
    "float_index": (
        [_j({"v": 1, "type": "update_objects", "id": 5, "objects": [{"index": 1.5}]})],
        "bad_message",
    ),
    "string_index": (
        [_j({"v": 1, "type": "update_objects", "id": 5, "objects": [{"index": "0"}]})],
        "bad_message",
    ),
    "bool_index": (
        [_j({"v": 1, "type": "update_objects", "id": 5, "objects": [{"index": True}]})],
        "bad_message",
    ),
    "neither_index_nor_name": (
        [_j({"v": 1, "type": "update_objects", "id": 5, "objects": [{"position": [0, 0, 0]}]})],
        "bad_message",
    ),
    "unknown_encoding": (
        [
            _j(
                {
                    **_obj(),
                    "arrays": [
                        {"dtype": "float32", "shape": [3, 3], "encoding": "zlib"},
                        {"dtype": "int32", "shape": [1, 3], "encoding": "raw"},
                    ],
                }
            ),
            V3.tobytes(),
            TRI,
        ],
        "bad_message",
    ),
    "unknown_name": (
        [_j({"v": 1, "type": "update_objects", "id": 5, "objects": [{"name": "nobody"}]})],
        "not_found",
    ),
    "bad_settings": (
        [_j({"v": 1, "type": "set_display", "id": 6, "method": "magic"})],
        "bad_settings",
    ),
    "oversize_header": (
        [_j({"v": 1, "type": "hello", "id": 7, "pad": "x" * (1 << 20)})],
        "too_large",
    ),
    "oversize_string": (
        [_j({"v": 1, "type": "load_scene", "id": 8, "path": "p" * 5000})],
        "too_large",
    ),
    "oversize_array": (
        [
            _j(
                {**_obj(), "arrays": _arrays(("float64", (1 << 20, 1 << 20, 3)), ("int32", (1, 3)))}
            ),
            b"",
            TRI,
        ],
        "too_large",
    ),
    "too_many_updates": (
        [_j({"v": 1, "type": "update_objects", "id": 5, "objects": [{"index": 0}] * 5000})],
        "too_large",
    ),
    "missing_file": (
        [_j({"v": 1, "type": "load_scene", "id": 8, "path": "/nonexistent.obj"})],
        "not_found",
    ),
}


@pytest.mark.parametrize("name", list(CASES))
def test_malformed_gets_error_reply(svc, name):
    frames, code = CASES[name]
    reply = _send(svc.control, frames, with_delimiter=name != "garbage_no_delimiter")
    assert reply is not None, "no reply: the connection must answer every message"
    header = json.loads(reply[-1] if name == "garbage_no_delimiter" else reply[1])
    assert header["ok"] is False
    assert header["error"]["code"] == code, header
    # another client is still served, and so is the same service
    assert raw_request(svc.control, HELLO)["ok"]


def test_bad_clients_do_not_stop_good_ones(svc):
    """A good client keeps its session (one socket) while a bad one floods garbage."""
    good = zmq.Context.instance().socket(zmq.DEALER)
    good.setsockopt(zmq.LINGER, 0)
    good.connect(svc.control)
    try:
        for i in range(20):
            bad = _send(svc.control, [b"\x00" * (i + 1), b"x"])
            assert bad is not None and json.loads(bad[1])["ok"] is False
            good.send_multipart([b"", _j({"v": 1, "type": "ping", "id": i})])
            assert good.poll(5000)
            assert json.loads(good.recv_multipart()[1])["id"] == i
        stats = raw_request(svc.control, {"v": 1, "type": "stats", "id": 1})
        assert stats["stats"]["errors"] >= 20
    finally:
        good.close(0)


def test_unknown_version_reply_is_version_1_and_echoes_the_request(svc):
    """protocol.md 1.2: a request in a version the service does not speak gets a
    version-1 bad_version reply naming the versions it does speak; nothing is done."""
    before = raw_request(svc.control, {"v": 1, "type": "stats", "id": 1})["stats"]
    req = {"v": 2, "type": "shutdown", "id": "next-gen"}
    reply = raw_request(svc.control, req)
    assert reply["v"] == 1 and reply["ok"] is False
    assert reply["id"] == "next-gen" and reply["type"] == "shutdown"
    assert reply["error"]["code"] == "bad_version" and "[1]" in reply["error"]["message"]
    hello = raw_request(svc.control, {**HELLO, "versions": [2, 1]})
    assert hello["ok"] and hello["version"] == 1 and hello["versions"] == [1]
    after = raw_request(svc.control, {"v": 1, "type": "stats", "id": 2})["stats"]
    assert after["session"] == before["session"]  # the v=2 shutdown was not acted on
