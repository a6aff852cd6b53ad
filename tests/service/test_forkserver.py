"""The fork server against real processes: workers forked from the template say
``READY`` to a real broker, their ends are reported with the code subprocess would
give, and nothing outlives the template's close or its death.

``service/net/forkserver.py``; ``docs/service.md``, "Supervised workers".
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
from service.net.forkserver import ForkServer


@pytest.fixture
def rig():
    """(a started fork server, a real broker, the server's log lines)."""
    ctx = zmq.Context()
    broker = Broker(ctx, "tcp://127.0.0.1:*", "tcp://127.0.0.1:*")
    thread = threading.Thread(target=broker.run, daemon=True)
    thread.start()
    log: list[str] = []
    forks = ForkServer(dict(os.environ), log.append)
    forks.start()
    try:
        yield forks, broker, log
    finally:
        forks.close()
        broker.stop()
        thread.join(5)
        ctx.term()


def _worker(broker: Broker, *extra: str) -> list[str]:
    return [sys.executable, "-m", "service.net.worker", "--connect", broker.backend_address,
            *extra]


def _state(forks: ForkServer) -> str:
    forks.pump()  # what the template said so far
    return forks.state


def _spawn(forks: ForkServer, command: list[str]):
    assert wait_until(lambda: _state(forks) == "ready", HANG_S), "the template never got ready"
    child = forks.spawn(command)
    assert child is not None, forks.state
    return child


def test_a_forked_worker_says_ready_and_its_kill_is_reported(rig):
    forks, broker, log = rig
    child = _spawn(forks, _worker(broker))
    assert wait_until(lambda: child.pid in {w["pid"] for w in broker.info()["workers"]},
                      HANG_S), "the forked worker never said READY"
    assert os.getpgid(child.pid) == child.pid  # its own group: the supervisor kills it
    assert child.poll() is None
    os.killpg(child.pid, signal.SIGKILL)
    assert child.wait(HANG_S) == -signal.SIGKILL
    assert not alive(child.pid)
    assert log == []


def test_a_forked_worker_failing_at_start_reports_its_exit_status(rig):
    forks, broker, _ = rig
    child = _spawn(forks, [sys.executable, "-m", "service.net.worker", "--connect", "bogus"])
    assert child.wait(HANG_S) == 1  # an invalid address: the worker's exception, status 1


def test_the_fork_server_starts_only_workers(rig):
    forks, _, _ = rig
    assert wait_until(lambda: _state(forks) == "ready", HANG_S)
    with pytest.raises(ValueError, match="starts only service.net.worker"):
        forks.spawn([sys.executable, "-c", "pass"])


def test_nothing_outlives_the_template(rig):
    forks, broker, log = rig
    first = _spawn(forks, _worker(broker))
    second = _spawn(forks, _worker(broker))
    assert wait_until(lambda: len(broker.info()["workers"]) == 2, HANG_S)
    os.kill(second.pid, signal.SIGSTOP)  # a stopped child cannot see its parent go
    template = forks.proc.pid
    os.kill(template, signal.SIGKILL)
    assert wait_until(lambda: _state(forks) == "gone", HANG_S), forks.state
    assert first.poll() == -signal.SIGKILL and second.poll() == -signal.SIGKILL
    assert wait_until(lambda: not alive(first.pid) and not alive(second.pid), HANG_S)
    assert any("fork server ended" in line for line in log), log
    assert forks.spawn(_worker(broker)) is None  # the supervisor then starts fresh processes
