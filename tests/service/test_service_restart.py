"""The service restarted on the same ports: the client library reconnects by itself."""

from __future__ import annotations

import signal

from testkit import TINY_DISPLAY, free_port, start_service, wait_until

from service.net.client import FrameSubscriber, ServiceClient


def test_client_reconnects_after_restart():
    args = ("--scene", "game", *TINY_DISPLAY)
    first = start_service(*args)
    second = None
    client = ServiceClient(first.control, timeout_s=1.0, retries=20)
    frames = FrameSubscriber(first.frames)
    try:
        old = client.hello()["session"]
        assert wait_until(lambda: frames.next(0.5), 30)
        assert frames.session == old
        first.proc.send_signal(signal.SIGKILL)
        first.proc.wait(10)
        second = start_service(*args, "--control", first.control, "--frames", first.frames)
        info = client.hello()  # Lazy Pirate: fresh socket, resend, until it answers
        assert info["session"] != old and client.restarted
        assert client.stats()["session"] == info["session"]
        assert wait_until(lambda: frames.next(0.5) and frames.session == info["session"], 30)
        assert frames.restarted
    finally:
        client.close()
        frames.close()
        first.stop()
        if second is not None:
            second.stop()


def test_client_gives_up_with_a_deadline():
    from service.base.errors import ServiceUnavailableError

    client = ServiceClient(f"tcp://127.0.0.1:{free_port()}", timeout_s=0.2, retries=2)
    try:
        try:
            client.ping()
        except ServiceUnavailableError as exc:
            assert exc.code == "unavailable"
        else:
            raise AssertionError("no service, yet a reply")
        assert client.reconnects == 3
    finally:
        client.close()
