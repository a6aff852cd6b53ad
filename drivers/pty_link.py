"""A pseudo-terminal pair that stands in for a serial device's port.

:class:`PtyLink` opens a pty pair (``os.openpty``); its ``name`` is the slave side's
path, which another process opens as a serial port with
``serial.serial_for_url(path)``.  The simulated devices (``sim_devices``) write a
device's bytes into it, and ``holo-replay --pty`` replays a recorded session into
it, so it lives here, below both.  A disconnect closes the pair and a reconnect makes
a new one; pass ``symlink`` to get a stable path that is re-pointed at each new slave.
"""

from __future__ import annotations

import contextlib
import os
import select
import struct
import threading
import time

from service.base.errors import DeviceError

POLL_S = 0.005
#: How long :meth:`PtyLink.drain` waits at most for a reader to take what was sent.
DRAIN_TIMEOUT_S = 10.0


class PtyLink:
    """A pty pair; the device owns the master side, clients open ``name``.

    Parameters
    ----------
    symlink : str or None
        A path kept pointing at the current slave device (replaced atomically).
    stop : threading.Event or None
        When set, a write blocked on a full pty gives up (see :meth:`write`).
    """

    def __init__(self, symlink: str | None = None,
                 stop: threading.Event | None = None) -> None:
        self.symlink = symlink
        self.stop = stop
        self._master = self._slave = -1
        self.name = ""
        self._open()

    def _open(self) -> None:
        # deferred: POSIX only: the module still imports elsewhere
        import tty

        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.name = os.ttyname(self._slave)
        if self.symlink:
            tmp = f"{self.symlink}.tmp{os.getpid()}"
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
            os.symlink(self.name, tmp)
            os.replace(tmp, self.symlink)

    @property
    def path(self) -> str:
        """The path a client should open (the symlink if there is one)."""
        return self.symlink or self.name

    def write(self, data: bytes) -> None:
        """Write all of ``data`` (waits while the pty buffer is full).

        If ``stop`` is set while it waits (nobody reads the slave side), the rest of
        ``data`` is dropped so the program can exit.
        """
        view = memoryview(data)
        while view and not (self.stop is not None and self.stop.is_set()):
            try:
                n = os.write(self._master, view)
            except BlockingIOError:
                select.select([], [self._master], [], POLL_S)
                continue
            except OSError as exc:
                raise DeviceError(f"pty {self.name} write failed: {exc}") from exc
            view = view[n:]

    def wait_client(self, stop: threading.Event | None = None) -> None:
        """Nothing to wait for: bytes wait in the pty until a client opens it."""

    def read_available(self) -> bytes:
        """Host bytes waiting on the master side (b"" if none)."""
        try:
            return os.read(self._master, 4096)
        except (BlockingIOError, OSError):
            return b""

    def unread(self) -> bool:
        """True while the client has not read everything written to the master side.

        ``FIONREAD`` alone misses bytes in transit: the kernel moves what the master
        writes into the slave's input queue from a work queue, which runs late (most
        looks right after a write, and a loaded machine can hold them back for longer).
        Polling the slave for input first runs that pending work (Linux ``n_tty_poll``
        flushes the port's buffer before it answers), so the two looks together see
        every byte the client has not read yet.
        """
        # deferred: POSIX only: the module still imports elsewhere
        import fcntl
        import termios

        if self._slave < 0:
            return False
        if select.select([self._slave], [], [], 0)[0]:
            return True
        buf = bytearray(4)
        fcntl.ioctl(self._slave, termios.FIONREAD, buf)
        return struct.unpack("i", buf)[0] > 0

    def drain(self, timeout: float = DRAIN_TIMEOUT_S) -> None:
        """Wait (up to ``timeout``) until the client has read what was sent.

        Closing the pty discards what the client has not read yet, so a run that
        ends by itself waits for a slow reader (a loaded machine can leave one
        seconds behind); a run stopped through ``stop`` does not wait.
        """
        deadline = time.monotonic() + timeout
        while (self.unread() and time.monotonic() < deadline
               and not (self.stop is not None and self.stop.is_set())):
            select.select([], [], [], POLL_S)

    def disconnect(self) -> None:
        """Close both ends (a client sees the device vanish).

        The symlink goes first: while the device is away, a client retrying the link
        must not open whatever pty the kernel hands the recycled ``/dev/pts/N`` to.
        """
        if self.symlink:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.symlink)
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)
        self._master = self._slave = -1

    def reconnect(self, stop: threading.Event | None = None) -> None:
        """A new pty pair (new ``name``; the symlink follows)."""
        self._open()

    def close(self) -> None:
        """Close both ends and remove the symlink."""
        self.disconnect()
        if self.symlink:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.symlink)
