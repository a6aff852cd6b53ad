"""Where a simulated device's bytes go, and the loop that sends them.

Links (all offer ``name``, ``write``, ``read_available``, ``disconnect``,
``reconnect``, ``close``):

* :class:`LoopLink` - a pyserial ``loop://`` port for in-process tests.  What the
  device writes, a reader of ``link.port`` gets; it is one-way (host commands
  cannot be told apart from the device's own bytes, so none are read).
* :class:`~drivers.pty_link.PtyLink` - a pseudo-terminal pair; it lives in ``drivers``
  because ``holo-replay --pty`` uses it too.
* :class:`TcpLink` - a TCP server on 127.0.0.1 only; clients open
  ``socket://127.0.0.1:PORT``.  A disconnect closes the client connection and a
  reconnect waits for the next client.
* :class:`UdpLink` - opentrack's "UDP over network" output: every write is one
  datagram to ``HOST:PORT``, where a client listens on
  ``opentrack-udp://HOST:PORT``.  A disconnect is a sender that stops (nothing is
  sent until the reconnect); there is no client to wait for and no host bytes.

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
import select
import socket
import threading
import time
from collections.abc import Callable, Iterator
from typing import Protocol

import serial

from drivers.protocols.opentrack import URL_SCHEME
from service.base.errors import DeviceError, SettingsError
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


class UdpLink:
    """Sends every write as one UDP datagram to ``(host, port)`` (see module docstring)."""

    def __init__(self, host: str, port: int) -> None:
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self._sock = socket.socket(family, socket.SOCK_DGRAM)
        self.target = (host, port)
        self.name = f"{URL_SCHEME}://{f'[{host}]' if ':' in host else host}:{port}"
        self.sending = True

    def wait_client(self, stop: threading.Event | None = None) -> None:
        """Nobody to wait for: datagrams go out whether or not anyone listens."""

    def write(self, data: bytes) -> None:
        """Send ``data`` as one datagram (nothing while disconnected).

        Raises
        ------
        DeviceError
            The datagram could not be sent (no route, too large).
        """
        if not self.sending:
            return
        try:
            self._sock.sendto(data, self.target)
        except OSError as exc:
            raise DeviceError(f"cannot send to {self.name}: {exc}") from exc

    def read_available(self) -> bytes:
        """Nothing: opentrack's output receives nothing."""
        return b""

    def drain(self, timeout: float = 2.0) -> None:
        """Nothing is queued."""

    def disconnect(self) -> None:
        """The sender stops."""
        self.sending = False

    def reconnect(self, stop: threading.Event | None = None) -> None:
        """The sender goes on."""
        self.sending = True

    def close(self) -> None:
        """Close the socket."""
        self._sock.close()


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
