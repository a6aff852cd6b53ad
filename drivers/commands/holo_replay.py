"""``holo-replay``: replay a session log (or a raw byte capture) through the decoders.

Examples::

    holo-replay session.hlog --dump                      # recorded timing, JSON lines
    holo-replay session.hlog --as-fast-as-possible --dump
    holo-replay session.hlog --speed 2 --skip 10 --loop --pub   # on tcp://127.0.0.1:5560
    holo-replay session.hlog --to-pty --loop             # holo-devices opens the printed pty
    holo-replay session.hlog --to-port /dev/ttyUSB1      # out of a null-modem cable
    holo-replay capture.log --protocol hatire --as-fast-as-possible --dump

Records are paced by :class:`drivers.replay_clock.ReplayScheduler` (absolute targets
from the start: no drift).  Each device's bytes and control records go through the
same :class:`drivers.reader.DeviceStream` as in ``holo-devices``, and ``t`` is
``(t_ns - start_monotonic_ns) / 1e9`` with the log header's session start, so the
``--dump`` output equals what ``holo-devices --dump`` printed live.  ``--skip S``
still decodes the first S seconds (decoder state stays right) but prints and
publishes nothing from them.  ``--to-port URL`` writes one device's bytes
(``--device``, default the first) into a serial port at the recorded timing;
``--to-pty`` makes a pty pair, prints its path on stderr (``holo-replay: device on
/dev/pts/N``; ``--pty-link`` keeps a stable symlink) and plays the device there for a
``holo-devices --tracker /dev/pts/N`` (pyserial drops what was written before the
client opened the port, so ``--loop`` suits it).

A file without the log magic is read as a raw capture (``--protocol`` required):
chunks of ``--chunk-size`` bytes stamped at the line rate of ``--baud``; time 0 is
its first byte.  A capture whose first 64 KiB do not frame as ``--protocol`` (more
than half the bytes rejected: :mod:`drivers.protocols.framing`) is refused before
any output, naming the protocols it does frame as; the SGI dial box protocol has no
framing, so without this a tracker capture read as ``sgi`` gave thousands of
made-up button events.  A session log is replayed as recorded, but a device whose
bytes did not frame is named at the end and its events do not count for the exit
status.  With no output option (``--dump``, ``--pub``, ``--to-port``,
``--to-pty``) ``--dump`` is implied, and a note on stderr says so.

Exit status (the rule of :mod:`service.base.signals`): 0 when the replay decoded device
events; 1 when it decoded none (an empty log, or bytes in another protocol: the
message names what was read and discarded; events of a device whose bytes do not
frame do not count) or ``--skip`` passed them all; 2 for a bad file or settings
(a raw capture that does not frame as ``--protocol``); 130 / 143 after a clean stop
on SIGINT / SIGTERM.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import signal
import sys
import threading
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, TextIO

import serial

from drivers.commands.holo_devices import (
    Listener,
    add_publish_options,
    dump_listener,
    positive_int,
    publishing_line,
)
from drivers.events import DEFAULT_COUNTS_PER_TURN, Event, StatusEvent
from drivers.protocols import DEVICE_OF, sgi_dialbox
from drivers.protocols.framing import (
    PREFIX_BYTES,
    FramingCheck,
    check_framing,
    count_events,
    protocols_that_frame,
)
from drivers.pty_link import PtyLink
from drivers.publisher import Publisher
from drivers.reader import (
    CONTROL_PROTOCOL,
    CONTROL_SUFFIX,
    Chunk,
    Control,
    DeviceStream,
    Item,
    canonical_protocol,
)
from drivers.recording import (
    BITS_PER_BYTE_8N1,
    MAGIC,
    LogHeader,
    LogReader,
    RawCaptureReader,
    Record,
)
from drivers.replay_clock import ReplayScheduler, ReplaySettings
from drivers.udp_port import UdpSender, is_udp_url
from service.base.cli_args import float_range, int_range, output_problem, plain_help
from service.base.errors import DeviceError, HoloError, LogFileError, SettingsError
from service.base.signals import (
    EXIT_FAILED,
    EXIT_OK,
    EXIT_RULE,
    EXIT_USAGE,
    exit_status,
    stop_on_signals,
)

#: default line rate per protocol for raw captures.
RAW_BAUD = {"hatire": 115200, "native": 115200, "sgi": 9600}


class _Stopped(Exception):
    """Raised by the replay's sleep when a stop was asked for."""


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (also used for ``--help``)."""
    p = argparse.ArgumentParser(
        prog="holo-replay",
        description="Replay a holo-devices session log (or a raw serial capture) at its "
        "recorded timing: dump, publish, or write the bytes into a serial port.",
        epilog=plain_help("Without --dump, --pub, --to-port or --to-pty, --dump is implied. "
                          + EXIT_RULE + " 1: no device event was decoded (or --skip passed "
                          "them all)."))
    p.add_argument("file", type=Path, metavar="FILE",
                   help="session log, or raw capture with --protocol")
    speed = p.add_mutually_exclusive_group()
    speed.add_argument("--speed", type=float_range(0, lo_open=True), default=1.0,
                       metavar="X", help="speed factor (default 1)")
    speed.add_argument("--as-fast-as-possible", action="store_true", help="never wait")
    p.add_argument("--skip", type=float_range(0), default=0.0, metavar="S",
                   help="start S recorded seconds in")
    p.add_argument("--loop", action="store_true", help="start again at the end")
    p.add_argument("--passes", type=positive_int, default=None, metavar="N",
                   help="replay N times, then stop (implies --loop)")
    add_publish_options(p)
    p.add_argument("--dump", action="store_true",
                   help="print one JSON line per event (implied without another output)")
    out = p.add_mutually_exclusive_group()
    out.add_argument("--to-port", metavar="URL", help="write a device's bytes into this port "
                     "(opentrack-udp://HOST:PORT: a recorded opentrack session's datagrams)")
    out.add_argument("--to-pty", action="store_true",
                     help="play the device on a new pty pair (its path is printed on stderr)")
    p.add_argument("--pty-link", metavar="PATH", help="with --to-pty: a symlink to the pty")
    p.add_argument("--device", metavar="NAME",
                   help="device whose bytes --to-port / --to-pty write (default: the first)")
    p.add_argument("--protocol", choices=tuple(RAW_BAUD), help="protocol of a raw capture")
    p.add_argument("--baud", type=positive_int, default=None, metavar="N",
                   help="raw capture line rate / --to-port baud (default: per protocol)")
    p.add_argument("--chunk-size", type=positive_int, default=64, metavar="N",
                   help="raw capture bytes per chunk (default: %(default)s)")
    p.add_argument("--skip-bytes", type=int_range(0), default=0, metavar="N",
                   help="raw capture bytes to drop first")
    p.add_argument("--hatire-big-endian", action="store_true",
                   help="Hatire bytes are big-endian (raw captures; a session log's header "
                   "says it itself)")
    p.add_argument("--dial-counts-per-turn", type=positive_int, default=None, metavar="N",
                   help="dial counts per turn for the 'turns' of dial events (default: the "
                   f"log's setting, else {DEFAULT_COUNTS_PER_TURN})")
    return p


def has_output(args: argparse.Namespace) -> bool:
    """True when the command line names an output (dump, publisher, port)."""
    return bool(args.dump or args.pub or args.to_port or args.to_pty)


def open_source(args: argparse.Namespace) -> LogReader | RawCaptureReader:
    """A :class:`LogReader`, or a :class:`RawCaptureReader` for a file without the magic.

    Raises
    ------
    LogFileError
        Missing file, damaged header, or a raw capture without ``--protocol``.
    """
    try:
        with open(args.file, "rb") as f:
            head = f.read(len(MAGIC))
    except OSError as exc:
        raise LogFileError(f"{args.file}: cannot open: {exc.strerror or exc}") from exc
    if head == MAGIC:
        return LogReader(args.file, warn=False)
    if args.protocol is None:
        raise LogFileError(f"{args.file}: not a session log (no HOLOLOG magic); "
                           "pass --protocol to replay a raw capture")
    reader = RawCaptureReader(args.file, protocol=args.protocol,
                              baudrate=args.baud or RAW_BAUD[args.protocol],
                              chunk_size=args.chunk_size, skip_bytes=args.skip_bytes,
                              device=DEVICE_OF[args.protocol])
    check_raw_framing(args)
    return reader


def check_raw_framing(args: argparse.Namespace) -> None:
    """Refuse a raw capture whose first bytes do not frame as ``--protocol``.

    Raises
    ------
    LogFileError
        Naming the rejected bytes and the protocols that do frame them.
    """
    try:
        with open(args.file, "rb") as f:
            f.seek(args.skip_bytes)
            head = f.read(PREFIX_BYTES)
    except OSError as exc:
        raise LogFileError(f"{args.file}: cannot read: {exc}") from exc
    big = args.hatire_big_endian and args.protocol == "hatire"
    check = check_framing(args.protocol, head, **({"byte_order": "big"} if big else {}))
    if check.frames:
        return
    chosen = args.protocol + (" --hatire-big-endian" if big else "")
    others = [p for p in protocols_that_frame(head) if p != chosen]
    fix = ("leave out --hatire-big-endian" if others[:1] == ["hatire"] and big
           else f"pass --protocol {others[0]}" if others else "")
    hint = (f"it frames as {' or '.join(others)}: {fix}" if others
            else "nor as any other protocol (a leading banner? --skip-bytes N drops it)")
    raise LogFileError(f"{args.file}: does not frame as {chosen}: "
                       f"{check.describe('its first ')}; {hint}")


def data_devices(header: LogHeader) -> list[tuple[str, str]]:
    """``(name, protocol)`` of the devices whose bytes the log holds."""
    return [(d.name, d.protocol) for d in header.devices if d.protocol != CONTROL_PROTOCOL]


def decoder_options(header: LogHeader, big_endian: bool = False) -> dict[str, dict[str, Any]]:
    """Device name -> decoder options: the header's ``extra["decoder_options"]``.

    ``big_endian`` makes Hatire devices whose options do not name a byte order
    big-endian (raw captures, logs written before the header kept options).
    """
    recorded = header.extra.get("decoder_options") or {}
    out = {name: dict(recorded.get(name) or {}) for name, _ in data_devices(header)}
    for name, proto in data_devices(header):
        if big_endian and canonical_protocol(proto) == "hatire":
            out[name].setdefault("byte_order", "big")
    return out


def raw_capture_options(args: argparse.Namespace,
                        options: dict[str, dict[str, Any]]) -> None:
    """Decoder options a raw capture needs (updates ``options`` in place).

    A raw capture's chunks are stamped at the line rate, ``--chunk-size`` bytes
    apart (64 bytes at 9600 baud: 67 ms), so an SGI dial packet split between two
    chunks would look 67 ms late and be dropped by the decoder's 10 ms rule, which
    is about real arrival times that a capture does not have.  The timeout is
    widened by one chunk period.
    """
    if args.protocol != "sgi":
        return
    chunk_ns = args.chunk_size * BITS_PER_BYTE_8N1 * 1e9 / (args.baud or RAW_BAUD["sgi"])
    for opts in options.values():
        opts.setdefault("dial_timeout_ns", sgi_dialbox.DIAL_TIMEOUT_NS + math.ceil(chunk_ns))


class Replayer:
    """Turns records into items and events, one :class:`DeviceStream` per device.

    Parameters
    ----------
    header : LogHeader
    options : Mapping, optional
        Device name -> decoder options (default: :func:`decoder_options` of the header).
    """

    def __init__(self, header: LogHeader,
                 options: Mapping[str, Mapping[str, Any]] | None = None) -> None:
        self.header = header
        self.t0_ns = header.start_monotonic_ns
        self._devices = data_devices(header)
        self._options = decoder_options(header) if options is None else dict(options)
        #: device name -> framing counts of the passes so far (:meth:`reset` adds each)
        self.framing = {name: FramingCheck(canonical_protocol(proto))
                        for name, proto in self._devices}
        #: device name -> its first bytes (up to PREFIX_BYTES), to say what they frame as
        self.head = {name: bytearray() for name, _ in self._devices}
        self.streams: dict[str, DeviceStream] = {}
        self.reset()

    def reset(self) -> None:
        """Fresh decoders (a new pass); the old ones' counts go into :attr:`framing`."""
        for name, stream in self.streams.items():
            st = stream.decoder.stats
            self.framing[name] += FramingCheck(stream.protocol, st.bytes_in,
                                               st.bytes_discarded, st.resyncs,
                                               self._events.get(name, 0), st.frames)
        self.streams = {name: DeviceStream(name, proto, self._options.get(name))
                        for name, proto in self._devices}
        self._last_t: dict[str, int] = {}
        self._events: dict[str, int] = {}

    def misframed(self) -> dict[str, FramingCheck]:
        """Devices whose bytes (so far, over finished passes) do not frame as their protocol."""
        return {name: c for name, c in self.framing.items() if not c.frames}

    def flush(self) -> list[tuple[Item, list[Event]]]:
        """End of a pass: each decoder's leftovers, at its device's last record time.

        Returns ``(item, events)`` pairs for the listeners; the item is an empty
        chunk (nothing was read).
        """
        out: list[tuple[Item, list[Event]]] = []
        for name, t_ns in self._last_t.items():
            events = self.streams[name].flush(t_ns)
            if events:
                out.append((Chunk(name, t_ns, b""), events))
        return out

    def item(self, rec: Record) -> Item:
        """The live reader's item for a record."""
        if rec.device.endswith(CONTROL_SUFFIX):
            return Control.from_bytes(rec.device[: -len(CONTROL_SUFFIX)], rec.t_ns, rec.data)
        return Chunk(rec.device, rec.t_ns, rec.data)

    def events(self, item: Item) -> list[Event]:
        """Decode an item as the live reader did (unknown devices give nothing)."""
        stream = self.streams.get(item.device)
        if stream is None:
            return []
        self._last_t[item.device] = item.t_ns
        if isinstance(item, Chunk):
            head = self.head[item.device]
            if len(head) < PREFIX_BYTES:
                head += item.data[: PREFIX_BYTES - len(head)]
        events = stream.process(item)
        self._events[item.device] = self._events.get(item.device, 0) + count_events(events)
        return events


