"""The broker's job counts add up in every snapshot, read while jobs flow.

``info()`` runs on the service's thread while the broker's thread routes: each
dispatched job is busy on a worker, answered, or lost, at every instant, so the
chaos benchmark's ``unaccounted`` (dispatched - answered - lost - busy) is 0 in
any snapshot, not only once everything has settled.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading

import pytest
from testkit import HANG_S, wait_until

#: a worker that says READY and answers each job at once, until killed
ECHO = """
import json, os, sys, zmq
sock = zmq.Context().socket(zmq.DEALER)
sock.connect(sys.argv[1])
sock.send_multipart([b"", b"READY", json.dumps({"pid": os.getpid()}).encode()])
while True:
    frames = sock.recv_multipart()
    sock.send_multipart([b"", *frames[1:], b"done"])
"""

JOBS = 3000


@pytest.fixture
def flowing(broker):
    """The broker with two echo workers ready: ``(broker, front, workers)``."""
    b, front = broker
    workers = [subprocess.Popen([sys.executable, "-c", ECHO, b.backend_address])
               for _ in range(2)]
    try:
        assert wait_until(lambda: b.idle() == 2, HANG_S), "the workers never said READY"
        yield b, front, workers
    finally:
        for w in workers:
            w.kill()
            w.wait(HANG_S)


def _unaccounted(info: dict) -> int:
    return info["dispatched"] - info["answered"] - info["lost"] - info["busy"]


def test_every_snapshot_accounts_for_every_job(flowing):
    b, front, workers = flowing
    seen: list[int] = []
    done = threading.Event()

    def read() -> None:
        # a snapshot every 0.2 ms: a reader that never lets go of the GIL and the
        # broker's lock starves the broker's thread on an idle machine
        while not done.wait(0.0002):
            seen.append(_unaccounted(b.info()))

    reader = threading.Thread(target=read)
    reader.start()
    try:
        sent = answered = 0
        while answered < JOBS:
            while sent < JOBS and sent - answered < 4:
                front.send_multipart([b"", json.dumps({"job": sent}).encode()])
                sent += 1
            assert front.poll(HANG_S * 1000), "a job was never answered"
            front.recv_multipart()
            answered += 1
        workers[0].kill()  # a worker leaving the books while the reader reads
        b.forget(workers[0].pid)
        assert wait_until(lambda: b.live() == 1, HANG_S)
    finally:
        done.set()
        reader.join(HANG_S)
    info = b.info()
    assert info["dispatched"] == JOBS and info["answered"] == JOBS, info
    assert len(seen) > 100, "too few snapshots to tell"
    assert set(seen) == {0}, f"{sum(u != 0 for u in seen)} of {len(seen)} snapshots off"
