"""The supervisor against real processes: a worker hung before ``READY`` is killed, one
that dies right after ``READY`` again and again is restarted with a back-off, and one
killed from outside before ``READY`` is no failed start.

The broker is real (ZeroMQ on 127.0.0.1, on its own thread); the workers are real
processes: one that never connects (hung at start-up) and one that says ``READY`` the
way ``service.net.worker`` does and exits on the first job the broker hands it (a
worker that crashes on every job).  Every wait is on a condition with a timeout.
"""

from __future__ import annotations

import os
import signal
import sys
import threading

import pytest
import zmq
from testkit import HANG_S, alive, wait_until

from service.net.broker import Broker
from service.net.supervisor import MAX_FAILED_STARTS, Supervisor

#: a worker that says READY (as service/net/worker.py does) and dies on its first job
CRASHER = """
import json, os, sys, zmq
sock = zmq.Context().socket(zmq.DEALER)
sock.connect(sys.argv[1])
sock.send_multipart([b"", b"READY", json.dumps({"pid": os.getpid(), "heartbeat_s": 60}).encode()])
sock.recv_multipart()  # a job
sys.exit(3)
"""


@pytest.fixture
def rig():
    """(make a supervisor for a worker command, its log lines)."""
    ctx = zmq.Context()
    broker = Broker(ctx, "tcp://127.0.0.1:*", "tcp://127.0.0.1:*")
    threads = [threading.Thread(target=broker.run, daemon=True)]
    threads[0].start()
    made: list[Supervisor] = []
    log: list[str] = []

    def make(command: list[str], **kw) -> Supervisor:
        sup = Supervisor(broker, command, dict(os.environ), log.append, **kw)
        made.append(sup)
        sup.start(1)
        threads.append(threading.Thread(target=sup.run, daemon=True))
        threads[-1].start()
        return sup

    try:
        yield make, log, broker
    finally:
        for sup in made:
            sup.close()
        broker.stop()
        for t in threads:
            t.join(5)
        ctx.term()


def test_a_worker_hung_before_ready_is_killed_and_started_again(rig):
    make, log, _ = rig
    sup = make([sys.executable, "-c", "import signal; signal.pause()"], startup_s=1.0)
    first = wait_until(lambda: sup.pids(), HANG_S)
    assert first, "the worker never started"
    assert wait_until(lambda: sup.deaths >= 1, HANG_S), log
    assert wait_until(lambda: not alive(first[0]), HANG_S), "the hung worker lives on"
    assert any("no READY 1 s after it started; killed" in line for line in log), log
    assert wait_until(lambda: sup.restarts >= 1, HANG_S), "it was not started again"


def test_a_worker_that_dies_on_every_job_is_restarted_with_a_back_off(rig):
    make, log, broker = rig
    sup = make([sys.executable, "-c", CRASHER, broker.backend_address])
    ctx = zmq.Context()
    requester = ctx.socket(zmq.DEALER)
    requester.connect(broker.front.getsockopt_string(zmq.LAST_ENDPOINT))
    try:
        for deaths in range(4):  # each worker, once READY, gets a job and dies of it
            assert wait_until(lambda: sup.slots[0].ready and not sup.slots[0].dead,
                              2 * HANG_S), log
            requester.send_multipart([b"", b"job"])
            assert wait_until(lambda n=deaths: sup.deaths > n, HANG_S), log
    finally:
        requester.close(0)
        ctx.term()
    waits = [line for line in log if "died within 10 s of starting work" in line]
    # the first quick death restarts at once; then 0.5 s, 1 s, 2 s ...
    assert waits and "restarting it in 0.5 s" in waits[0], log
    assert any("restarting it in 1 s" in line for line in waits), log
    assert sup.errors() == []  # never given up: renders go on in process meanwhile


def test_a_worker_killed_from_outside_before_ready_is_no_failed_start(rig):
    make, log, _ = rig
    sup = make([sys.executable, "-c", "import signal; signal.pause()"])  # never READY
    for kills in range(MAX_FAILED_STARTS + 1):
        pid = wait_until(lambda: (sup.pids() or [None])[0], HANG_S)
        assert pid, log
        os.kill(pid, signal.SIGKILL)  # an operator, the OOM killer, the chaos benchmark
        assert wait_until(lambda n=kills: sup.deaths > n, HANG_S), log
    assert sup.errors() == [] and sup.slots[0].failed_starts == 0, log
    assert not any("died at start-up" in line for line in log), log
    # killed again and again, soon after it started: restarted after a back-off
    assert any("restarting it in 0.5 s" in line for line in log), log
    assert wait_until(lambda: sup.restarts >= MAX_FAILED_STARTS + 1, HANG_S), log
