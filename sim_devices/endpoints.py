"""Where a simulated device's bytes go, and the loop that sends them.

Links (all offer ``name``, ``write``, ``read_available``, ``disconnect``,
``reconnect``, ``close``):

* :class:`LoopLink` - a pyserial ``loop://`` port for in-process tests.  What the
  device writes, a reader of ``link.port`` gets; it is one-way (host commands
  cannot be told apart from the device's own bytes, so none are read).
* :class:`PtyLink` - a pseudo-terminal pair (``os.openpty``); ``name`` is the slave
  device path another process opens with ``serial.serial_for_url(path)``.  A
  disconnect closes the pair and a reconnect makes a new one; pass ``symlink`` to
  get a stable path that is re-pointed at each new slave.
* :class:`TcpLink` - a TCP server on 127.0.0.1 only; clients open
  ``socket://127.0.0.1:PORT``.  A disconnect closes the client connection and a
  reconnect waits for the next client.

:class:`DeviceRunner` plays a device's ``frames()`` through a
:class:`~sim_devices.faults.FaultInjector` into a link, in real time or as fast as
possible, pacing writes to the baud rate (10 bits per byte, 8N1) unless ``pace`` is
off, and answers host commands (``device.receive``) between frames.  It waits while
``device.streaming`` is false (before the dial box's init handshake, after a
tracker's stop command).  A ``disconnect`` fault also power-cycles a device that
has ``power_cycle()`` (a tracker waiting for its start command waits again).
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import threading
import time
from collections.abc import Callable, Iterator
from typing import Protocol

import serial

from service.errors import DeviceError, SettingsError
from sim_devices.faults import Disconnect, FaultInjector, FaultLedger, FaultSpec, Pause, Write

POLL_S = 0.005
BITS_PER_BYTE = 10


class SimDevice(Protocol):
    """What the runner needs from a simulated device."""

    streaming: bool
    baud: int

    def frames(self, seconds: float | None = None) -> Iterator[tuple[float, Callable[[], bytes]]]:
        """``(t, make_bytes)`` to send, in time order."""
        ...

    def receive(self, data: bytes, t: float = 0.0) -> bytes:
        """Host bytes in; reply bytes out."""
        ...


class LoopLink:
    """A ``loop://`` port; read what the device sent from ``link.port``."""

    def __init__(self) -> None:
        self.port = serial.serial_for_url("loop://", timeout=0.05)
        self.name = "loop://"

    def write(self, data: bytes) -> None:
        """Queue bytes for the reader."""
        self.port.write(data)

    def wait_client(self, stop: threading.Event | None = None) -> None:
        """Nothing to wait for on a loop port."""

    def read_available(self) -> bytes:
        """Nothing: a loop port cannot carry host commands separately."""
        return b""

    def drain(self, timeout: float = 2.0) -> None:
        """Nothing to wait for (the reader holds the same port)."""

    def disconnect(self) -> None:
        """Nothing to drop on a loop port."""

    def reconnect(self, stop: threading.Event | None = None) -> None:
        """Nothing to restore on a loop port."""

    def close(self) -> None:
        """Close the port."""
        self.port.close()


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

    def drain(self, timeout: float = 10.0) -> None:
        """Wait (up to ``timeout``) until the client has read what was sent.

        Closing the pty discards what the client has not read yet, so a run that
        ends by itself waits for a slow reader (a loaded machine can leave one
        seconds behind); a run stopped through ``stop`` does not wait.
        """
        import fcntl
        import struct
        import termios

        deadline = time.monotonic() + timeout
        buf = bytearray(4)
        empty = 0  # the kernel moves pty data in the background: want 3 empty looks
        while (self._slave >= 0 and empty < 3 and time.monotonic() < deadline
               and not (self.stop is not None and self.stop.is_set())):
            fcntl.ioctl(self._slave, termios.FIONREAD, buf)
            empty = empty + 1 if struct.unpack("i", buf)[0] == 0 else 0
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


