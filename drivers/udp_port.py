"""A UDP listener that a :class:`~drivers.reader.DeviceReader` reads like a port.

``opentrack-udp://HOST:PORT`` (port optional: opentrack's 4242) binds a UDP socket
on ``HOST:PORT`` and receives opentrack's pose datagrams; :func:`open_port` is the
readers' opener: it opens such URLs here and every other one with pyserial
(:func:`serial.serial_for_url`), so one reader code path serves serial devices and
opentrack alike.  ``HOST`` ``0.0.0.0`` listens on every interface (opentrack on
another computer), ``127.0.0.1`` on this one only.

:meth:`UdpPort.read_datagram` waits (``select``, at most the read timeout) and
returns **one** datagram, so the decoder sees datagram boundaries.  The socket is
not shared (no ``SO_REUSEADDR``): a second listener on a port in use fails to open,
as a serial port in use does.  Closing and binding again (the reader's watchdog
reopen) needs nothing else: UDP leaves no ``TIME_WAIT``.
"""

from __future__ import annotations

import select
import socket
from typing import Any
from urllib.parse import urlsplit

import serial

from drivers.protocols.opentrack import DEFAULT_PORT, URL_SCHEME
from service.base.errors import SettingsError

#: Largest datagram read (anything longer is cut to this and then counted as the wrong size).
MAX_DATAGRAM = 65536


def is_udp_url(url: str) -> bool:
    """True for an ``opentrack-udp://`` URL."""
    return url.lower().startswith(URL_SCHEME + "://")


def parse_udp_url(url: str) -> tuple[str, int]:
    """``(host, port)`` of ``opentrack-udp://HOST[:PORT]``.

    Raises
    ------
    SettingsError
        Not that scheme, no host, or a port outside 1-65535.
    """
    if not is_udp_url(url):
        raise SettingsError(f"{url!r} is not an {URL_SCHEME}://HOST:PORT URL")
    parts = urlsplit(url)
    try:
        port = parts.port
    except ValueError:
        port = -1
    if port is None and not parts.netloc.endswith(":"):
        port = DEFAULT_PORT
    if not parts.hostname or port is None or not 1 <= port <= 65535 or parts.path not in ("", "/"):
        raise SettingsError(f"{url!r}: give {URL_SCHEME}://HOST:PORT with a port in 1-65535, "
                            f"e.g. {URL_SCHEME}://127.0.0.1:{DEFAULT_PORT}")
    return parts.hostname, port


class UdpPort:
    """A bound UDP socket with the few port methods a reader uses.

    Parameters
    ----------
    url : str
        ``opentrack-udp://HOST[:PORT]``.
    timeout : float
        Longest wait of :meth:`read_datagram`, seconds.

    Raises
    ------
    serial.SerialException
        The address cannot be bound (in use, not this machine's); the reader
        reports it as ``open_failed`` and retries, as for a serial port.
    """

    def __init__(self, url: str, timeout: float = 0.05, **_serial: Any) -> None:
        host, port = parse_udp_url(url)
        self.url = url
        self.timeout = timeout
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self._sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            self._sock.bind((host, port))
        except OSError as exc:
            self._sock.close()
            raise serial.SerialException(f"cannot listen on UDP {host}:{port}: {exc}") from exc
        self._sock.setblocking(False)

    @property
    def address(self) -> tuple[str, int]:
        """The bound ``(host, port)``."""
        return self._sock.getsockname()[:2]

    def read_datagram(self, timeout_s: float | None = None) -> bytes:
        """Wait up to ``timeout_s`` (default the port's timeout); one datagram or ``b""``."""
        wait = self.timeout if timeout_s is None else timeout_s
        ready, _, _ = select.select((self._sock,), (), (), wait)
        if not ready:
            return b""
        try:
            return self._sock.recv(MAX_DATAGRAM)
        except BlockingIOError:
            return b""

    def write(self, data: bytes) -> int:
        """Always refused: opentrack's UDP output takes no commands."""
        raise serial.SerialException("an opentrack UDP listener takes no host commands")

    def flush(self) -> None:
        """Nothing is buffered."""

    def close(self) -> None:
        """Close the socket (idempotent)."""
        self._sock.close()


class UdpSender:
    """The other end: every :meth:`write` one datagram to ``opentrack-udp://HOST:PORT``.

    What ``holo-replay --to-port opentrack-udp://...`` writes a recorded opentrack
    session's datagrams into (one record, one datagram, as they were received).
    """

    def __init__(self, url: str) -> None:
        host, port = parse_udp_url(url)
        self.url = url
        self._to = (host, port)
        self._sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET,
                                   socket.SOCK_DGRAM)

    def write(self, data: bytes) -> int:
        """Send ``data`` as one datagram (a failed send is lost, as UDP is)."""
        try:
            return self._sock.sendto(data, self._to)
        except OSError:
            return 0

    def flush(self) -> None:
        """Nothing is buffered."""

    def close(self) -> None:
        """Close the socket."""
        self._sock.close()


def open_port(url: str, **kwargs: Any) -> Any:
    """The readers' opener: :class:`UdpPort` for ``opentrack-udp://``, else pyserial's."""
    if is_udp_url(url):
        return UdpPort(url, **kwargs)
    return serial.serial_for_url(url, **kwargs)
