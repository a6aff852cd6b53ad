"""Stop a command cleanly on SIGINT / SIGTERM, and the one rule for its exit status.

**The rule** (every ``holo-*`` command): a command stopped by a signal first stops
cleanly (files flushed and closed, children ended, the terminal restored), then exits
with ``128 + the signal's number``, as a shell reports a command the signal killed:
**130** after Ctrl-C (SIGINT), **143** after SIGTERM.  Otherwise 0 when it did its
job, 1 when it ran but did nothing useful (each command's ``--help`` says when), 2 for
bad usage or settings (argparse's status).  :data:`EXIT_RULE` is that text for
``--help`` epilogs.

Two ways to be stopped, both here:

- A command whose main thread loops (readers, replays, simulators, viewers, the
  launcher) uses :func:`stop_on_signals`: the signal only sets an event, the loop
  ends, and the context's :class:`Received` gives the exit status.  The handler stays
  lock-free: a Python signal handler runs in the main thread between two bytecodes,
  possibly while that thread is inside ``threading.Event.wait()`` and holds the
  event's internal lock, so a handler calling ``event.set()`` could wait for a lock
  its own thread holds (``holo-replay --to-pty`` hung exactly so on a loaded CI
  machine).  The handler writes the signal's number into a pipe instead, and a
  watcher thread sets the event from outside the handler.
- A command that computes in its main thread (benchmarks, ``holo-render``) uses
  :func:`interruptible`: SIGINT and SIGTERM raise :class:`Interrupted` wherever the
  main thread is (``finally`` blocks run), and the command prints one line
  (``holo-bench: interrupted (SIGINT)``) instead of a traceback.

:func:`end_process` ends a child process: terminate, then kill if it does not go.
:func:`exit_now` ends a command whose work is on disk without the interpreter's
teardown.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import NoReturn, TextIO

__all__ = [
    "EXIT_FAILED",
    "EXIT_OK",
    "EXIT_RULE",
    "EXIT_USAGE",
    "Interrupted",
    "Received",
    "end_process",
    "exit_now",
    "exit_status",
    "interruptible",
    "raise_on_signals",
    "stop_on_signals",
]

#: The command did its job.
EXIT_OK = 0
#: The command ran but did nothing useful (no device opened, nothing decoded...).
EXIT_FAILED = 1
#: Bad usage or settings (argparse's own status).
EXIT_USAGE = 2
#: The signals every command stops on.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
#: The rule, for ``--help`` epilogs.
EXIT_RULE = ("Exit status: 0 done; 2 bad usage or settings; after a clean stop on Ctrl-C "
             "(SIGINT) 130, on SIGTERM 143 (128 + the signal's number).")

_QUIT = b"\x00"  # no signal has number 0: the context's exit


@dataclass
class Received:
    """The first stop signal a :func:`stop_on_signals` block received.

    Attributes
    ----------
    signum : int or None
        Its number, None while none came.
    """

    signum: int | None = None

    @property
    def name(self) -> str:
        """``"SIGINT"``, ``"SIGTERM"``..., or ``""`` when no signal came."""
        return "" if self.signum is None else signal.Signals(self.signum).name

    def exit_status(self, otherwise: int = EXIT_OK) -> int:
        """``128 + signum`` after a signal, else ``otherwise``."""
        return exit_status(self.signum, otherwise)


def exit_status(signum: int | None, otherwise: int = EXIT_OK) -> int:
    """The rule: ``128 + signum`` for a command a signal stopped, else ``otherwise``."""
    return otherwise if signum is None else 128 + int(signum)


def _watch(read_fd: int, stop: threading.Event, got: Received) -> None:
    while True:
        try:
            byte = os.read(read_fd, 1)
        except OSError:
            return
        if byte in (_QUIT, b""):  # the context's exit, or the pipe closed
            return
        if got.signum is None:
            got.signum = byte[0]
        stop.set()


@contextlib.contextmanager
def stop_on_signals(
    stop: threading.Event, signals: tuple[int, ...] = STOP_SIGNALS
) -> Iterator[Received]:
    """Within the block, each of ``signals`` sets ``stop``; the old handlers come back after.

    Parameters
    ----------
    stop : threading.Event
        Set (from a watcher thread, never from the handler itself) when a signal comes.
    signals : tuple of int
        The signals to catch (default SIGINT and SIGTERM).

    Yields
    ------
    Received
        Which signal came first; complete once the block has exited, so
        ``received.exit_status()`` after the block is the command's status.

    Outside the main thread, where handlers cannot be installed, it does nothing.
    """
    got = Received()
    if threading.current_thread() is not threading.main_thread():
        yield got
        return
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)

    def handler(signum: int, frame: object) -> None:
        with contextlib.suppress(OSError):  # a full pipe already holds a pending stop
            os.write(write_fd, bytes((signum,)))

    watcher = threading.Thread(target=_watch, args=(read_fd, stop, got), name="signal-watch",
                               daemon=True)
    watcher.start()
    old = {sig: signal.signal(sig, handler) for sig in signals}
    try:
        yield got
    finally:
        for sig, previous in old.items():
            signal.signal(sig, previous)
        with contextlib.suppress(OSError):
            os.write(write_fd, _QUIT)
        watcher.join(2.0)
        os.close(write_fd)
        os.close(read_fd)


class Interrupted(BaseException):  # noqa: N818 -- a stop, like KeyboardInterrupt
    """Raised in the main thread by :func:`raise_on_signals` when a stop signal comes.

    A ``BaseException`` like ``KeyboardInterrupt``, so ``except Exception`` clauses
    do not swallow it.

    Parameters
    ----------
    signum : int
    """

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


@contextlib.contextmanager
def raise_on_signals(signals: tuple[int, ...] = STOP_SIGNALS) -> Iterator[None]:
    """Within the block, each of ``signals`` raises :class:`Interrupted` in the main thread.

    For commands that compute in their main thread (no loop that could watch an
    event).  The old handlers come back after.  Outside the main thread it does nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: object) -> None:
        raise Interrupted(signum)

    old = {sig: signal.signal(sig, handler) for sig in signals}
    try:
        yield
    finally:
        for sig, previous in old.items():
            signal.signal(sig, previous)


