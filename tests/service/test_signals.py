"""stop_on_signals: SIGTERM stops a main thread that spends its life in Event.wait()."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from service.base.signals import stop_on_signals

ROOT = Path(__file__).resolve().parents[2]
posix_only = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")

# The main thread does nothing but short Event.wait() calls, so a signal nearly always
# lands while it holds the event's lock: a handler calling stop.set() would hang here.
CHILD = """
import signal, sys, threading
from service.base.signals import stop_on_signals
stop = threading.Event()
with stop_on_signals(stop):
    print("ready", flush=True)
    while not stop.wait(0.0005):
        pass
print("stopped", flush=True)
"""


@posix_only
@pytest.mark.parametrize("run", range(3))
def test_sigterm_stops_a_main_thread_waiting_on_the_event(run):
    proc = subprocess.Popen([sys.executable, "-c", CHILD], cwd=ROOT, stdout=subprocess.PIPE,
                            text=True)
    try:
        assert proc.stdout.readline().strip() == "ready"
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(10) == 0
        assert proc.stdout.read().strip() == "stopped"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
        proc.stdout.close()


def test_outside_the_main_thread_it_installs_nothing():
    before = signal.getsignal(signal.SIGTERM)
    seen = []

    def body():
        with stop_on_signals(threading.Event()):
            seen.append(signal.getsignal(signal.SIGTERM))

    t = threading.Thread(target=body)
    t.start()
    t.join(5)
    assert seen == [before]


def test_old_handlers_come_back_after_the_block():
    before = signal.getsignal(signal.SIGINT)
    with stop_on_signals(threading.Event()):
        assert signal.getsignal(signal.SIGINT) is not before
    assert signal.getsignal(signal.SIGINT) is before
