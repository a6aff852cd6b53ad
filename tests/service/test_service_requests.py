"""Resent mutating requests are applied once; size caps answer ``too_large``; render stats."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest
import zmq

from service.net import protocol
from service.net.client import RequestTooLargeError, ServiceClient


def _exchange(address: str, frames: list, timeout_ms: int = 20000) -> dict | None:
    """Send ``frames`` on a fresh DEALER (a fresh connection, as a Lazy Pirate resend)."""
    s = zmq.Context.instance().socket(zmq.DEALER)
    s.setsockopt(zmq.LINGER, 0)
    s.connect(address)
    try:
        s.send_multipart(frames, copy=False)
        if not s.poll(timeout_ms):
            return None
        return json.loads(s.recv_multipart()[1])
    finally:
        s.close(0)


TRI_V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
TRI_T = np.array([[0, 1, 2]], np.int32)


def _tri() -> dict:
    return {"name": "tri", "mesh": {"vertices": TRI_V, "triangles": TRI_T}}


def _load_object(rid: int, client_id: str | None) -> list:
    obj = {"name": "tri", "mesh": {"vertices": {"$array": 0}, "triangles": {"$array": 1}}}
    head = {
        "v": 1,
        "type": "load_object",
        "id": rid,
        "object": obj,
        "arrays": [{"dtype": "float32", "shape": [3, 3]}, {"dtype": "int32", "shape": [1, 3]}],
    }
    if client_id is not None:
        head["client_id"] = client_id
    return [b"", json.dumps(head).encode(), TRI_V.tobytes(), TRI_T.tobytes()]


def test_resent_load_object_adds_the_object_once(svc):
    first = _exchange(svc.control, _load_object(7, "c-0001"))
    again = _exchange(svc.control, _load_object(7, "c-0001"))  # the resend, new socket
    other = _exchange(svc.control, _load_object(8, "c-0001"))
    assert first["ok"] and again["ok"] and other["ok"]
    assert again["index"] == first["index"]
    assert other["index"] == first["index"] + 1
    # another client may reuse the id: its request is its own
    third = _exchange(svc.control, _load_object(7, "c-0002"))
    assert third["index"] == first["index"] + 2
    with ServiceClient(svc.control) as c:
        assert c.stats()["resends_answered"] >= 1


def test_library_resend_is_answered_from_the_cache(svc):
    with ServiceClient(svc.control) as c:
        c._ids = itertools.repeat(41)  # every request reuses one id, as a resend does
        a = c.load_object(obj=_tri())
        b = c.load_object(obj=_tri())
        assert a == b


def test_message_between_field_cap_and_maxmsgsize_gets_too_large(svc):
    limits = protocol.Limits()
    hello = _exchange(svc.control, [b"", json.dumps({"v": 1, "type": "hello", "id": 1}).encode()])
    assert hello["limits"]["max_array_bytes"] == limits.max_array_bytes
    assert hello["limits"]["max_message_bytes"] == limits.max_message_bytes
    rows = limits.max_array_bytes // 24 + 1024  # float64 (V, 3): just past the array cap
    assert limits.max_array_bytes < rows * 24 < limits.max_message_bytes
    vertices = np.zeros((rows, 3), np.float64)
    head = {
        "v": 1,
        "type": "load_object",
        "id": 3,
        "object": {"name": "big", "mesh": {"vertices": {"$array": 0}, "triangles": {"$array": 1}}},
        "arrays": [{"dtype": "float64", "shape": [rows, 3]}, {"dtype": "int32", "shape": [1, 3]}],
    }
    got = _exchange(svc.control, [b"", json.dumps(head).encode(), vertices, TRI_T.tobytes()])
    assert got is not None, "no reply: the connection was dropped"
    assert not got["ok"] and got["error"]["code"] == "too_large"
    assert _exchange(svc.control, [b"", json.dumps({"v": 1, "type": "ping", "id": 4}).encode()])


def test_client_refuses_an_oversized_request_before_sending(svc):
    with ServiceClient(svc.control) as c:
        c.hello()
        requests = c.stats()["requests"]
        c.limits = protocol.Limits(max_array_bytes=1024)
        big = {
            "name": "big",
            "mesh": {"vertices": np.zeros((200, 3)), "triangles": np.array([[0, 1, 2]], np.int32)},
        }
        with pytest.raises(RequestTooLargeError, match="arrays\\[0\\] has 4800 bytes"):
            c.load_object(obj=big)
        assert c.stats()["requests"] == requests + 1  # only this stats request arrived


def test_render_reply_has_stats(svc):
    with ServiceClient(svc.control, timeout_s=20) as c:
        header, arrays = c.render_once()
    st = header["stats"]
    assert st["method"] == "zbuffer" and st["mode"] == "in_process"
    for stage in ("project", "cull", "sort", "occlusion", "motion", "galpixmap", "total"):
        assert st["ms"][stage] >= 0.0
    p = st["polygons"]
    assert p["in"] > 0 and 0 <= p["culled"] <= p["in"] and 0 < p["drawn"] <= p["in"]
    assert st["rendezvous"] >= 0 and st["wall_ms"] > 0
    assert arrays["colour"].shape == (2, 24, 32, 3)