class TcpLink:
    """A one-client TCP server on 127.0.0.1 (``port=0`` picks a free port)."""

    def __init__(self, port: int = 0, accept_timeout: float = 30.0) -> None:
        self._server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self._server.bind(("127.0.0.1", port))
        except OSError as exc:
            self._server.close()
            raise DeviceError(f"cannot listen on 127.0.0.1:{port}: {exc}") from exc
        self._server.listen(1)
        self.port = self._server.getsockname()[1]
        self.name = f"socket://127.0.0.1:{self.port}"
        self.accept_timeout = accept_timeout
        self._conn: socket.socket | None = None

    def wait_client(self, stop: threading.Event | None = None) -> None:
        """Block until a client connects (or ``stop`` is set / the timeout passes)."""
        deadline = time.monotonic() + self.accept_timeout
        self._server.settimeout(POLL_S * 10)
        while self._conn is None:
            if (stop is not None and stop.is_set()) or time.monotonic() > deadline:
                raise DeviceError(f"no client connected to {self.name}")
            with contextlib.suppress(TimeoutError):
                self._conn, _ = self._server.accept()
        self._conn.setblocking(False)
        self._conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def _accept_pending(self) -> None:
        ready, _, _ = select.select([self._server], [], [], 0)
        if ready:
            self._conn, _ = self._server.accept()
            self._conn.setblocking(False)
            self._conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def write(self, data: bytes) -> None:
        """Send to the client (dropped if none is connected)."""
        if self._conn is None:
            return
        try:
            self._conn.setblocking(True)
            self._conn.sendall(data)
            self._conn.setblocking(False)
        except OSError:
            self.disconnect()

    def read_available(self) -> bytes:
        """Host bytes from the client (b"" if none); takes a waiting new client."""
        if self._conn is None:
            self._accept_pending()
            return b""
        try:
            data = self._conn.recv(4096)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:
            data = b""
        if not data:
            self.disconnect()
        return data

    def drain(self, timeout: float = 2.0) -> None:
        """Nothing to wait for: the kernel delivers sent bytes after a close."""

    def disconnect(self) -> None:
        """Close the client connection."""
        if self._conn is not None:
            with contextlib.suppress(OSError):
                self._conn.close()
            self._conn = None

    def reconnect(self, stop: threading.Event | None = None) -> None:
        """Wait for the next client."""
        self.wait_client(stop)

    def close(self) -> None:
        """Close the connection and the server."""
        self.disconnect()
        self._server.close()


class DeviceRunner:
    """Plays a device through faults into a link (see module docstring).

    Parameters
    ----------
    device : SimDevice
        Tracker or dial box simulator.
    link : LoopLink, PtyLink or TcpLink
        Where bytes go.
    faults : FaultSpec or None
        Faults to inject (seeded).
    seconds : float or None
        Stop after this much device time (None: when ``frames`` ends or on stop).
    realtime : bool
        Send each frame at its time (True) or as fast as possible (False).
    pace : bool
        Sleep ``10 * len / baud`` after each write.
    baud : int or None
        Rate to pace to (default: the device's own, e.g. 115200 or 9600).
    """

    def __init__(self, device: SimDevice, link: object, faults: FaultSpec | None = None,
                 seconds: float | None = None, realtime: bool = True,
                 pace: bool = True, baud: int | None = None) -> None:
        self.device = device
        self.link = link
        self.injector = FaultInjector(faults)
        self.seconds = seconds
        self.realtime = realtime
        self.pace = pace
        self.baud = baud or device.baud
        if self.baud <= 0:
            raise SettingsError("baud must be > 0")
        self.stop_event = threading.Event()
        self.done = threading.Event()
        self.bytes_sent = 0
        self._thread: threading.Thread | None = None
        self._offset = 0.0
        self._t0 = 0.0
        self._actions = {Write: self._write, Pause: self._pause, Disconnect: self._disconnect}

    @property
    def ledger(self) -> FaultLedger:
        """What the fault injector did so far."""
        return self.injector.ledger

    def run(self) -> FaultLedger:
        """Send everything (blocking); returns the fault ledger."""
        try:
            self.link.wait_client(self.stop_event)
            self._t0 = time.monotonic()
            for t, make in self.device.frames(self.seconds):
                if not self._wait_until(t):
                    break
                frame = make()
                if not frame:
                    continue
                for action in self.injector.apply(frame):
                    self._actions[type(action)](action)
        finally:
            self.done.set()
        return self.ledger

    def start(self) -> DeviceRunner:
        """Run in a daemon thread."""
        self._thread = threading.Thread(target=self.run, name="sim-device", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout: float = 5.0) -> None:
        """Ask the run to end and wait for it."""
        self.stop_event.set()
        if self._thread is not None:
            self._thread.join(timeout)

    def poll_host(self) -> None:
        """Hand host bytes to the device and send its reply."""
        data = self.link.read_available()
        if data:
            reply = self.device.receive(data, time.monotonic() - self._t0)
            if reply:
                self._write(Write(reply))

    def _wait_until(self, t: float) -> bool:
        while not self.stop_event.is_set():
            self.poll_host()
            if not self.device.streaming:
                before = time.monotonic()
                self.stop_event.wait(POLL_S)
                self._offset += time.monotonic() - before
                continue
            if not self.realtime:
                return True
            left = self._t0 + self._offset + t - time.monotonic()
            if left <= 0:
                return True
            self.stop_event.wait(min(left, POLL_S))
        return False

    def _write(self, action: Write) -> None:
        try:
            self.link.write(action.data)
        except DeviceError:
            return
        self.bytes_sent += len(action.data)
        if self.pace:
            self.stop_event.wait(BITS_PER_BYTE * len(action.data) / self.baud)

    def _pause(self, action: Pause) -> None:
        self.stop_event.wait(action.seconds)
        self._offset += action.seconds

    def _disconnect(self, action: Disconnect) -> None:
        self.link.disconnect()
        power_cycle = getattr(self.device, "power_cycle", None)
        if power_cycle is not None:  # unplugged: back in its power-on state
            power_cycle()
        self.stop_event.wait(action.seconds)
        self._offset += action.seconds
        if not self.stop_event.is_set():
            self.link.reconnect(self.stop_event)
