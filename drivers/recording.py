"""Session logs: raw serial bytes with their receive times, crash-safe.

The recorder stores the bytes each device delivered, exactly as read, with the
monotonic time (ns) at which they were received, so that replay drives the same
decoder as a live session.  The layout is described in ``docs/recording-format.md``:

* a file header: magic, format version, a JSON document (devices, their protocols
  and serial settings, wall-clock start time) and its CRC-32;
* records, each ``sync | device | flags | t_ns | length | header CRC | data | data CRC``.

A process killed mid-write leaves a readable file: every completed record is
intact, a torn last record is detected and skipped (counted in
:attr:`ReadStats.torn`, with a :class:`LogWarning`).  A damaged record in the
middle fails its CRC, is counted in :attr:`ReadStats.corrupt` (with a warning),
and reading resumes at the next sync marker whose record header checks out.
Struct-packed binary and JSON only, never Python object serialisation.
"""

from __future__ import annotations

import json
import mmap
import os
import struct
import time
import warnings
import zlib
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, BinaryIO

from service.base.errors import LogFileError, SettingsError

#: First bytes of every log file (the CR LF catches text-mode mangling).
MAGIC = b"HOLOLOG\x00\r\n\x1a\n"
#: Format version written by this module.
VERSION = 1
#: ``magic | version (uint16) | json length (uint32)``.
FILE_HEAD = struct.Struct("<12sHI")
#: Four bytes that open every record.
SYNC = b"\xa7RC\x5d"
#: ``sync | device (uint16) | flags (uint16) | t_ns (int64) | length (uint32)``.
REC_HEAD = struct.Struct("<4sHHqI")
CRC = struct.Struct("<I")
#: Largest data payload of one record (a sanity bound used while resyncing).
MAX_RECORD = 1 << 24
#: Bits on the wire per byte for 8N1 framing (start + 8 data + stop).
BITS_PER_BYTE_8N1 = 10


class LogWarning(UserWarning):
    """A log was readable but damaged (torn tail, corrupt records)."""


@dataclass(frozen=True)
class SerialSettings:
    """How a device's port was opened (pyserial names).

    Parameters
    ----------
    url : str
        Port name or pyserial URL (``/dev/ttyUSB0``, ``loop://``).
    baudrate : int
    bytesize : int
    parity : str
        ``"N"``, ``"E"``, ``"O"``, ``"M"`` or ``"S"``.
    stopbits : float
    """

    url: str = ""
    baudrate: int = 115200
    bytesize: int = 8
    parity: str = "N"
    stopbits: float = 1


@dataclass(frozen=True)
class DeviceInfo:
    """One recorded device.

    Parameters
    ----------
    name : str
        The id used in :meth:`LogWriter.write` and :class:`Record`.
    protocol : str
        Decoder name (``"hatire"``, ``"dialbox"``...).
    serial : SerialSettings
    """

    name: str
    protocol: str
    serial: SerialSettings = field(default_factory=SerialSettings)


def _text(d: dict[str, Any], key: str) -> str:
    """``d[key]``, which must be a string (TypeError names it otherwise)."""
    if not isinstance(d[key], str):
        raise TypeError(f"device {key} must be a string, got {d[key]!r:.40}")
    return d[key]


@dataclass(frozen=True)
class LogHeader:
    """The JSON header of a log file.

    Parameters
    ----------
    devices : tuple of DeviceInfo
        At most 65535; record device ids index this tuple.
    start_wall_ns : int
        Wall-clock time (ns since the Unix epoch) when recording started.
    start_monotonic_ns : int
        Monotonic clock at the same moment (record times use this clock).
    extra : dict
        Free JSON-able notes (host, program version...).
    """

    devices: tuple[DeviceInfo, ...]
    start_wall_ns: int = field(default_factory=time.time_ns)
    start_monotonic_ns: int = field(default_factory=time.monotonic_ns)
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        names = [d.name for d in self.devices]
        if len(set(names)) != len(names) or not 0 < len(names) < 65536:
            raise SettingsError(f"device names must be unique, 1..65535 of them: {names}")

    def to_json(self) -> dict[str, Any]:
        """JSON-able dict, with an ISO wall-clock start for people."""
        d = asdict(self)
        d["devices"] = [asdict(x) for x in self.devices]
        iso = datetime.fromtimestamp(self.start_wall_ns / 1e9, UTC).isoformat()
        d["start_wall_iso"] = iso
        return d

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> LogHeader:
        """Inverse of :meth:`to_json`.

        Raises
        ------
        LogFileError
            Missing or ill-typed fields.
        """
        try:
            devices = tuple(
                DeviceInfo(_text(x, "name"), _text(x, "protocol"),
                           SerialSettings(**x.get("serial", {})))
                for x in d["devices"]
            )
            return cls(
                devices,
                int(d["start_wall_ns"]),
                int(d["start_monotonic_ns"]),
                dict(d.get("extra", {})),
            )
        except (KeyError, TypeError, ValueError, OverflowError) as exc:  # Overflow: 1e400
            raise LogFileError(f"bad log header: {exc!r}") from exc

    def device_index(self, name: str) -> int:
        """Index of the device called ``name``."""
        for i, d in enumerate(self.devices):
            if d.name == name:
                return i
        raise SettingsError(f"device {name!r} is not in the log header")


