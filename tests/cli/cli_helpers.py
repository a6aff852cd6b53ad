"""Helpers of the command-line tests: child processes whose lines are collected.

A module of its own (not ``conftest``) so test files import it by a name no other
test folder uses.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
posix_only = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals and ptys")
linux_only = pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="/proc")


def wait_for(pred: Callable[[], bool], timeout: float = 20.0, what: str = "condition") -> None:
    """Wait on a condition (polling every few ms); fail after ``timeout``."""
    deadline = time.monotonic() + timeout
    tick = threading.Event()
    while not pred():
        if time.monotonic() > deadline:
            raise AssertionError(f"{what} not met within {timeout} s")
        tick.wait(0.01)


def catches(pid: int, signum: int) -> bool:
    """True once process ``pid`` has a handler for ``signum`` (Linux ``SigCgt`` mask)."""
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    mask = next(int(ln.split()[1], 16) for ln in text.splitlines() if ln.startswith("SigCgt"))
    return bool(mask >> (signum - 1) & 1)


def children_of(pid: int) -> set[int]:
    """The process ids of ``pid``'s children (Linux)."""
    out: set[int] = set()
    for task in Path(f"/proc/{pid}/task").iterdir():
        text = (task / "children").read_text().split()
        out.update(int(t) for t in text)
    return out


def alive(pid: int) -> bool:
    """True while ``pid`` exists and is not a zombie."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


class Proc:
    """``python -m MODULE ARGS`` with its stdout / stderr lines collected by threads.

    Parameters
    ----------
    args : str
        The module and its arguments.
    stdout : file descriptor, optional
        Where stdout goes instead of a pipe (a pty's slave side).
    """

    def __init__(self, *args: str, stdout: int | None = None) -> None:
        self.p = subprocess.Popen([sys.executable, "-m", *args], cwd=ROOT, text=True,
                                  stdout=subprocess.PIPE if stdout is None else stdout,
                                  stderr=subprocess.PIPE, stdin=subprocess.DEVNULL)
        self.out: list[str] = []
        self.err: list[str] = []
        streams = [(self.p.stderr, self.err)]
        if stdout is None:
            streams.append((self.p.stdout, self.out))
        self._threads = [threading.Thread(target=self._pump, args=s, daemon=True)
                         for s in streams]
        for t in self._threads:
            t.start()

    @staticmethod
    def _pump(stream, lines: list[str]) -> None:
        for line in stream:
            lines.append(line.rstrip("\n"))

    def wait_lines(self, pred: Callable[[], bool], timeout: float = 30.0) -> None:
        """Wait until ``pred()``; fail (with the last stderr lines) if the process ends."""
        deadline = time.monotonic() + timeout
        tick = threading.Event()
        while not pred():
            if time.monotonic() > deadline or self.p.poll() is not None:
                if pred():
                    return
                raise AssertionError(f"condition not met; rc={self.p.poll()}, "
                                     f"stderr={self.err[-8:]}")
            tick.wait(0.01)

    def signal(self, signum: int) -> None:
        """Send ``signum`` to the process."""
        self.p.send_signal(signum)

    def finish(self, timeout: float = 30.0) -> int:
        """Wait for the exit status; the output threads have finished after it."""
        rc = self.p.wait(timeout)
        for t in self._threads:
            t.join(timeout)
        return rc

    def kill(self) -> None:
        """Kill it if it still runs."""
        if self.p.poll() is None:
            self.p.kill()
            self.p.wait(10)


SIGNALS = pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM],
                                  ids=["SIGINT", "SIGTERM"])


#: The rule of service.signals: the exit status after a clean stop on each signal.
STATUS = {signal.SIGINT: 130, signal.SIGTERM: 143}
