"""Serial device readers: one thread per device, receive times, statistics, watchdog.

Shape (after python-can's bus / notifier): a :class:`DeviceReader` owns one port
and one decoder and runs on its own daemon thread; everything it produces goes to a
``sink(item, events)`` callable, usually :meth:`EventHub.put`, and one consumer
thread drains the hub into listeners (recorder, publisher, ``--dump``), so no
listener ever needs a lock.

What a reader does:

* opens its port by pyserial URL (:func:`serial.serial_for_url`: ``/dev/ttyUSB0``,
  ``loop://``, ``socket://host:port``, ``rfc2217://...``) with a short read timeout,
  or, for ``opentrack-udp://HOST:PORT``, binds a UDP socket there
  (:mod:`drivers.udp_port`) and reads it one datagram per chunk;
* waits for bytes without a fixed sleep and never longer than ``poll_s``: a port with
  a file descriptor (a tty, a pty: pyserial's POSIX ports) is waited on with
  :func:`select.select` and read with one :func:`os.read` of up to
  :data:`MAX_CHUNK` bytes; any other port (``loop://``, ``socket://``, Windows) with
  a one-byte read under the port's timeout, then whatever is already waiting.  The
  chunk is stamped with :func:`time.monotonic_ns` the moment the first read returned
  bytes;
* feeds the chunk to the decoder (:class:`DeviceStream`) and hands the chunk (for
  the recorder) and its events (for everyone else) to the sink at once, on the
  reader thread (:meth:`drivers.publisher.Publisher.sink` publishes there, before
  queueing the item for the slower listeners);
* keeps statistics (:meth:`DeviceReader.stats`): the decoder's counters (frames,
  bytes discarded, resyncs, counter gaps, CRC errors...) and its own (chunks,
  opens, reconnects, disconnects, watchdog trips, open failures);
* watchdog: no valid frame for ``watchdog_s`` seconds (or a read error: a device
  unplugged, a pty hung up) closes the port and reopens it with exponential backoff
  (``backoff_s`` doubling up to ``backoff_max_s``; reset by the next valid frame), so
  a device unplugged and plugged back in resumes without restarting the program;
  each failed open is told to ``on_retry`` (:class:`Retry`: the try, the wait
  before the next, the error), and with ``retry=False`` the reader tries once and
  ends (:attr:`DeviceReader.gave_up` says why);
  the hooks' ``on_open`` runs on every open (the dial box handshake, the tracker's
  start command);
* clean stop (:meth:`DeviceReader.stop`): the hooks' ``on_stop`` (the tracker's stop
  command) while the port is still open, then an ``info`` status
  (``message: "closed"``) that flushes the decoder, so a torn last frame shows as
  ``truncated``.

Things the reader itself says (port opened, lost, reopened; a device's init
handshake) are :class:`Control` items: they go to the sink like chunks, are recorded
in the session log, and :meth:`DeviceStream.process` turns them into the same
:class:`~drivers.events.StatusEvent` live and in replay (flushing and resetting the
decoder where the live reader did), which is what makes a replayed dump identical
to the live one.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import queue
import select
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, fields
from types import MappingProxyType
from typing import Any, Protocol

import serial

from drivers.events import Event, StatusEvent
from drivers.protocols import DEVICE_OF, make_decoder
from drivers.udp_port import UdpPort, open_port
from service.base.errors import DeviceError, LogFileError, SettingsError

#: Protocol name in a log header for a device's control records.
CONTROL_PROTOCOL = "control"
#: Suffix of the log device that holds a device's control records.
CONTROL_SUFFIX = ":control"
#: Largest chunk one read returns.
MAX_CHUNK = 4096
#: Protocol aliases accepted in log headers.
PROTOCOL_ALIASES = {"sgi_dialbox": "sgi", "dialbox": "sgi", "sgi": "sgi",
                    "hatire": "hatire", "native": "native", "opentrack": "opentrack"}


def canonical_protocol(name: str) -> str:
    """Decoder name for ``name`` (accepts ``sgi_dialbox`` / ``dialbox`` for ``sgi``)."""
    try:
        return PROTOCOL_ALIASES[name]
    except KeyError:
        raise SettingsError(f"unknown protocol {name!r}; "
                            "known: hatire, native, opentrack, sgi") from None


@dataclass(frozen=True, slots=True)
class Chunk:
    """Bytes as received from a device.

    Parameters
    ----------
    device : str
        Reader name (``"tracker"``, ``"dials"``).
    t_ns : int
        Receive time, :func:`time.monotonic_ns` domain.
    data : bytes
    """

    device: str
    t_ns: int
    data: bytes


@dataclass(frozen=True, slots=True)
class Control:
    """Something the reader did or saw that is not device bytes.

    Parameters
    ----------
    device : str
        Reader name.
    t_ns : int
        When, :func:`time.monotonic_ns` domain.
    event : str
        Status event name (``"info"``, ``"error"``, ``"reconnect"``).
    details : Mapping
        JSON-able details.
    flush : bool
        Flush the decoder first (its leftover bytes become status events).
    reset : bool
        Reset the decoder afterwards (new connection, re-initialised device); the
        status event then says ``details.decoder_reset: true`` (the dial values
        restart from 0, which the publisher mirrors).
    """

    device: str
    t_ns: int
    event: str
    details: Mapping[str, Any] = field(default_factory=dict)
    flush: bool = False
    reset: bool = False

    def to_bytes(self) -> bytes:
        """The JSON body stored in a log record.

        Keys keep their order (no sorting), so the status event rebuilt in replay
        prints exactly as the live one did.
        """
        body = {"event": self.event, "details": dict(self.details),
                "flush": self.flush, "reset": self.reset}
        return json.dumps(body, separators=(",", ":")).encode()

    @classmethod
    def from_bytes(cls, device: str, t_ns: int, data: bytes) -> Control:
        """Inverse of :meth:`to_bytes`.

        Raises
        ------
        LogFileError
            The body is not a control record.
        """
        try:
            d = json.loads(data)
            return cls(device, t_ns, str(d["event"]), dict(d.get("details", {})),
                       bool(d.get("flush", False)), bool(d.get("reset", False)))
        except (ValueError, KeyError, TypeError) as exc:
            raise LogFileError(f"bad control record for {device!r}: {exc}") from exc


Item = Chunk | Control
Sink = Callable[[Item, list[Event]], None]


class DeviceStream:
    """A decoder plus the rules for applying items; shared by live reading and replay.

    Parameters
    ----------
    name : str
        Reader / log device name.
    protocol : str
        ``hatire``, ``native`` or ``sgi`` (aliases accepted).
    decoder_options : Mapping, optional
        Keyword arguments of the decoder.
    """

    def __init__(self, name: str, protocol: str,
                 decoder_options: Mapping[str, Any] | None = None) -> None:
        self.name = name
        self.protocol = canonical_protocol(protocol)
        self.decoder = make_decoder(self.protocol, **dict(decoder_options or {}))
        self._apply = {Chunk: self._chunk, Control: self._control}

    @property
    def device(self) -> str:
        """``"tracker"`` or ``"dials"`` (the events' device)."""
        return self.decoder.device

    def process(self, item: Item) -> list[Event]:
        """Events that ``item`` gives (decoded bytes, or the control's status)."""
        return self._apply[type(item)](item)

    def flush(self, t_ns: int) -> list[Event]:
        """End of input (the end of a replay): the decoder's leftovers at ``t_ns``.

        A torn last frame becomes a ``truncated`` status, pending garbage a
        ``resync``; the live reader does the same on a clean stop (the ``closed``
        control item).
        """
        return self.decoder.flush(t_ns)

    def _chunk(self, item: Chunk) -> list[Event]:
        return self.decoder.feed(item.data, item.t_ns)

    def _control(self, item: Control) -> list[Event]:
        events = self.decoder.flush(item.t_ns) if item.flush else []
        details = {**item.details, "decoder_reset": True} if item.reset else item.details
        events.append(StatusEvent(item.t_ns, self.device, item.event, details))
        if item.reset:
            self.decoder.reset()
        return events


@dataclass(frozen=True)
class ReaderSettings:
    """How a reader opens and watches its port.

    Parameters
    ----------
    url : str
        pyserial port name or URL.
    protocol : str
        Decoder name.
    name : str or None
        Reader name (default: the protocol's device, ``tracker`` or ``dials``).
    baudrate : int
    poll_s : float
        Read timeout: the longest a read blocks (also the stop latency).
    watchdog_s : float or None
        Reopen after this long without a valid frame (None: only on read errors).
    backoff_s, backoff_max_s : float
        First and largest wait between reopen attempts (doubling).
    write_timeout_s : float
        Timeout of host-to-device writes.
    decoder_options : Mapping
        Keyword arguments of the decoder.
    retry : bool
        Open again (after ``backoff_s``...) when an open fails; False: the reader
        gives up on the first failed open and its thread ends.
    """

    url: str
    protocol: str
    name: str | None = None
    baudrate: int = 115200
    poll_s: float = 0.05
    watchdog_s: float | None = 2.0
    backoff_s: float = 0.05
    backoff_max_s: float = 2.0
    write_timeout_s: float = 1.0
    decoder_options: Mapping[str, Any] = field(default_factory=dict)
    retry: bool = True

    def __post_init__(self) -> None:
        canonical_protocol(self.protocol)
        if self.baudrate <= 0 or self.poll_s <= 0 or self.write_timeout_s <= 0:
            raise SettingsError("baudrate, poll_s and write_timeout_s must be > 0")
        if self.watchdog_s is not None and self.watchdog_s <= 0:
            raise SettingsError("watchdog_s must be > 0 or None")
        if not 0 < self.backoff_s <= self.backoff_max_s:
            raise SettingsError("need 0 < backoff_s <= backoff_max_s")

    @property
    def device_name(self) -> str:
        """The reader name."""
        return self.name or DEVICE_OF[canonical_protocol(self.protocol)]


@dataclass
class ReaderCounters:
    """The reader's own counters (the decoder keeps the byte-level ones).

    Attributes
    ----------
    chunks : int
        Reads that returned bytes.
    opens : int
        Successful opens (the first included).
    reconnects : int
        Successful reopens after a loss.
    disconnects : int
        Read errors that closed the port.
    watchdog_trips : int
        Reopens because no valid frame came in time.
    open_failures : int
        Failed open attempts.
    write_errors : int
        Host-to-device writes that failed or found the port closed.
    """

    chunks: int = 0
    opens: int = 0
    reconnects: int = 0
    disconnects: int = 0
    watchdog_trips: int = 0
    open_failures: int = 0
    write_errors: int = 0

    def as_dict(self) -> dict[str, int]:
        """The counters as a plain dict."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True, slots=True)
class Retry:
    """One failed open, as :class:`DeviceReader` tells its ``on_retry`` callable.

    Parameters
    ----------
    reader : str
        Reader name.
    url : str
        The port that did not open.
    attempt : int
        Failed opens in this outage (1 for the first).
    wait_s : float or None
        Seconds until the next try (the backoff); None: no next try (``retry=False``).
    message : str
        The open's error.
    """

    reader: str
    url: str
    attempt: int
    wait_s: float | None
    message: str


class DeviceHooks(Protocol):
    """Device-specific behaviour a reader calls on its own thread."""

    def on_open(self, reader: DeviceReader) -> None:
        """The port was (re)opened; run the device's init handshake here."""
        ...

    def on_events(self, reader: DeviceReader, events: list[Event]) -> None:
        """Events were decoded (e.g. react to a re-init request)."""
        ...

    def on_stop(self, reader: DeviceReader) -> None:
        """Clean stop, port still open: say goodbye (optional; errors are ignored)."""
        ...


class _NoHooks:
    def on_open(self, reader: DeviceReader) -> None:
        """Nothing to initialise."""

    def on_events(self, reader: DeviceReader, events: list[Event]) -> None:
        """Nothing to react to."""

    def on_stop(self, reader: DeviceReader) -> None:
        """Nothing to say."""


class DeviceReader:
    """Reads one device on its own daemon thread (see the module docstring).

    Parameters
    ----------
    settings : ReaderSettings
    sink : callable (item, events) -> None
        Receives every chunk / control item with its events, on the reader thread.
    hooks : DeviceHooks, optional
        Init handshake and event reactions (the dial box's).
    clock_ns : callable () -> int
        Receive-time clock (:func:`time.monotonic_ns`).
    opener : callable
        Opens a port: ``opener(url, baudrate=..., timeout=..., write_timeout=...)``
        (:func:`drivers.udp_port.open_port`: pyserial, or a UDP listener for
        ``opentrack-udp://``).
    on_retry : callable (Retry) -> None, optional
        Told of each failed open on the reader thread (``holo-devices`` prints it);
        not recorded: the session log keeps one ``open_failed`` status per outage.

    Attributes
    ----------
    crashed : Exception or None
        Set when the thread ended on an unexpected exception (a bug, not a device
        fault); an ``error`` status with ``reason: "reader_crashed"`` reports it.
    gave_up : str or None
        Why the thread ended without being stopped (``retry=False`` and the port did
        not open); None otherwise.
    """

    def __init__(self, settings: ReaderSettings, sink: Sink, *,
                 hooks: DeviceHooks | None = None,
                 clock_ns: Callable[[], int] = time.monotonic_ns,
                 opener: Callable[..., Any] = open_port,
                 on_retry: Callable[[Retry], None] | None = None) -> None:
        self.settings = settings
        self.name = settings.device_name
        self.stream = DeviceStream(self.name, settings.protocol, settings.decoder_options)
        self.counters = ReaderCounters()
        self._sink = sink
        self._hooks = hooks or _NoHooks()
        self._clock = clock_ns
        self._opener = opener
        self._port: Any = None
        self._fd: int | None = None
        self._port_lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._backoff = settings.backoff_s
        self._last_valid_ns = 0
        self._down_since_ns: int | None = None
        self._failures_in_outage = 0
        self._open_error: str | None = None
        self._on_retry = on_retry
        self.crashed: Exception | None = None
        self.gave_up: str | None = None

    # -- life cycle -----------------------------------------------------------------
    def start(self) -> DeviceReader:
        """Start the reader thread (daemon); returns ``self``."""
        if self._thread is not None:
            raise DeviceError(f"reader {self.name!r} already started")
        self._thread = threading.Thread(target=self._run, name=f"reader-{self.name}",
                                        daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop the thread, join it (up to ``timeout_s``) and close the port."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
        self._close_port()

    @property
    def stopping(self) -> bool:
        """True once :meth:`stop` was called."""
        return self._stop.is_set()

    @property
    def connected(self) -> bool:
        """True while the port is open."""
        return self._port is not None

    def stats(self) -> dict[str, Any]:
        """Decoder counters, reader counters and ``connected``, as one dict."""
        out: dict[str, Any] = self.stream.decoder.stats.as_dict()
        out.update(self.counters.as_dict())
        out["connected"] = self.connected
        return out

    def __enter__(self) -> DeviceReader:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- host side --------------------------------------------------------------------
    def write(self, data: bytes) -> bool:
        """Send host-to-device bytes (thread-safe); False if the port is closed or failed."""
        with self._port_lock:
            port = self._port
            if port is None:
                self.counters.write_errors += 1
                return False
            try:
                port.write(data)
                port.flush()
            except (serial.SerialException, OSError):
                self.counters.write_errors += 1
                return False
        return True

    def emit(self, event: str, details: Mapping[str, Any] | None = None, *,
             flush: bool = False, reset: bool = False) -> list[Event]:
        """Emit a :class:`Control` item now; returns its events.

        Call it on the reader thread only (from hooks): it drives the decoder.
        """
        item = Control(self.name, self._clock(), event, MappingProxyType(dict(details or {})),
                       flush, reset)
        events = self.stream.process(item)
        self._sink(item, events)
        return events

    def pump(self, until: Callable[[list[Event]], bool], timeout_s: float) -> bool:
        """Read and dispatch until ``until(events)`` is true for one read's events.

        For init handshakes, on the reader thread.  Returns False on timeout or stop.
        Read errors propagate (the run loop treats them as a lost device).
        """
        deadline = time.monotonic() + timeout_s
        while not self._stop.is_set() and time.monotonic() < deadline:
            if until(self._read_once()):
                return True
        return False

    # -- the thread ---------------------------------------------------------------------
    def _run(self) -> None:
        try:
            self._loop()
            self._shutdown()
        except Exception as exc:  # a bug, not a device problem: report it, end the thread
            self.crashed = exc
            with contextlib.suppress(Exception):
                self.emit("error", {"reason": "reader_crashed", "message": repr(exc)})
        finally:
            self._close_port()

    def _loop(self) -> None:
        while not self._stop.is_set():
            if self._port is None and not self._open():
                wait = self._next_backoff() if self.settings.retry else None
                self._tell_retry(wait)
                if wait is None:
                    self.gave_up = self._open_error or "lost during its opening handshake"
                    break
                self._stop.wait(wait)
                continue
            try:
                self._read_once()
            except (serial.SerialException, OSError) as exc:
                self.counters.disconnects += 1
                self._lose("disconnected", str(exc))
                continue
            self._check_watchdog()

    def _shutdown(self) -> None:
        """Clean stop: the hooks' goodbye, then a ``closed`` status that flushes.

        ``on_stop`` (the tracker's stop command) runs while the port is still open;
        the ``info`` status ``message: "closed"`` flushes the decoder first, so a torn
        last frame is reported as ``truncated``, as ``holo-replay`` does at its end.
        """
        on_stop = getattr(self._hooks, "on_stop", None)
        if self._port is not None and on_stop is not None:
            with contextlib.suppress(serial.SerialException, OSError):
                on_stop(self)
        self.emit("info", {"message": "closed"}, flush=True)

    def _open(self) -> bool:
        s = self.settings
        self._open_error = None
        try:
            port = self._opener(s.url, baudrate=s.baudrate, timeout=s.poll_s,
                                write_timeout=s.write_timeout_s)
        except (serial.SerialException, OSError, ValueError) as exc:
            self._open_failed(exc)
            return False
        with self._port_lock:
            self._port, self._fd = port, _select_fd(port)
        self._opened()
        try:
            self._hooks.on_open(self)
        except (serial.SerialException, OSError) as exc:
            self.counters.disconnects += 1
            self._lose("disconnected", str(exc))
            return False
        return True

    def _opened(self) -> None:
        now = self._clock()
        self.counters.opens += 1
        self._last_valid_ns = now
        details: dict[str, Any] = {"url": self.settings.url,
                                   "attempts": self._failures_in_outage + 1}
        if self._down_since_ns is not None:
            details["down_s"] = round((now - self._down_since_ns) / 1e9, 6)
        if self.counters.opens == 1:
            self.emit("info", {"message": "opened", **details}, reset=True)
        else:
            self.counters.reconnects += 1
            self.emit("reconnect", details, reset=True)
        self._down_since_ns = None
        self._failures_in_outage = 0

    def _open_failed(self, exc: Exception) -> None:
        self._open_error = str(exc)
        self.counters.open_failures += 1
        self._failures_in_outage += 1
        if self._down_since_ns is None:
            self._down_since_ns = self._clock()
        if self._failures_in_outage == 1:
            self.emit("error", {"reason": "open_failed", "url": self.settings.url,
                                "message": str(exc)})

    def _tell_retry(self, wait: float | None) -> None:
        """Tell ``on_retry`` of the failed open (not of a handshake that lost the port)."""
        if self._on_retry is not None and self._open_error is not None:
            self._on_retry(Retry(self.name, self.settings.url, self._failures_in_outage, wait,
                                 self._open_error))

    def _next_backoff(self) -> float:
        wait = self._backoff
        self._backoff = min(self._backoff * 2, self.settings.backoff_max_s)
        return wait

    def _read_once(self) -> list[Event]:
        port, fd = self._port, self._fd
        if port is None:
            raise serial.SerialException("port closed")
        if fd is not None:
            data = self._read_fd(fd)
            t_ns = self._clock()
        elif isinstance(port, UdpPort):  # one datagram per chunk: the decoder needs them whole
            data = port.read_datagram()
            t_ns = self._clock()
        else:
            data = port.read(1)
            t_ns = self._clock()
            if data:
                data += self._drain(port)
        if not data:
            return []
        self.counters.chunks += 1
        item = Chunk(self.name, t_ns, data)
        frames = self.stream.decoder.stats.frames
        events = self.stream.process(item)
        self._sink(item, events)
        if self.stream.decoder.stats.frames != frames:
            self._last_valid_ns = t_ns
            self._backoff = self.settings.backoff_s
        self._hooks.on_events(self, events)
        return events

    def _read_fd(self, fd: int) -> bytes:
        """Wait up to ``poll_s`` for bytes on ``fd``; all that is there, or ``b""``.

        One ``select`` and one ``read`` system call (pyserial's ``read(1)`` plus a
        drain take two of each and an ``ioctl``).  Errors as pyserial reports them.
        """
        try:
            ready, _, _ = select.select((fd,), (), (), self.settings.poll_s)
            if not ready:
                return b""
            data = os.read(fd, MAX_CHUNK)
        except BlockingIOError:  # ready, then nothing after all (non-blocking fd)
            return b""
        except (OSError, ValueError) as exc:
            raise serial.SerialException(f"read failed: {exc}") from exc
        if not data:
            raise serial.SerialException(
                "device reports readiness to read but returned no data "
                "(device disconnected or multiple access on port?)")
        return data

    @staticmethod
    def _drain(port: Any) -> bytes:
        """What is already waiting, up to :data:`MAX_CHUNK` bytes, without blocking."""
        out = b""
        while len(out) < MAX_CHUNK:
            n = port.in_waiting
            if not n:
                break
            out += port.read(min(n, MAX_CHUNK - len(out)))
        return out

    def _check_watchdog(self) -> None:
        limit = self.settings.watchdog_s
        if limit is None or self._port is None:
            return
        silent_ns = self._clock() - self._last_valid_ns
        if silent_ns > limit * 1e9:
            self.counters.watchdog_trips += 1
            self._lose("watchdog", f"no valid frame for {silent_ns / 1e9:.3f} s")
            self._stop.wait(self._next_backoff())

    def _lose(self, reason: str, message: str) -> None:
        self._close_port()
        self._down_since_ns = self._clock()
        self._failures_in_outage = 0
        self.emit("error", {"reason": reason, "message": message}, flush=True, reset=True)

    def _close_port(self) -> None:
        with self._port_lock:
            port, self._port, self._fd = self._port, None, None
        if port is not None:
            with contextlib.suppress(Exception):
                port.close()


def _select_fd(port: Any) -> int | None:
    """The file descriptor to wait on for ``port``, or None to use ``port.read``.

    Only pyserial's POSIX ports qualify: they read the descriptor directly, with no
    buffer of their own that an :func:`os.read` would bypass.
    """
    posix = getattr(serial, "serialposix", None)  # absent on Windows
    if posix is None or not isinstance(port, posix.Serial):
        return None
    try:
        return int(port.fileno())
    except (AttributeError, io.UnsupportedOperation, serial.SerialException, OSError):
        return None


class EventHub:
    """Where readers put what they produce; one consumer thread dispatches it.

    ``put`` is the readers' sink (thread-safe); :meth:`dispatch` drains the queue
    into listeners ``listener(item, events)`` on the calling thread.
    """

    def __init__(self) -> None:
        self._queue: queue.SimpleQueue[tuple[Item, list[Event]]] = queue.SimpleQueue()

    def put(self, item: Item, events: list[Event]) -> None:
        """Queue one item with its events (any thread)."""
        self._queue.put((item, events))

    def dispatch(self, listeners: Iterable[Callable[[Item, list[Event]], None]],
                 timeout_s: float = 0.05, max_items: int = 10_000) -> int:
        """Wait up to ``timeout_s`` for an item, then hand out all waiting ones.

        Returns
        -------
        int
            Items dispatched.
        """
        listeners = tuple(listeners)
        try:
            first = self._queue.get(timeout=timeout_s)
        except queue.Empty:
            return 0
        count = 0
        entry: tuple[Item, list[Event]] | None = first
        while entry is not None:
            for listener in listeners:
                listener(*entry)
            count += 1
            entry = self._next() if count < max_items else None
        return count

    def _next(self) -> tuple[Item, list[Event]] | None:
        try:
            return self._queue.get_nowait()
        except queue.Empty:
            return None

    def empty(self) -> bool:
        """True when nothing is waiting."""
        return self._queue.empty()