class _PtyOut:
    """A pty pair's master side with the few port methods the replay uses."""

    def __init__(self, link: PtyLink) -> None:
        self.link = link
        self.path = link.path

    def write(self, data: bytes) -> None:
        """Write all of ``data`` for the client of the slave side.

        Host bytes the client sent (a tracker driver's start command on each open)
        are read and dropped, so they never fill the pty.
        """
        self.link.read_available()
        self.link.write(data)

    def flush(self) -> None:
        """Wait until the client has read what was written (a stop ends the wait).

        Closing the pty throws away what its client has not read yet, so a replay
        that ends by itself would lose its last frames to a reader a little behind.
        """
        self.link.drain()

    def close(self) -> None:
        """Close the pair (and remove the symlink); :meth:`flush` first to lose nothing."""
        self.link.close()


class ReplaySession:
    """One ``holo-replay`` run: source, scheduler, outputs.

    Parameters
    ----------
    args : argparse.Namespace
    out : text stream
        Where the dump goes.
    """

    def __init__(self, args: argparse.Namespace, out: TextIO) -> None:
        self.args = args
        self.out = out
        self.stop = threading.Event()
        self.source = open_source(args)
        header = self.source.header
        options = decoder_options(header, args.hatire_big_endian)
        if isinstance(self.source, RawCaptureReader):
            raw_capture_options(args, options)
        self.replayer = Replayer(header, options)
        self.counts_per_turn = int(args.dial_counts_per_turn
                                   or header.extra.get("counts_per_turn")
                                   or DEFAULT_COUNTS_PER_TURN)
        settings = ReplaySettings(speed=args.speed, as_fast_as_possible=args.as_fast_as_possible,
                                  skip_s=args.skip,
                                  skip_mode="drop" if args.to_port or args.to_pty else "fast",
                                  loop=args.loop or args.passes is not None,
                                  max_passes=args.passes)
        self.scheduler: ReplayScheduler[Record] = ReplayScheduler(settings, sleep=self._sleep)
        self.listeners: list[Listener] = []
        self.publisher: Publisher | None = None
        self.port: Any = None
        self.port_device: str | None = None
        #: device bytes replayed and device events (pose, dial, button) decoded from them
        self.bytes_read = 0
        self.decoded = 0
        #: device events replayed from --skip on, and the log's first and last record times
        self.shown = 0
        self.shown_by_device: dict[str, int] = {}
        self.span_ns = (0, 0)
        try:
            self._open_outputs()
        except HoloError:
            self.close()
            raise

    def _sleep(self, seconds: float) -> None:
        if self.stop.wait(seconds):
            raise _Stopped

    def _open_outputs(self) -> None:
        a, t0 = self.args, self.replayer.t0_ns
        if a.pub:
            self.publisher = Publisher(a.pub, t0, pose_address=a.pub_pose,
                                       counts_per_turn=self.counts_per_turn)
            pub = self.publisher
            self.listeners.append(lambda item, events: pub.publish_all(events))
        if a.dump:
            self.listeners.append(dump_listener(self.out, t0, self.counts_per_turn))
        if a.to_port or a.to_pty:
            self._open_port(a)

    def _open_port(self, a: argparse.Namespace) -> None:
        names = [n for n, _ in data_devices(self.source.header)]
        self.port_device = a.device or names[0]
        if self.port_device not in names:
            raise SettingsError(f"--device {self.port_device!r} not in the log: {names}")
        if a.to_pty:
            self.port = _PtyOut(PtyLink(a.pty_link, stop=self.stop))
            return
        proto = dict(data_devices(self.source.header))[self.port_device]
        if is_udp_url(a.to_port):  # a recorded opentrack session: one record, one datagram
            self.port = UdpSender(a.to_port)
            return
        baud = a.baud or RAW_BAUD.get(proto, 115200)
        try:
            self.port = serial.serial_for_url(a.to_port, baudrate=baud, write_timeout=2.0)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise DeviceError(f"cannot open {a.to_port!r}: {exc}") from exc

    def _records(self) -> Iterator[tuple[int, Record]]:
        """Scheduled records with the pass number."""
        for rec in self.scheduler.play(self.source):
            yield self.scheduler.stats.passes, rec

    def run(self) -> None:
        """Replay everything (or until stopped); each pass ends with a decoder flush."""
        first = next(iter(self.source), None)
        if first is None:
            return
        show_from = first.t_ns + round(self.args.skip * 1e9)
        self.span_ns = (first.t_ns, first.t_ns)
        current = 0
        with contextlib.suppress(_Stopped):
            for n_pass, rec in self._records():
                if n_pass != current:
                    current = n_pass
                    self._end_pass(show_from)
                self._one(rec, rec.t_ns >= show_from)
                if self.stop.is_set():
                    break
        self._end_pass(show_from)

    def _end_pass(self, show_from: int) -> None:
        """Flush the decoders (a torn last frame shows as ``truncated``), then reset."""
        for item, events in self.replayer.flush():
            if item.t_ns >= show_from:
                self._dispatch(item, events)
        self.replayer.reset()

    def _one(self, rec: Record, show: bool) -> None:
        item = self.replayer.item(rec)
        self.span_ns = (self.span_ns[0], max(self.span_ns[1], rec.t_ns))
        if self.port is not None and isinstance(item, Chunk) and item.device == self.port_device:
            self.port.write(item.data)
        events = self.replayer.events(item)
        if isinstance(item, Chunk):
            self.bytes_read += len(item.data)
            self.decoded += sum(not isinstance(e, StatusEvent) for e in events)
        if show:
            self._dispatch(item, events)

    def _dispatch(self, item: Item, events: list[Event]) -> None:
        shown = sum(not isinstance(e, StatusEvent) for e in events)
        self.shown += shown
        self.shown_by_device[item.device] = self.shown_by_device.get(item.device, 0) + shown
        for listener in self.listeners:
            listener(item, events)
        if events and not self.args.as_fast_as_possible:
            self.out.flush()
        if self.publisher is not None:
            self.publisher.service()

    def close(self) -> None:
        """Close the publisher and the port."""
        if self.publisher is not None:
            self.publisher.close()
        if self.port is not None:
            with contextlib.suppress(Exception):
                self.port.flush()
            self.port.close()

    def useful(self) -> int:
        """Device events shown from devices whose bytes framed as their protocol."""
        bad = self.replayer.misframed()
        return sum(n for device, n in self.shown_by_device.items() if device not in bad)

    def problems(self) -> Iterable[str]:
        """What went wrong: log damage, misframed devices, nothing decoded or shown."""
        st = self.source.stats
        if st.torn or st.corrupt:
            yield (f"log damage: {st.torn} torn, {st.corrupt} corrupt regions, "
                   f"{st.skipped_bytes} bytes skipped")
        for name, check in self.replayer.misframed().items():
            yield self._misframed_line(name, check)
        if not self.decoded:
            yield f"{self.args.file}: {self._nothing_decoded()}"
        elif not self.shown:
            span = (self.span_ns[1] - self.span_ns[0]) / 1e9
            yield (f"--skip {self.args.skip:g} s is past the last device event; the log "
                   f"spans {span:.1f} s, so nothing was replayed")

    def _misframed_line(self, name: str, check: FramingCheck) -> str:
        others = [p for p in protocols_that_frame(bytes(self.replayer.head[name]))
                  if p != check.protocol]
        hint = f"the bytes frame as {' or '.join(others)}: " if others else ""
        return (f"{name}: the recorded bytes do not frame as {check.protocol} "
                f"({check.describe()}), so its {check.events} events are not trusted; "
                f"{hint}recorded with the wrong protocol?")

    def _nothing_decoded(self) -> str:
        if not self.bytes_read:
            return "no device bytes in the file; nothing was replayed"
        protocols = ", ".join(sorted({p for _, p in data_devices(self.source.header)}))
        return (f"no pose, dial or button event decoded from {self.bytes_read} bytes "
                f"(read as {protocols}; is that the device's protocol?)")


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``holo-replay``; returns the exit status (see the module docstring)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.pub_pose and not args.pub:
        parser.error("--pub-pose needs --pub")
    problem = output_problem(args.pty_link) if args.pty_link else None
    if problem:  # the link is made once the pty is open: a traceback there before
        print(f"holo-replay: --pty-link {problem}", file=sys.stderr)
        return EXIT_USAGE
    if not has_output(args):
        args.dump = True
        print("holo-replay: no output option given: dumping JSON lines (--dump)",
              file=sys.stderr, flush=True)
    try:
        session = ReplaySession(args, sys.stdout)
    except HoloError as exc:
        print(f"holo-replay: {exc}", file=sys.stderr)
        return EXIT_USAGE
    if isinstance(session.port, _PtyOut):
        print(f"holo-replay: device on {session.port.path}", file=sys.stderr, flush=True)
    if session.publisher is not None:
        print(publishing_line("holo-replay", session.publisher), file=sys.stderr, flush=True)
    signum = None
    try:
        with stop_on_signals(session.stop) as got:
            session.run()
        signum = got.signum
        sys.stdout.flush()
    except KeyboardInterrupt:  # a Ctrl-C before the handler was in place
        signum = signal.SIGINT
    except BrokenPipeError:
        pass
    except (HoloError, serial.SerialException) as exc:
        print(f"holo-replay: {exc}", file=sys.stderr)
        return EXIT_USAGE
    finally:
        session.close()
    for line in session.problems():
        print(f"holo-replay: {line}", file=sys.stderr)
    return exit_status(signum, EXIT_OK if session.useful() else EXIT_FAILED)


if __name__ == "__main__":
    sys.exit(main())