@dataclass(frozen=True)
class Record:
    """One chunk of bytes as received.

    Attributes
    ----------
    device : str
        Device name from the header.
    t_ns : int
        Receive time, monotonic ns (same clock as ``start_monotonic_ns``).
    data : bytes
    """

    device: str
    t_ns: int
    data: bytes


@dataclass
class ReadStats:
    """What a reader met.

    Attributes
    ----------
    records : int
        Good records yielded.
    torn : int
        Incomplete records at the end of the file (0 or 1).
    corrupt : int
        Damaged regions skipped (each resync counts once).
    skipped_bytes : int
        Bytes skipped in damaged regions and torn tails.
    """

    records: int = 0
    torn: int = 0
    corrupt: int = 0
    skipped_bytes: int = 0


def encode_record(device: int, t_ns: int, data: bytes, flags: int = 0) -> bytes:
    """Pack one record.

    Parameters
    ----------
    device : int
        Index into the header's devices.
    t_ns : int
    data : bytes
    flags : int
        Reserved, 0.

    Returns
    -------
    bytes
        ``REC_HEAD | CRC(head[4:]) | data | CRC(data)``.
    """
    if len(data) > MAX_RECORD:
        raise SettingsError(f"record of {len(data)} bytes exceeds {MAX_RECORD}")
    head = REC_HEAD.pack(SYNC, device, flags, t_ns, len(data))
    return b"".join((head, CRC.pack(zlib.crc32(head[4:])), data, CRC.pack(zlib.crc32(data))))


def encode_file_header(header: LogHeader) -> bytes:
    """Pack the file header: ``FILE_HEAD | JSON | CRC(JSON)``."""
    js = json.dumps(header.to_json(), sort_keys=True).encode()
    return FILE_HEAD.pack(MAGIC, VERSION, len(js)) + js + CRC.pack(zlib.crc32(js))


