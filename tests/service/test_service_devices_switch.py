"""``set_viewer(devices=ADDR)`` at run time: the service follows a new holo-devices source."""

from __future__ import annotations

import json
import time

import zmq
from testkit import wait_until

from service.net.client import FrameSubscriber, ServiceClient


class Source:
    """A holo-devices-like PUB socket sending tracker poses (docs/device-messages.md)."""

    def __init__(self, session: str) -> None:
        self.sock = zmq.Context.instance().socket(zmq.PUB)
        self.sock.setsockopt(zmq.LINGER, 0)
        # a port of its own choosing: one picked beforehand can be taken before the bind
        self.address = f"tcp://127.0.0.1:{self.sock.bind_to_random_port('tcp://127.0.0.1')}"
        self.session = session
        self.n = 0

    def pose(self, x_mm: float, seq: int) -> None:
        self.n += 1
        body = {
            "t": self.n / 60, "device": "tracker", "kind": "pose",
            "yaw": 0.0, "pitch": 0.0, "roll": 0.0, "x": x_mm, "y": 0.0, "z": 600.0,
            "seq": seq, "t_ns": time.monotonic_ns(), "session": self.session, "n": self.n,
        }  # fmt: skip
        self.sock.send_multipart([b"pose", json.dumps(body).encode()])

    def close(self) -> None:
        self.sock.close(0)


def _follow(frames: FrameSubscriber, sources: list[tuple[Source, float, int]], want: int) -> dict:
    """Keep every source publishing until a frame carries pose ``seq`` ``want``."""
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        for src, x_mm, seq in sources:
            src.pose(x_mm, seq)
        got = frames.next(0.1)
        if got and got[0]["pose_seq"] == want:
            return got[0]
    raise AssertionError(f"no frame carried pose {want}")


def test_set_viewer_switches_device_source(service_factory):
    a, b = Source("left"), Source("right")
    try:
        svc = service_factory(
            "--scene", "game", "--zones", "5", "--size", "32x24",
            "--workers", "0", "--refresh", "30",
        )  # fmt: skip
        with FrameSubscriber(svc.frames) as frames, ServiceClient(svc.control) as c:
            assert wait_until(lambda: frames.next(0.5), 60), "no frames"
            assert frames.next(1.0)[0]["pose_seq"] is None  # no devices yet
            assert c.set_viewer(devices=a.address)["devices"] == a.address
            # a: 150 mm left at 600 mm (-14 deg of 16) -> zone 0; b: right -> zone 4
            left = _follow(frames, [(a, -150.0, 100), (b, 150.0, 200)], 100)
            assert left["zone"] == 0 and c.stats()["zone"] == 0
            assert c.set_viewer(devices=b.address)["devices"] == b.address
            right = _follow(frames, [(a, -150.0, 101), (b, 150.0, 201)], 201)
            assert right["zone"] == 4 and c.stats()["zone"] == 4
            # only b is heard now: a's poses never come back
            seen = set()
            for _ in range(20):
                a.pose(-150.0, 103)
                b.pose(150.0, 203)
                got = frames.next(0.2)
                if got:
                    seen.add(got[0]["pose_seq"])
            assert 103 not in seen and 101 not in seen and 203 in seen, seen
            assert c.set_viewer(devices=None)["devices"] is None
    finally:
        a.close()
        b.close()
