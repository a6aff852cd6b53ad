"""A fork server for render workers: a restart costs a fork, not a fresh interpreter.

A worker started as ``python -m service.net.worker`` spends about 0.6 CPU s before it
does anything: the interpreter, numpy, numba, pyzmq and the render pipeline's
modules.  The **template** (``python -m service.net.forkserver FD``, one per
service) pays that once; each worker is then ``os.fork()`` of it, running
:func:`service.net.worker.main` in the child.  The child still loads its kernels
(``--warm-up``, about 0.26 CPU s with a warm cache) and makes its own ZeroMQ
context: the template never loads a kernel, runs a thread or makes a context, so
the fork copies no lock held by another thread and no socket (GNU OpenMP, numba's
threading layer here, is not fork-safe once a parallel kernel has been loaded:
numba ends such a child with "fork() called from a process already using GNU
OpenMP").

The pipe protocol is lines of text.  The service writes to the template's stdin::

    spawn ["--connect", "tcp://127.0.0.1:5557", "--warm-up"]

and reads on the pipe ``FD``::

    ready                 the template is up (its modules imported)
    pid 4242              the child the last ``spawn`` started
    exit 4242 -9          a child ended: its return code as subprocess gives it

Each child leads a process group of its own and gets ``--parent`` the template's
pid (it exits when the template is gone); the template exits at EOF on stdin.
:class:`ForkServer` is the service's end; :class:`ForkedProc` stands for one child
with the part of :class:`subprocess.Popen` the supervisor uses.
"""

from __future__ import annotations

import contextlib
import json
import os
import select
import signal
import subprocess
import sys
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field

#: the command line whose worker the template forks (``sys.executable -m`` it)
WORKER_MODULE = "service.net.worker"
#: seconds the template has to import its modules and say ``ready`` (a loaded 2-core
#: machine took 5 s; a worker started as a fresh process meanwhile would take as long)
READY_S = 60.0
#: seconds the template has to answer a ``spawn`` with the child's pid
SPAWN_S = 5.0
#: seconds the template gets to end after its stdin closes
CLOSE_S = 3.0


@dataclass
class ForkedProc:
    """A child of the template: ``pid``, ``returncode``, ``poll()`` and ``wait()``."""

    pid: int
    server: ForkServer
    returncode: int | None = None

    def poll(self) -> int | None:
        """The return code once the template reported the child's end, else None."""
        self.server.pump()
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        """Wait for the child's end; :class:`subprocess.TimeoutExpired` after ``timeout``."""
        end = None if timeout is None else time.monotonic() + timeout
        while self.poll() is None:
            left = None if end is None else end - time.monotonic()
            if left is not None and left <= 0:
                raise subprocess.TimeoutExpired(WORKER_MODULE, timeout or 0.0)
            self.server.pump(0.05 if left is None else min(0.05, left))
        return self.returncode


@dataclass
class ForkServer:
    """The service's end of the template: start it, ask it for workers, hear of their ends.

    Parameters
    ----------
    env : dict
        The workers' environment (the template's, which its children inherit).
    log : callable
        One line of text if the template fails (the supervisor then starts workers
        with :class:`subprocess.Popen`).
    """

    env: dict[str, str]
    log: Callable[[str], None] = lambda line: None
    #: seconds the template has to say ``ready`` before it is given up
    ready_s: float = READY_S
    proc: subprocess.Popen | None = None
    #: "starting" (importing), "ready", or "gone" (ended, or broken: not used again)
    state: str = "starting"
    children: dict[int, ForkedProc] = field(default_factory=dict)
    #: :meth:`close` was called (the template's end is not news)
    closed: bool = False
    _started_at: float = 0.0
    _fd: int = -1
    _buf: bytes = b""
    _pids: list[int] = field(default_factory=list)
    #: return codes of children reported ended before :meth:`spawn` took their pid
    _ended: dict[int, int] = field(default_factory=dict)
    _lock: threading.RLock = field(default_factory=threading.RLock)

    def start(self) -> None:
        """Start the template (it imports the worker's modules, then says ``ready``)."""
        r, w = os.pipe()
        self._started_at = time.monotonic()
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "service.net.forkserver", str(w)],
                stdin=subprocess.PIPE, env=self.env, pass_fds=(w,), process_group=0,
            )
        except OSError as exc:
            os.close(r)
            self._gone(f"fork server did not start: {exc}")
        finally:
            os.close(w)
        if self.proc is not None:
            os.set_blocking(r, False)
            self._fd = r

    def pump(self, timeout_s: float = 0.0) -> None:
        """Read what the template said (waiting up to ``timeout_s`` for something)."""
        with self._lock:
            if self._fd < 0:
                return
            if timeout_s > 0:
                select.select([self._fd], [], [], timeout_s)
            while True:
                try:
                    data = os.read(self._fd, 65536)
                except BlockingIOError:
                    break
                if not data:
                    self._gone("fork server ended")
                    return
                self._buf += data
            *lines, self._buf = self._buf.split(b"\n")
            for line in lines:
                self._heard(line.decode().split())

    def wait_ready(self) -> str:
        """Wait until the template is ready or gone (at most :attr:`ready_s`); its state."""
        end = self._started_at + self.ready_s
        while self.state == "starting" and time.monotonic() < end:
            self.pump(min(0.05, max(0.0, end - time.monotonic())))
        return self.state

    def _heard(self, words: list[str]) -> None:
        if words == ["ready"] and self.state == "starting":
            self.state = "ready"
        elif len(words) == 2 and words[0] == "pid":
            self._pids.append(int(words[1]))
        elif len(words) == 3 and words[0] == "exit":
            child = self.children.pop(int(words[1]), None)
            if child is None:
                self._ended[int(words[1])] = int(words[2])
            else:
                child.returncode = int(words[2])

    def spawn(self, command: list[str]) -> ForkedProc | None:
        """A forked worker running ``command``'s arguments, or None.

        None while the template is still starting (ask again later) or once it is
        gone (:attr:`state`; start the worker another way).
        """
        with self._lock:
            self.pump()
            if self.state == "starting" and time.monotonic() - self._started_at > self.ready_s:
                self._gone(f"fork server not ready {self.ready_s:g} s after it started")
            if self.state != "ready" or self.proc is None or self.proc.stdin is None:
                return None
            try:
                self.proc.stdin.write(f"spawn {json.dumps(_worker_args(command))}\n".encode())
                self.proc.stdin.flush()
            except OSError as exc:
                self._gone(f"fork server unreachable: {exc}")
                return None
            end = time.monotonic() + SPAWN_S
            while not self._pids and self.state == "ready" and time.monotonic() < end:
                self.pump(min(0.05, max(0.0, end - time.monotonic())))
            if not self._pids:
                self._gone(f"fork server gave no pid in {SPAWN_S:g} s")
                return None
            pid = self._pids.pop(0)
            child = ForkedProc(pid, self, self._ended.pop(pid, None))
            if child.returncode is None:
                self.children[pid] = child
            return child

    def _gone(self, why: str) -> None:
        """The template ended or broke: end its children (their ends go unreported)."""
        if self.state != "gone" and not self.closed:
            self.log(f"{why}; workers start as fresh processes from now on")
        self.state = "gone"
        for child in self.children.values():
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(child.pid, signal.SIGKILL)
            child.returncode = -signal.SIGKILL
        self.children.clear()
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1
        if self.proc is not None and self.proc.poll() is None:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(self.proc.pid, signal.SIGKILL)

    def close(self, timeout_s: float = CLOSE_S) -> None:
        """End the template (EOF on its stdin; SIGKILL after ``timeout_s``)."""
        with self._lock:
            self.closed = True
            if self.proc is None:
                return
            with contextlib.suppress(OSError):
                self.proc.stdin.close()
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                pass
            self._gone("fork server closed")
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.proc.wait(1.0)