class LogWriter:
    """Append records to a new log file.

    Parameters
    ----------
    path : str or Path
    header : LogHeader
    flush_every : int
        Flush to the OS after this many records (1: every record).  A killed
        process loses at most the unflushed ones; all flushed ones stay readable.
    fsync : bool
        Also ``os.fsync`` at each flush (survives power loss, costs time).
    overwrite : bool
        Replace an existing file instead of raising.
    """

    def __init__(
        self,
        path: str | Path,
        header: LogHeader,
        *,
        flush_every: int = 1,
        fsync: bool = False,
        overwrite: bool = False,
    ) -> None:
        if flush_every < 1:
            raise SettingsError(f"flush_every must be >= 1, not {flush_every}")
        self.path = Path(path)
        self.header = header
        self._index = {d.name: i for i, d in enumerate(header.devices)}
        self._flush_every = flush_every
        self._fsync = fsync
        self._pending = 0
        self.records = 0
        try:
            self._f: BinaryIO | None = open(self.path, "wb" if overwrite else "xb")
        except OSError as exc:
            raise LogFileError(f"{self.path}: cannot create log: {exc}") from exc
        self._f.write(encode_file_header(header))
        self._flush()

    def write(self, device: str, t_ns: int, data: bytes) -> None:
        """Append one chunk of bytes received from ``device`` at ``t_ns``.

        Raises
        ------
        SettingsError
            Unknown device.
        LogFileError
            The writer is closed.
        """
        if self._f is None:
            raise LogFileError(f"{self.path}: write after close")
        try:
            idx = self._index[device]
        except KeyError:
            raise SettingsError(f"device {device!r} is not in the log header") from None
        self._f.write(encode_record(idx, int(t_ns), bytes(data)))
        self.records += 1
        self._pending += 1
        if self._pending >= self._flush_every:
            self._flush()

    def _flush(self) -> None:
        self._f.flush()
        if self._fsync:
            os.fsync(self._f.fileno())
        self._pending = 0

    def close(self) -> None:
        """Flush and close (idempotent)."""
        if self._f is not None:
            self._flush()
            self._f.close()
            self._f = None

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _read_file_header(buf: bytes | mmap.mmap, path: Path) -> tuple[LogHeader, int]:
    """Parse the file header; return it and the offset of the first record."""
    if len(buf) < FILE_HEAD.size:
        raise LogFileError(f"{path}: too short for a log header ({len(buf)} bytes)")
    magic, version, n = FILE_HEAD.unpack_from(buf, 0)
    if magic != MAGIC:
        raise LogFileError(f"{path}: not a Holo-realizer log (bad magic {magic!r})")
    if version != VERSION:
        raise LogFileError(f"{path}: log format version {version}, this reader knows {VERSION}")
    end = FILE_HEAD.size + n + CRC.size
    if len(buf) < end:
        raise LogFileError(f"{path}: header torn ({len(buf)} of {end} bytes)")
    js = bytes(buf[FILE_HEAD.size : FILE_HEAD.size + n])
    if CRC.unpack_from(buf, end - CRC.size)[0] != zlib.crc32(js):
        raise LogFileError(f"{path}: header CRC mismatch")
    try:
        return LogHeader.from_json(json.loads(js)), end
    except ValueError as exc:
        raise LogFileError(f"{path}: header is not JSON: {exc}") from exc


def _check_record(buf: bytes | mmap.mmap, pos: int, n_devices: int) -> tuple[str, int]:
    """Classify the record at ``pos``: ("ok"|"torn"|"bad", end offset or 0)."""
    size = len(buf)
    head_end = pos + REC_HEAD.size + CRC.size
    if head_end > size:
        tail = bytes(buf[pos : pos + len(SYNC)])
        return ("torn", 0) if SYNC.startswith(tail) else ("bad", 0)
    sync, dev, _flags, _t, n = REC_HEAD.unpack_from(buf, pos)
    head_crc = CRC.unpack_from(buf, pos + REC_HEAD.size)[0]
    if sync != SYNC or head_crc != zlib.crc32(buf[pos + 4 : pos + REC_HEAD.size]):
        return "bad", 0
    if dev >= n_devices or n > MAX_RECORD:
        return "bad", 0
    end = head_end + n + CRC.size
    if end > size:
        return "torn", 0
    if CRC.unpack_from(buf, end - CRC.size)[0] != zlib.crc32(buf[head_end : end - CRC.size]):
        return "bad", 0
    return "ok", end


class LogReader:
    """Iterate the records of a log file, surviving torn tails and corruption.

    Parameters
    ----------
    path : str or Path
    warn : bool
        Issue a :class:`LogWarning` for each damaged region and torn tail.

    Attributes
    ----------
    header : LogHeader
        Read at construction.
    stats : ReadStats
        Counts from the latest (or current) iteration.

    Raises
    ------
    LogFileError
        Missing file, bad magic, unknown version, torn or corrupt file header.
    """

    def __init__(self, path: str | Path, *, warn: bool = True) -> None:
        self.path = Path(path)
        self.warn = warn
        self.stats = ReadStats()
        with self._open() as buf:
            self.header, self._start = _read_file_header(buf, self.path)

    def _open(self) -> _Mapped:
        try:
            return _Mapped(self.path)
        except OSError as exc:
            raise LogFileError(f"{self.path}: cannot open log: {exc}") from exc

    def __iter__(self) -> Iterator[Record]:
        self.stats = ReadStats()
        names = [d.name for d in self.header.devices]
        with self._open() as buf:
            pos = self._start
            while pos < len(buf):
                kind, end = _check_record(buf, pos, len(names))
                if kind == "ok":
                    _, dev, _, t_ns, n = REC_HEAD.unpack_from(buf, pos)
                    data_at = pos + REC_HEAD.size + CRC.size
                    self.stats.records += 1
                    yield Record(names[dev], t_ns, bytes(buf[data_at : data_at + n]))
                    pos = end
                elif kind == "torn":
                    self._torn(pos, len(buf))
                    return
                else:
                    pos = self._resync(buf, pos, len(names))

    def _torn(self, pos: int, size: int) -> None:
        self.stats.torn += 1
        self.stats.skipped_bytes += size - pos
        self._warn(f"{self.path}: torn last record at byte {pos} ({size - pos} bytes) skipped")

    def _resync(self, buf: bytes | mmap.mmap, pos: int, n_devices: int) -> int:
        """Skip a damaged region; return the offset of the next plausible record."""
        start = pos
        pos = buf.find(SYNC, pos + 1)
        while pos != -1 and _check_record(buf, pos, n_devices)[0] == "bad":
            pos = buf.find(SYNC, pos + 1)
        pos = len(buf) if pos == -1 else pos
        self.stats.corrupt += 1
        self.stats.skipped_bytes += pos - start
        self._warn(f"{self.path}: corrupt data at bytes {start}..{pos} skipped")
        return pos

    def _warn(self, msg: str) -> None:
        if self.warn:
            warnings.warn(msg, LogWarning, stacklevel=4)


