"""A worker starved of the CPU is not taken for dead; a stopped one still is.

On a machine busy with other programs a worker's heartbeat waits behind its render (a
compiled kernel holds the GIL) and behind the CPU.  The broker asks
:class:`~service.net.supervisor.CpuWatch` about a local worker silent past its limit:
one whose process used CPU since it was last heard from gets another window, one
stopped (SIGSTOP) or idle-hung is dead.  Real processes, a real broker on 127.0.0.1;
every wait is on a condition with a timeout.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import zmq
from testkit import HANG_S, wait_until

from service.net.broker import Broker
from service.net.supervisor import CpuWatch

#: a worker that says READY with a 0.1 s heartbeat, then on its job goes silent and
#: spins the CPU for argv[2] seconds (a render that holds the GIL), then answers
SPINNER = """
import json, os, sys, time, zmq
sock = zmq.Context().socket(zmq.DEALER)
sock.connect(sys.argv[1])
sock.send_multipart([b"", b"READY", json.dumps({"pid": os.getpid(), "heartbeat_s": 0.1}).encode()])
frames = sock.recv_multipart()
print("job", flush=True)
end = time.process_time() + float(sys.argv[2])
while time.process_time() < end:
    pass
sock.send_multipart([b"", *frames[1:], b"done"])
sock.recv_multipart()
"""

SPIN = "while True:\n    pass\n"
IDLE = "import sys\nprint('up', flush=True)\nsys.stdin.read()\n"


def _child(code: str, *args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", code, *args], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)


def _end(proc: subprocess.Popen) -> None:
    proc.kill()
    proc.wait(HANG_S)


def test_the_watch_tells_a_working_process_from_a_stopped_or_idle_one():
    busy, idle = _child(SPIN), _child(IDLE)
    watch = CpuWatch(lambda: [busy.pid, idle.pid])
    try:
        assert idle.stdout.readline() == "up\n"  # its start-up's CPU is behind it
        for p in (busy, idle):
            watch.mark(p.pid)
        assert wait_until(lambda: watch.working(busy.pid), HANG_S)
        assert not watch.working(idle.pid)  # alive, but no CPU since its mark
        os.kill(busy.pid, signal.SIGSTOP)
        assert wait_until(lambda: not watch.working(busy.pid), HANG_S)
        assert not watch.working(busy.pid)  # stopped: never working
        os.kill(busy.pid, signal.SIGCONT)
        assert not CpuWatch(lambda: []).working(busy.pid)  # not ours: never working
    finally:
        _end(busy)
        _end(idle)


def _job(b: Broker, front: zmq.Socket, spin_s: float) -> subprocess.Popen:
    pids: list[int] = []
    b.watch = CpuWatch(lambda: pids)  # as the service does: before any worker starts
    worker = _child(SPINNER, b.backend_address, str(spin_s))
    pids.append(worker.pid)
    assert wait_until(lambda: b.idle() == 1, HANG_S), "the worker never said READY"
    front.send_multipart([b"", json.dumps({"job": 1}).encode()])
    assert worker.stdout.readline() == "job\n"
    return worker


def test_a_silent_worker_that_works_is_not_dead_and_answers(broker):
    b, front = broker
    worker = _job(b, front, 1.5)  # 15 heartbeats of silence while it computes
    try:
        assert front.poll(HANG_S * 1000), "the job was never answered"
        reply = front.recv_multipart()
        assert reply[-1] == b"done" and not reply[-1].startswith(b"{")  # not a lost notice
        assert b.take_deaths() == [] and b.starved >= 1 and b.lost == 0
    finally:
        _end(worker)


def test_a_stopped_worker_is_dead_within_its_silence_limit(broker):
    b, front = broker
    worker = _job(b, front, 30.0)
    try:
        os.kill(worker.pid, signal.SIGSTOP)
        assert wait_until(lambda: b.lost == 1, HANG_S), "the stopped worker was never dead"
        deaths = b.take_deaths()
        assert [pid for pid, _ in deaths] == [worker.pid] and "silent" in deaths[0][1]
    finally:
        _end(worker)