def _worker_args(command: list[str]) -> list[str]:
    """``[python, -m, service.net.worker, *args]`` -> ``args`` (ValueError for another)."""
    if command[1:3] != ["-m", WORKER_MODULE]:
        raise ValueError(f"the fork server starts only {WORKER_MODULE}, not {command!r}")
    return command[3:]


# ------------------------------------------------------------------ the template
def _child(args: list[str], closing: list[int]) -> None:
    """In the forked child: leave the template's pipes and signals, run the worker."""
    code = 1
    try:
        os.setpgid(0, 0)
        signal.set_wakeup_fd(-1)
        signal.signal(signal.SIGCHLD, signal.SIG_DFL)
        for fd in closing:
            os.close(fd)
        null = os.open(os.devnull, os.O_RDONLY)
        os.dup2(null, 0)
        os.close(null)
        # deferred: the template imported it already; the service's end never needs it
        from service.net import worker

        code = worker.main([*args, "--parent", str(os.getppid())])
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    except BaseException:  # noqa: BLE001 - report it the way a worker process would
        traceback.print_exc()
    finally:
        with contextlib.suppress(Exception):
            sys.stdout.flush()
            sys.stderr.flush()
        os._exit(code)


def _fork(args: list[str], closing: list[int]) -> int:
    """Fork a worker; the parent makes it a group leader too (no race with a kill)."""
    if threading.active_count() != 1:
        raise RuntimeError("the fork server has a thread: it must not fork")
    pid = os.fork()
    if pid == 0:
        _child(args, closing)
    with contextlib.suppress(OSError):
        os.setpgid(pid, pid)
    return pid


def _reap(out: int) -> None:
    """Report every ended child."""
    while True:
        try:
            pid, status = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            return
        os.write(out, f"exit {pid} {os.waitstatus_to_exitcode(status)}\n".encode())


def serve(out: int) -> None:
    """The template's loop: fork on ``spawn``, report ends, return at EOF on stdin."""
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # as service.net.worker.main
    # deferred: after the OpenMP setting, and only in the template (not the service)
    import service.net.worker  # noqa: F401 - the imports each child no longer pays

    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_r, False)
    os.set_blocking(wake_w, False)
    signal.signal(signal.SIGCHLD, lambda *_: None)
    signal.set_wakeup_fd(wake_w)
    closing = [out, wake_r, wake_w]
    os.write(out, b"ready\n")
    buf = b""
    while True:
        readable, _, _ = select.select([0, wake_r], [], [])
        if wake_r in readable:
            with contextlib.suppress(BlockingIOError):
                os.read(wake_r, 4096)
            _reap(out)
        if 0 not in readable:
            continue
        data = os.read(0, 65536)
        if not data:
            return
        *lines, buf = (buf + data).split(b"\n")
        for line in lines:
            if line.startswith(b"spawn "):
                pid = _fork(json.loads(line[6:]), closing)
                os.write(out, f"pid {pid}\n".encode())


if __name__ == "__main__":
    serve(int(sys.argv[1]))