class _Mapped:
    """Read-only memory map of a file (empty files give b"")."""

    def __init__(self, path: Path) -> None:
        self._f = open(path, "rb")
        size = os.fstat(self._f.fileno()).st_size
        self._mm = mmap.mmap(self._f.fileno(), 0, access=mmap.ACCESS_READ) if size else None

    def __enter__(self) -> bytes | mmap.mmap:
        return self._mm if self._mm is not None else b""

    def __exit__(self, *exc: object) -> None:
        if self._mm is not None:
            self._mm.close()
        self._f.close()


class RawCaptureReader:
    """Read a raw, headerless byte capture as records with synthetic times.

    Chunk ``k`` is stamped with the time its last byte would arrive on the wire,
    ``(offset_end * bits_per_byte / baudrate)`` seconds after ``t0_ns``, so replay
    paces the bytes at the line rate (not the producer's rate, which a raw capture
    does not record).

    Parameters
    ----------
    path : str or Path
    protocol : str
        Decoder name for the synthetic header (e.g. ``"hatire"``).
    baudrate : int
    chunk_size : int
        Bytes per record (the last may be shorter).
    skip_bytes : int
        Bytes to drop from the front (e.g. a capture program's banner line);
        0 keeps them for the decoder to resynchronise past.
    device : str
        Device name in the synthetic header and records.
    bits_per_byte : int
        10 for 8N1.
    t0_ns : int
        Time of the first byte.

    Attributes
    ----------
    header : LogHeader
        Synthetic: one device (serial URL ``file://<path>``, the given baud rate),
        ``start_wall_ns`` from the file's modification time,
        ``start_monotonic_ns = t0_ns`` and ``extra["synthetic_times"] = True``.
    stats : ReadStats
    """

    def __init__(
        self,
        path: str | Path,
        *,
        protocol: str,
        baudrate: int = 115200,
        chunk_size: int = 64,
        skip_bytes: int = 0,
        device: str = "raw",
        bits_per_byte: int = BITS_PER_BYTE_8N1,
        t0_ns: int = 0,
    ) -> None:
        if baudrate <= 0 or chunk_size <= 0 or skip_bytes < 0 or bits_per_byte <= 0:
            raise SettingsError("baudrate, chunk_size, bits_per_byte > 0 and skip_bytes >= 0")
        self.path = Path(path)
        if not self.path.is_file():
            raise LogFileError(f"{self.path}: no such capture file")
        self._args = (baudrate, chunk_size, skip_bytes, bits_per_byte, t0_ns)
        serial = SerialSettings(url=f"file://{self.path}", baudrate=baudrate)
        self.header = LogHeader(
            (DeviceInfo(device, protocol, serial),),
            start_wall_ns=int(self.path.stat().st_mtime_ns),
            start_monotonic_ns=t0_ns,
            extra={"synthetic_times": True, "source": str(self.path)},
        )
        self.stats = ReadStats()

    def __iter__(self) -> Iterator[Record]:
        baud, chunk, skip, bits, t0 = self._args
        name = self.header.devices[0].name
        self.stats = ReadStats()
        ns_per_byte = bits * 1e9 / baud
        with open(self.path, "rb") as f:
            f.seek(skip)
            offset = 0
            while data := f.read(chunk):
                offset += len(data)
                self.stats.records += 1
                yield Record(name, t0 + round(offset * ns_per_byte), data)