def interruptible(prog: str, body: Callable[[], int], err: TextIO | None = None) -> int:
    """Run ``body()``; on SIGINT / SIGTERM write one line and return the rule's status.

    Parameters
    ----------
    prog : str
        The command's name, for the line ``PROG: interrupted (SIGINT)`` on ``err``.
    body : callable
        The command's work; returns its exit status.
    err : text stream, optional
        Where the line goes (default ``sys.stderr`` at the time of the call).

    Returns
    -------
    int
        ``body()``'s status, or 130 / 143 (128 + the signal's number).
    """
    try:
        with raise_on_signals():
            return body()
    except (Interrupted, KeyboardInterrupt) as exc:
        signum = exc.signum if isinstance(exc, Interrupted) else signal.SIGINT
    stream = err if err is not None else sys.stderr
    with contextlib.suppress(OSError, ValueError):  # a closed or broken stderr
        stream.write(f"{prog}: interrupted ({signal.Signals(signum).name})\n")
        stream.flush()
    return exit_status(signum)


def exit_now(status: int) -> NoReturn:
    """End this process now with ``status``, skipping the interpreter's teardown.

    For a command whose work is all on disk and whose children have ended when its
    ``main`` returns, and which holds many objects: the teardown collects and frees
    each of them, which took 1-2.4 s after a cold ``holo-warmup`` (in each of its two
    processes, most of it in the garbage collector) for nothing the user keeps.
    stdout and stderr are flushed first; ``atexit`` handlers and ``weakref``
    finalizers do not run, so a command that relies on one must not end here.
    """
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(AttributeError, OSError, ValueError):  # closed or broken
            stream.flush()
    os._exit(status)


def end_process(p: subprocess.Popen, timeout: float = 5.0) -> None:
    """End child ``p``: SIGTERM, wait up to ``timeout`` s, then SIGKILL and wait again."""
    if p.poll() is None:
        p.terminate()
        try:
            p.wait(timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(timeout)


#: Linux ``prctl`` option: the signal this process gets when its parent thread ends.
PR_SET_PDEATHSIG = 1


def end_with_parent(parent: int, signum: int) -> bool:
    """Get ``signum`` when the parent ends (Linux ``PR_SET_PDEATHSIG``); False elsewhere.

    For helper processes (the warm-up's second process, a level-of-detail build)
    that must not run on after the process that started them is killed outright.

    Parameters
    ----------
    parent : int
        The parent's pid as the caller knew it: if the parent went before the
        setting took, this process exits at once (``SystemExit(1)``).
    signum : int
        The signal to get: SIGKILL where nothing needs cleaning up, else SIGTERM.
    """
    try:
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signum)
    except (OSError, AttributeError):
        return False
    if os.getppid() != parent:  # it went before the prctl took
        raise SystemExit(1)
    return True
