"""Helpers of the service tests: free ports, raw requests, a real ``holo-service`` subprocess.

A module of its own (not ``conftest``) so that test files import it by a name no
other test folder uses.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import zmq

from service.signals import end_process

ROOT = Path(__file__).resolve().parents[2]


def free_port() -> int:
    """A TCP port nobody listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_until(predicate: Callable[[], object], timeout_s: float, step_s: float = 0.02) -> object:
    """Poll ``predicate`` until it returns something truthy or the deadline passes."""
    deadline = time.monotonic() + timeout_s
    tick = threading.Event()  # never set: wait() is the poll interval
    while time.monotonic() < deadline:
        got = predicate()
        if got:
            return got
        tick.wait(step_s)
    return predicate()


def rss_kb(pid: int) -> int:
    """Resident set size of a process from /proc, kB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


def raw_request(
    address: str,
    header: dict,
    buffers: tuple = (),
    timeout_ms: int = 5000,
    ctx: zmq.Context | None = None,
) -> dict | None:
    """One request with a fresh DEALER (raw pyzmq, protocol doc layout); reply header."""
    s = (ctx or zmq.Context.instance()).socket(zmq.DEALER)
    s.setsockopt(zmq.LINGER, 0)
    s.connect(address)
    try:
        s.send_multipart([b"", json.dumps(header).encode(), *buffers])
        if not s.poll(timeout_ms):
            return None
        frames = s.recv_multipart()
        return json.loads(frames[1])
    finally:
        s.close(0)


def _is_ready(reply: dict | None) -> bool:
    """A hello reply from a service that is ready (not warming up)."""
    return reply is not None and reply.get("status", "ready") == "ready"


@dataclass
class ServiceProcess:
    """A running ``holo-service``."""

    proc: subprocess.Popen
    control: str
    frames: str
    ports: tuple[int, ...]

    def stop(self) -> None:
        end_process(self.proc)


def start_service(
    *args: str, ports: tuple[int, int, int] | None = None, ready_timeout_s: float = 60.0
) -> ServiceProcess:
    """Start ``holo-service`` on free loopback ports and wait until hello says it is ready.

    Until its warm-up is over the service answers hello with ``status: warming_up``
    (``docs/protocol.md`` 1.8); the tests want a service that renders.

    The broker's backend goes on ``ports[2]`` when the service starts local workers
    (``--workers 0`` starts no broker unless ``args`` name a ``--worker-address``).
    """
    ports = ports or (free_port(), free_port(), free_port())
    control, frames = f"tcp://127.0.0.1:{ports[0]}", f"tcp://127.0.0.1:{ports[1]}"
    local_workers = "--worker-address" not in args and not any(
        a == "--workers" and b == "0" for a, b in zip(args, args[1:], strict=False)
    )
    backend = ["--worker-address", f"tcp://127.0.0.1:{ports[2]}"] if local_workers else []
    cmd = [
        sys.executable,
        "-m",
        "service.cli_service",
        "--control",
        control,
        "--frames",
        frames,
        *backend,
        *args,
    ]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdin=subprocess.DEVNULL)
    svc = ServiceProcess(proc, control, frames, ports)
    try:
        hello = {"v": 1, "type": "hello", "id": 0, "versions": [1]}
        ok = wait_until(
            lambda: proc.poll() is not None or _is_ready(raw_request(control, hello, (), 500)),
            ready_timeout_s,
        )
        if not ok or proc.poll() is not None:
            raise RuntimeError(f"holo-service did not start (rc {proc.poll()})")
    except BaseException:
        svc.stop()
        raise
    return svc
