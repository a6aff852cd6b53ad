"""holo-service-worker: the remote render worker docs/service.md starts on other hosts."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest
import zmq
from testkit import ROOT, SIGNALS, STATUS, posix_only

from service.net.worker import READY


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "service.commands.holo_service_worker", *args],
                          cwd=ROOT,
                          text=True, capture_output=True, timeout=60)


@pytest.mark.parametrize(("argv", "words"), [
    (["--connect", "tcp://127.0.0.1:99999"], "is not a port number"),
    (["--connect", "nonsense"], "is not a ZeroMQ address"),
    (["--curve-keys", "/no/such/keys"], "no server.key or client.key_secret"),
    (["--nice", "-1"], "--nice"),
])
def test_bad_settings_are_one_line_and_status_2(argv, words):
    """Before: a traceback (zmq's 'Invalid argument', 'Invalid certificate file') or port
    99999 taken as 34463."""
    proc = _run(*argv)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("holo-service-worker: ") and words in last, proc.stderr


@posix_only
@SIGNALS
def test_it_says_where_it_connects_and_stops_with_the_signal_status(signum):
    ctx = zmq.Context.instance()
    broker = ctx.socket(zmq.ROUTER)
    broker.setsockopt(zmq.LINGER, 0)
    port = broker.bind_to_random_port("tcp://127.0.0.1")
    p = subprocess.Popen([sys.executable, "-m", "service.commands.holo_service_worker", "--connect",
                          f"tcp://127.0.0.1:{port}", "--nice", "0"], cwd=ROOT, text=True,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        assert broker.poll(60_000), "no READY from the worker"
        assert READY in broker.recv_multipart()
        p.send_signal(signum)
        _, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait(10)
        broker.close(0)
    assert p.returncode == STATUS[signum], err
    lines = err.strip().splitlines()
    assert lines[0].startswith(f"holo-service-worker: taking jobs from tcp://127.0.0.1:{port}")
    name = signal.Signals(signum).name
    assert lines[-1] == f"holo-service-worker: stopped ({name}) after 0 jobs", err
    assert "Traceback" not in err
