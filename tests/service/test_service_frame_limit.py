"""A request with more frames than ``max_frames`` gets ``too_large``; the service keeps serving."""

from __future__ import annotations

import json

import zmq
from testkit import raw_request

from service.net.client import ServiceClient


def _send(address: str, frames: list[bytes]) -> dict | None:
    s = zmq.Context.instance().socket(zmq.DEALER)
    s.setsockopt(zmq.LINGER, 0)
    s.connect(address)
    try:
        s.send_multipart(frames)
        if not s.poll(10000):
            return None
        return json.loads(s.recv_multipart()[1])
    finally:
        s.close(0)


def test_too_many_frames_are_too_large(small_service):
    addr = small_service.control
    hello = raw_request(addr, {"v": 1, "type": "hello", "id": 1})
    max_frames = hello["limits"]["max_frames"]
    assert max_frames == 1 + 1 + 1024  # docs/protocol.md 1.6
    with ServiceClient(addr) as c:
        errors = c.stats()["errors"]
    # after the empty delimiter: the header and max_frames buffers, one frame too many
    arrays = [{"dtype": "uint8", "shape": [1]}] * max_frames
    head = {"v": 1, "type": "ping", "id": 2, "arrays": arrays}
    got = _send(addr, [b"", json.dumps(head).encode(), *[b"x"] * max_frames])
    assert got is not None, "no reply"
    assert got["v"] == 1 and got["ok"] is False
    assert got["error"]["code"] == "too_large", got
    assert str(max_frames - 2) in got["error"]["message"]  # the buffers allowed
    assert got["id"] is None and got["type"] is None  # not read: the count is checked first
    # the connection's peer and every other client are still served
    assert raw_request(addr, {"v": 1, "type": "ping", "id": 3})["ok"]
    with ServiceClient(addr, timeout_s=20) as c:
        assert c.stats()["errors"] == errors + 1
        header, arrays = c.render_once()
        assert header["ok"] and arrays["colour"].shape == (2, 24, 32, 3)
