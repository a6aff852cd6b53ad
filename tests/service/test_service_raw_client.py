"""A client written from docs/protocol.md alone (raw pyzmq, not service.net.client)."""

from __future__ import annotations

import json
import time

import numpy as np
import zmq
from testkit import TINY_DISPLAY, raw_request, wait_until


class RawClient:
    """DEALER with the documented frames: b"", JSON header, raw buffers."""

    def __init__(self, address: str) -> None:
        self.s = zmq.Context.instance().socket(zmq.DEALER)
        self.s.setsockopt(zmq.LINGER, 0)
        self.s.connect(address)
        self.n = 0

    def ask(self, msg_type: str, arrays: tuple = (), **fields) -> tuple[dict, list[bytes]]:
        self.n += 1
        header = {"v": 1, "type": msg_type, "id": self.n, **fields}
        if arrays:
            header["arrays"] = [
                {"dtype": str(a.dtype), "shape": list(a.shape), "encoding": "raw"} for a in arrays
            ]
        self.s.send_multipart([b"", json.dumps(header).encode(), *[a.tobytes() for a in arrays]])
        assert self.s.poll(20000), f"no reply to {msg_type}"
        frames = self.s.recv_multipart()
        assert frames[0] == b""
        reply = json.loads(frames[1])
        assert reply["id"] == self.n and reply["v"] == 1
        return reply, frames[2:]

    def close(self) -> None:
        self.s.close(0)


def test_raw_client_full_session(service_factory):
    svc = service_factory(*TINY_DISPLAY, "--refresh", "30")
    c = RawClient(svc.control)
    sub = zmq.Context.instance().socket(zmq.SUB)
    sub.setsockopt(zmq.LINGER, 0)
    sub.setsockopt(zmq.SUBSCRIBE, b"")
    try:
        hello, _ = c.ask("hello", versions=[1, 99], client="raw")
        assert hello["ok"] and hello["version"] == 1 and hello["service"] == "holo-service"
        assert hello["frames"] == svc.frames and hello["heartbeat_s"] > 0
        sub.connect(hello["frames"])
        r, _ = c.ask("render")
        assert not r["ok"] and r["error"]["code"] == "no_scene"
        r, _ = c.ask("load_scene", builtin="game")
        assert r["ok"] and "player" in r["objects"]
        verts = np.array([[-0.2, -0.2, 0.0], [0.2, -0.2, 0.0], [0.0, 0.2, 0.05]], np.float32)
        tris = np.array([[0, 1, 2]], np.int32)
        r, _ = c.ask(
            "load_object",
            arrays=(verts, tris),
            object={
                "name": "tri",
                "mesh": {"vertices": {"$array": 0}, "triangles": {"$array": 1}},
                "position": [0.3, 0.3, 0.0],
                "velocity": [0.1, 0.0, 0.0],
            },
        )
        assert r["ok"] and r["index"] == 7
        r, _ = c.ask(
            "update_objects",
            objects=[
                {"name": "player", "position": [0.1, -0.5, 0.1], "velocity": [0.2, 0, 0]},
                {"index": 7, "orientation": [1, 0, 0, 0]},
            ],
        )
        assert r["ok"] and r["updated"] == 2
        r, _ = c.ask(
            "set_display",
            zones=3,
            cols=40,
            rows=30,
            galpixel_order=2,
            encodings=["colour", "depth", "debris"],
        )
        assert r["ok"] and r["display"]["zones"] == 3 and r["display"]["rows"] == 30
        r, bufs = c.ask("render")
        assert r["ok"], r
        descs = {d["name"]: d for d in r["arrays"]}
        colour = np.frombuffer(bufs[0], descs["colour"]["dtype"]).reshape(descs["colour"]["shape"])
        assert colour.shape == (3, 30, 40, 3) and colour.any()
        assert descs["depth"]["dtype"] == "float32" and len(bufs) == 2
        assert all(d["encoding"] == "raw" for d in r["arrays"])  # protocol.md 1.4 and 2
        got = _frame(sub, lambda h: h["kind"] == "frame" and len(h["arrays"]) == 3)
        header, bufs = got
        assert [d["name"] for d in header["arrays"]] == ["colour", "depth", "debris"]
        assert [d["encoding"] for d in header["arrays"]] == ["raw"] * 3
        assert header["arrays"][0]["shape"] == [3, 30, 40, 3]
        assert len(bufs[0]) == 3 * 30 * 40 * 3 and header["session"] == hello["session"]
        r, _ = c.ask("set_viewer", position=[0.0, 0.0, 0.0], velocity=[0.05, 0, 0])
        assert r["ok"] and r["viewer"]["velocity"] == [0.05, 0, 0]
        r, _ = c.ask("ping")
        assert r["ok"] and isinstance(r["t_ns"], int)
        stats, _ = c.ask("stats")
        assert stats["ok"] and stats["stats"]["updates"] >= 1
        r, _ = c.ask("shutdown")
        assert r["ok"]
        assert wait_until(lambda: svc.proc.poll() is not None, 15) and svc.proc.returncode == 0
    finally:
        c.close()
        sub.close(0)


def _frame(sub: zmq.Socket, want, timeout_s: float = 20.0):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if sub.poll(200):
            frames = sub.recv_multipart()
            header = json.loads(frames[1])
            if want(header):
                return header, frames[2:]
    raise AssertionError("no matching frame")


def test_req_socket_and_version_mismatch(small_service):
    s = zmq.Context.instance().socket(zmq.REQ)
    s.setsockopt(zmq.LINGER, 0)
    s.connect(small_service.control)
    try:
        s.send(json.dumps({"v": 1, "type": "hello", "id": "a", "versions": [2, 3]}).encode())
        assert s.poll(5000)
        reply = json.loads(s.recv())
        assert not reply["ok"] and reply["error"]["code"] == "bad_version" and reply["id"] == "a"
    finally:
        s.close(0)
    r = raw_request(small_service.control, {"v": 1, "type": "hello", "id": 3, "versions": [1]})
    assert r["ok"] and r["version"] == 1
