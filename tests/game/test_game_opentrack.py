"""The game's head view follows opentrack poses: UDP -> holo-devices -> the game's subscriber."""

from __future__ import annotations

import socket

from game_fakes import RecordingBackend
from testkit import HANG_S, wait_until

from drivers.protocols.opentrack import encode_raw
from drivers.subscriber import DeviceSubscriber
from game.client_loop import GameClient, LoopSettings
from game.display import GameWindow


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_the_head_view_follows_opentrack_datagrams(pygame_headless, procs):
    port = free_udp_port()
    devices = procs("drivers.commands.holo_devices", "--tracker", f"opentrack-udp://127.0.0.1:{port}",
                    "--pub", "tcp://127.0.0.1:0")
    devices.wait_lines(lambda: devices.err)
    address = devices.err[0].split()[-1]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as out, \
            DeviceSubscriber(address) as sub:
        client = GameClient(RecordingBackend(zones=3), GameWindow((320, 200)), LoopSettings(),
                            sub)
        assert client.mode == "head"

        def zone_with_head_at(x_cm: float) -> int:
            def shown() -> tuple[int] | None:  # a tuple: zone 0 is falsy
                out.sendto(encode_raw(x_cm, 0.0, 0.0, 0.0, 0.0, 0.0), ("127.0.0.1", port))
                client.tick()
                pose = sub.pose
                return (client.shown_zone(),) if pose and pose.x == 10 * x_cm else None

            got = wait_until(shown, HANG_S, 0.02)
            assert got is not None, f"no pose at {x_cm} cm reached the game"
            return got[0]

        assert zone_with_head_at(-20.0) == 0  # the viewer's left: the leftmost zone
        assert zone_with_head_at(20.0) == 2
        assert zone_with_head_at(0.0) == 1
