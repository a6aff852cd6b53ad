"""Viewer pose and input from a holo-devices stream: zone pick, pose in frame headers."""

from __future__ import annotations

import json
import time

import zmq
from testkit import wait_until

from service.net.client import FrameSubscriber, ServiceClient


class FakeDevices:
    """A PUB socket speaking docs/device-messages.md (pose and dials topics)."""

    def __init__(self) -> None:
        self.sock = zmq.Context.instance().socket(zmq.PUB)
        self.sock.setsockopt(zmq.LINGER, 0)
        # a port of its own choosing: one picked beforehand can be taken before the bind
        self.address = f"tcp://127.0.0.1:{self.sock.bind_to_random_port('tcp://127.0.0.1')}"
        self.n = 0

    def pose(self, x_mm: float, seq: int) -> None:
        self.n += 1
        body = {
            "t": self.n / 60,
            "device": "tracker",
            "kind": "pose",
            "yaw": 0.0,
            "pitch": 0.0,
            "roll": 0.0,
            "x": x_mm,
            "y": 0.0,
            "z": 600.0,
            "seq": seq,
            "t_ns": time.monotonic_ns(),
            "session": "fake",
            "n": self.n,
        }
        self.sock.send_multipart([b"pose", json.dumps(body).encode()])

    def dials(self) -> None:
        body = {
            "t": 0.0,
            "device": "dials",
            "kind": "state",
            "t_ns": time.monotonic_ns(),
            "session": "fake",
            "seq": 3,
            "dials": [0, 0, 40, 0, 0, 0, 0, 0],
            "buttons": [False] * 31 + [True],
        }
        self.sock.send_multipart([b"dials", json.dumps(body).encode()])

    def close(self) -> None:
        self.sock.close(0)


def _frame_with(frames: FrameSubscriber, devices: FakeDevices, x_mm: float, seq: int):
    """Send the pose until a frame carries it (the SUB may still be connecting)."""
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        devices.pose(x_mm, seq)
        devices.dials()
        got = frames.next(0.2)
        if got and got[0]["pose_seq"] == seq:
            return got[0]
    raise AssertionError(f"no frame carried pose {seq}")


def test_pose_picks_zone_and_reaches_frames(service_factory):
    devices = FakeDevices()
    try:
        svc = service_factory(
            "--scene",
            "game",
            "--zones",
            "5",
            "--size",
            "32x24",
            "--workers",
            "0",
            "--devices",
            devices.address,
        )
        with FrameSubscriber(svc.frames) as frames, ServiceClient(svc.control) as c:
            assert wait_until(lambda: frames.next(0.5), 60), "no frames"
            left = _frame_with(frames, devices, -150.0, 10)  # atan(-150/600) = -14 deg
            right = _frame_with(frames, devices, 150.0, 11)
            centre = _frame_with(frames, devices, 0.0, 12)
            assert (left["zone"], centre["zone"], right["zone"]) == (0, 2, 4)
            assert right["pose_t_ns"] > left["pose_t_ns"]
            assert centre["input"]["dials"][2] == 40 and centre["input"]["buttons"][31]
            assert c.stats()["pose_count"] >= 3
            view = c.set_viewer(devices=None)
            assert view["devices"] is None
    finally:
        devices.close()
