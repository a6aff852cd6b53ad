"""opentrack datagrams over real UDP move the service's (and so the game's) view."""

from __future__ import annotations

import socket
import time

from testkit import HANG_S, wait_until

from drivers.protocols.opentrack import encode_raw
from service.net.client import FrameSubscriber, ServiceClient


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def zone_after(frames: FrameSubscriber, send, zone: int) -> dict:
    """Send the pose until a frame shows ``zone`` (the links may still be connecting)."""
    deadline = time.monotonic() + HANG_S
    while time.monotonic() < deadline:
        send()
        got = frames.next(0.05)
        if got and got[0]["zone"] == zone and got[0]["pose_seq"] is not None:
            return got[0]
    raise AssertionError(f"no frame showed zone {zone}")


def test_opentrack_head_moves_pick_the_zone_through_holo_devices(procs, service_factory):
    port = free_udp_port()
    devices = procs("drivers.commands.holo_devices", "--tracker", f"opentrack-udp://127.0.0.1:{port}",
                    "--pub", "tcp://127.0.0.1:0")
    devices.wait_lines(lambda: devices.err)
    assert devices.err[0].startswith("holo-devices: publishing on tcp://127.0.0.1:")
    svc = service_factory("--scene", "game", "--zones", "5", "--size", "32x24", "--workers",
                          "0", "--devices", devices.err[0].split()[-1])
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as out, \
            FrameSubscriber(svc.frames) as frames, ServiceClient(svc.control) as c:
        assert wait_until(lambda: frames.next(0.5), HANG_S), "no frames"

        def head_at(x_cm: float):  # x_cm right of the centred pose (opentrack centres its output)
            return lambda: out.sendto(encode_raw(x_cm, 0.0, 0.0, 0.0, 0.0, 0.0),
                                      ("127.0.0.1", port))

        left = zone_after(frames, head_at(-15.0), 0)  # atan(-15 / 60) = -14 deg
        right = zone_after(frames, head_at(15.0), 4)
        centre = zone_after(frames, head_at(0.0), 2)
        assert left["pose_seq"] < right["pose_seq"] < centre["pose_seq"]  # datagram numbers
        assert right["pose_t_ns"] > left["pose_t_ns"]
        assert c.stats()["pose_count"] >= 3
