"""A real ``holo-service`` subprocess for the benchmarks, on free loopback ports."""

from __future__ import annotations

import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

from service.base.signals import end_process
from service.net.client import ServiceClient

ROOT = Path(__file__).resolve().parents[2]


def port() -> int:
    """A TCP port nobody listens on right now (racy)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


#: Longest wait for a started service to finish warming up (a cold cache on a loaded
#: 2-core machine took 485 s).
WARMUP_WAIT_S = 900.0


class Running:
    """A ``holo-service`` subprocess on free ports (killed on exit)."""

    def __init__(self, *args: str) -> None:
        self.control, self.frames = f"tcp://127.0.0.1:{port()}", f"tcp://127.0.0.1:{port()}"
        cmd = [
            sys.executable,
            "-m",
            "service.commands.holo_service",
            "--control",
            self.control,
            "--frames",
            self.frames,
            "--worker-address",
            f"tcp://127.0.0.1:{port()}",
            *args,
        ]
        self.proc = subprocess.Popen(
            cmd, cwd=ROOT, stdin=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        self.client = ServiceClient(self.control, timeout_s=2.0, retries=30)

    def __enter__(self) -> Running:
        try:  # a service that has to compile answers "warming up" until it is ready
            self.client.wait_ready(timeout_s=WARMUP_WAIT_S)
        except BaseException:
            self.__exit__()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.client.close()
        end_process(self.proc)

    def wait_updates(self, n: int, timeout_s: float) -> bool:
        """Poll stats until ``n`` updates were grafted."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if self.client.stats()["updates"] >= n:
                return True
            threading.Event().wait(0.1)
        return False


