"""Stop a command cleanly on SIGINT / SIGTERM without deadlocking its main thread.

A Python signal handler runs in the main thread between two bytecodes, possibly while
that thread is inside ``threading.Event.wait()`` and holds the event's internal lock.
A handler that calls ``event.set()`` then waits for a lock its own thread holds: the
process hangs until it is killed.  (``holo-replay --to-pty`` did exactly this on a
loaded CI machine.)

:func:`stop_on_signals` keeps the handler lock-free: it writes one byte into a pipe,
and a watcher thread reads the byte and sets the event from outside the handler.
:func:`end_process` ends a child process: terminate, then kill if it does not go.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import threading
from collections.abc import Iterator

__all__ = ["end_process", "stop_on_signals"]

_SIGNAL, _QUIT = b"s", b"q"


def _watch(read_fd: int, stop: threading.Event) -> None:
    while True:
        try:
            byte = os.read(read_fd, 1)
        except OSError:
            return
        if byte != _SIGNAL:  # b"q" from the context's exit, or b"" if the pipe closed
            return
        stop.set()


@contextlib.contextmanager
def stop_on_signals(
    stop: threading.Event, signals: tuple[int, ...] = (signal.SIGINT, signal.SIGTERM)
) -> Iterator[None]:
    """Within the block, each of ``signals`` sets ``stop``; the old handlers come back after.

    Parameters
    ----------
    stop : threading.Event
        Set (from a watcher thread, never from the handler itself) when a signal comes.
    signals : tuple of int
        The signals to catch (default SIGINT and SIGTERM).

    Outside the main thread, where handlers cannot be installed, it does nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)

    def handler(signum: int, frame: object) -> None:
        with contextlib.suppress(OSError):  # a full pipe already holds a pending stop
            os.write(write_fd, _SIGNAL)

    watcher = threading.Thread(target=_watch, args=(read_fd, stop), name="signal-watch",
                               daemon=True)
    watcher.start()
    old = {sig: signal.signal(sig, handler) for sig in signals}
    try:
        yield
    finally:
        for sig, previous in old.items():
            signal.signal(sig, previous)
        with contextlib.suppress(OSError):
            os.write(write_fd, _QUIT)
        watcher.join(2.0)
        os.close(write_fd)
        os.close(read_fd)


def end_process(p: subprocess.Popen, timeout: float = 5.0) -> None:
    """End child ``p``: SIGTERM, wait up to ``timeout`` s, then SIGKILL and wait again."""
    if p.poll() is None:
        p.terminate()
        try:
            p.wait(timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(timeout)
