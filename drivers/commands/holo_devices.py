"""``holo-devices``: read the tracker and the dial box, publish, record, dump.

Examples::

    holo-devices --tracker /dev/ttyUSB0 --dump
    holo-devices --tracker /dev/ttyACM0 --tracker-protocol native --dials /dev/ttyUSB1
                 --pub --record session.hlog      (one line; --pub: tcp://127.0.0.1:5560)
    holo-devices --tracker socket://127.0.0.1:7001 --dump --seconds 10

The tracker is sent its start command each time its port opens (the first time, and
after every reconnect or watchdog reopen) and its stop command on a clean stop
(``--hatire-start C`` / ``--hatire-stop C`` / ``--hatire-reset C`` choose the Hatire
characters; native devices get command frames); the dial box gets VRPN's handshake.

``--dump`` prints one JSON object per event per line on stdout (schema in
``docs/drivers.md``; dial events carry ``turns`` per ``--dial-counts-per-turn``).
With ``--pub`` the first stderr line names the bound address (``--pub`` alone binds
the default ``tcp://127.0.0.1:5560``, ``tcp://127.0.0.1:0`` picks a free port).
Problems with the links (errors, reconnects) also go to stderr, one line each; a
port that does not open is tried again with a back-off (50 ms doubling to 2 s),
each try one line (``holo-devices: tracker (/dev/ttyUSB9): open failed (try 3, same
error); next try in 0.20 s``), until it opens, ``--seconds`` end or Ctrl-C;
``--no-retry`` tries each port once (and a lost one once again) and ends the run
when one does not open.
Ctrl-C or SIGTERM stops cleanly: readers are joined, the queue is drained, the
recorder closed (the log is complete) and a JSON summary of each device's statistics
is printed on stderr.

Exit status (the rule of :mod:`service.base.signals`): 0 when the run ended (``--seconds``)
having opened a device; 1 when no device could ever be opened (each device's last
error is named), or with ``--no-retry`` when any port did not open; 2 for bad
settings (an address that cannot be bound, a log that cannot be created); 130 / 143
after a clean stop on SIGINT / SIGTERM.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any, TextIO

from drivers.dialbox_driver import DialBoxDriver
from drivers.events import DEFAULT_COUNTS_PER_TURN, Event, StatusEvent
from drivers.filters import FILTERS
from drivers.opentrack_forward import DEFAULT_FILTER, ForwardSettings, OpentrackForwarder
from drivers.protocols.framing import FramingCheck
from drivers.protocols.sgi_dialbox import BAUD as SGI_BAUD
from drivers.publisher import Publisher
from drivers.reader import (
    CONTROL_PROTOCOL,
    CONTROL_SUFFIX,
    Chunk,
    DeviceHooks,
    DeviceReader,
    EventHub,
    Item,
    ReaderSettings,
    Retry,
)
from drivers.recording import DeviceInfo, LogHeader, LogWriter, SerialSettings
from drivers.tracker_driver import TrackerDriver, add_command_options, commands_from_args
from drivers.udp_port import is_udp_url, parse_udp_url
from service.base.addresses import default_address, host_port
from service.base.cli_args import endpoint, float_range, int_range, output_problem, plain_help
from service.base.errors import HoloError, SettingsError
from service.base.signals import (
    EXIT_FAILED,
    EXIT_OK,
    EXIT_RULE,
    EXIT_USAGE,
    exit_status,
    stop_on_signals,
)

Listener = Callable[[Item, list[Event]], None]
#: status events echoed on stderr.
LOUD_STATUS = frozenset({"error", "reconnect"})
#: status reasons not echoed: the retry lines (:func:`retry_line`) say them.
SAID_BY_RETRY = frozenset({"open_failed"})
#: An argparse type: an integer > 0.
positive_int = int_range(1)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (also used for ``--help``)."""
    p = argparse.ArgumentParser(
        prog="holo-devices",
        description="Read a head tracker and an SGI dial box over serial ports "
        "(pyserial URLs), publish their events on ZeroMQ, record raw bytes, dump JSON.",
        epilog=plain_help(EXIT_RULE + " 1: no device could be opened at all, or with "
                          "--no-retry one did not open."))
    p.add_argument("--tracker", metavar="URL",
                   help="tracker port: /dev/ttyUSB0, loop://, socket://host:port, rfc2217://, "
                   "or opentrack-udp://HOST:PORT to listen for opentrack's UDP poses")
    p.add_argument("--tracker-protocol", choices=("hatire", "native", "opentrack"),
                   default=None, help="tracker protocol (default: opentrack for an "
                   "opentrack-udp:// URL, else hatire)")
    p.add_argument("--dials", metavar="URL", help="SGI dial and button box port")
    add_publish_options(p)
    p.add_argument("--record", metavar="FILE", help="record raw bytes to a new session log")
    p.add_argument("--dump", action="store_true", help="print one JSON line per event")
    p.add_argument("--baud", type=int_range(1), default=115200, metavar="N",
                   help="tracker baud rate (default: %(default)s)")
    p.add_argument("--dials-baud", type=int_range(1), default=SGI_BAUD, metavar="N",
                   help="dial box baud rate (default: %(default)s)")
    p.add_argument("--seconds", type=float_range(0), default=None, metavar="N",
                   help="stop after N seconds (default: run until Ctrl-C / SIGTERM)")
    p.add_argument("--watchdog", type=float_range(0), default=2.0, metavar="S",
                   help="reopen the tracker port after S s without a valid frame "
                   "(0: only on errors; default: %(default)s)")
    p.add_argument("--dials-watchdog", type=float_range(0), default=0.0, metavar="S",
                   help="same for the dial box, which is silent when untouched "
                   "(default: 0 = only on errors)")
    p.add_argument("--no-retry", dest="retry", action="store_false",
                   help="try each port once (a lost one once more): one that does not "
                   "open ends the run with status 1 (default: try again after "
                   f"{ReaderSettings.backoff_s:g} s, doubling up to "
                   f"{ReaderSettings.backoff_max_s:g} s, a line per try)")
    p.add_argument("--reset-wait", type=float_range(0), default=1.0, metavar="S",
                   help="longest wait for the dial box's reset answer (default: %(default)s)")
    p.add_argument("--lamps", type=int_range(0, 0xFFFFFFFF), default=0, metavar="MASK",
                   help="dial box lamps to light after init, e.g. 0xffffffff")
    add_tracker_options(p)
    add_forward_options(p)
    p.add_argument("--dial-counts-per-turn", type=positive_int, default=DEFAULT_COUNTS_PER_TURN,
                   metavar="N", help="dial counts per turn, for the 'turns' of dial events "
                   "(default: %(default)s, VRPN's value)")
    return p


def add_publish_options(p: argparse.ArgumentParser) -> None:
    """``--pub [ADDR]`` and ``--pub-pose [ADDR]`` (alone: the default ports 5560 / 5561)."""
    pub, pose = default_address("devices"), default_address("pose")
    p.add_argument("--pub", metavar="ADDR", nargs="?", const=pub, type=endpoint(bind=True),
                   help=f"publish events on a ZeroMQ socket bound here (alone: {pub}; "
                   "tcp://127.0.0.1:0 picks a free port)")
    p.add_argument("--pub-pose", metavar="ADDR", nargs="?", const=pose,
                   type=endpoint(bind=True),
                   help=f"also publish poses alone (single frame, conflating) here "
                   f"(alone: {pose})")


def add_tracker_options(p: argparse.ArgumentParser) -> None:
    """The tracker's host commands and Hatire byte order."""
    add_command_options(p)
    p.add_argument("--tracker-reset-on-open", action="store_true",
                   help="send the reset command before the start command on every open")
    p.add_argument("--hatire-big-endian", action="store_true",
                   help="Hatire frames are big-endian (default: little-endian)")


def add_forward_options(p: argparse.ArgumentParser) -> None:
    """``--forward-opentrack HOST:PORT``, ``--forward-filter NAME``, ``--forward-predict-ms``."""
    p.add_argument("--forward-opentrack", metavar="HOST:PORT", type=_host_port_arg,
                   help="also send the tracker's filtered poses to HOST:PORT as opentrack UDP "
                   "datagrams (opentrack's 'UDP over network' input listens on 4242)")
    p.add_argument("--forward-filter", choices=sorted(FILTERS), default=DEFAULT_FILTER,
                   help="pose filter of --forward-opentrack (default: %(default)s)")
    p.add_argument("--forward-predict-ms", type=float_range(0, 1000), default=0.0,
                   metavar="MS", help="forward the pose predicted MS ms ahead (default: 0)")


def forwarding_line(prog: str, fwd: OpentrackForwarder, done: bool = False) -> str:
    """``PROG: forwarding poses to opentrack at HOST:PORT (FILTER)``; at the end, the counts."""
    s = fwd.settings
    where = f"opentrack at {s.host}:{s.port}"
    if done:
        st = fwd.stats()
        return (f"{prog}: forwarded {st['sent']} poses to {where} ({st['skipped']} skipped, "
                f"{st['send_errors']} send errors)")
    ahead = f", {s.predict_ms:g} ms ahead" if s.predict_ms else ""
    return f"{prog}: forwarding poses to {where} (filter {s.filter}{ahead})"


def _host_port_arg(text: str) -> tuple[str, int]:
    try:
        return host_port(text)
    except SettingsError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def publishing_line(prog: str, pub: Publisher) -> str:
    """The stderr line that names the bound address(es): ``PROG: publishing on ...``."""
    where = pub.address + (f" (poses only: {pub.pose_address})" if pub.pose_address else "")
    return f"{prog}: publishing on {where}"


def log_devices(settings: Sequence[ReaderSettings]) -> tuple[DeviceInfo, ...]:
    """Header devices of a session log: each reader's bytes and its control records."""
    out: list[DeviceInfo] = []
    for s in settings:
        out.append(DeviceInfo(s.device_name, s.protocol, SerialSettings(s.url, s.baudrate)))
        out.append(DeviceInfo(s.device_name + CONTROL_SUFFIX, CONTROL_PROTOCOL))
    return tuple(out)


def header_extra(settings: Sequence[ReaderSettings], counts_per_turn: int) -> dict[str, Any]:
    """The log header's ``extra``: what replay needs to print what was seen live.

    ``decoder_options`` (device name -> decoder keyword arguments, e.g. a big-endian
    Hatire tracker) and ``counts_per_turn`` (the dump's dial ``turns``).
    """
    options = {s.device_name: dict(s.decoder_options) for s in settings if s.decoder_options}
    return {"program": "holo-devices", "t0": "start_monotonic_ns",
            "decoder_options": options, "counts_per_turn": counts_per_turn}


def recorder_listener(writer: LogWriter) -> Listener:
    """A hub listener writing chunks and control records to ``writer``."""

    def record(item: Item, events: list[Event]) -> None:
        if isinstance(item, Chunk):
            writer.write(item.device, item.t_ns, item.data)
        else:
            writer.write(item.device + CONTROL_SUFFIX, item.t_ns, item.to_bytes())

    return record


def dump_listener(out: TextIO, t0_ns: int,
                  counts_per_turn: int = DEFAULT_COUNTS_PER_TURN) -> Listener:
    """A hub listener writing one dump-schema JSON line per event to ``out``.

    Dial events' ``turns`` are ``value / counts_per_turn``.
    """

    def line(ev: Event) -> str:
        return ev.to_json(t0_ns, counts_per_turn) + "\n"

    def dump(item: Item, events: list[Event]) -> None:
        if events:
            out.write("".join(map(line, events)))

    return dump


def stderr_listener(err: TextIO, t0_ns: int) -> Listener:
    """A hub listener echoing link errors and reconnects on ``err``.

    Failed opens are left to the retry lines (:func:`retry_teller`).
    """

    def echo(item: Item, events: list[Event]) -> None:
        for ev in events:
            if (isinstance(ev, StatusEvent) and ev.event in LOUD_STATUS
                    and ev.details.get("reason") not in SAID_BY_RETRY):
                err.write(f"{ev.device}: {ev.event} {json.dumps(dict(ev.details))}\n")

    return echo


def tracker_protocol(url: str, protocol: str | None) -> str:
    """The tracker's protocol: ``opentrack`` exactly for ``opentrack-udp://`` URLs.

    Raises
    ------
    SettingsError
        A malformed ``opentrack-udp://`` URL, or a protocol that does not fit the URL.
    """
    udp = is_udp_url(url)
    if udp:
        parse_udp_url(url)
    chosen = protocol or ("opentrack" if udp else "hatire")
    if udp != (chosen == "opentrack"):
        raise SettingsError(
            f"--tracker-protocol {chosen} does not fit --tracker {url}: opentrack poses come "
            "over UDP (opentrack-udp://HOST:PORT), serial trackers over a port")
    return chosen


def retry_line(prog: str, retry: Retry, same_error: bool = False) -> str:
    """One failed open on one line: the device, the try, the error, the back-off.

    ``same_error``: the error is the one the previous line gave (not repeated).
    """
    what = (f"open failed (try {retry.attempt}, same error)" if same_error
            else f"open failed (try {retry.attempt}): {retry.message}")
    then = ("not retrying (--no-retry)" if retry.wait_s is None
            else f"next try in {retry.wait_s:.2f} s")
    return f"{prog}: {retry.reader} ({retry.url}): {what}; {then}"


def retry_teller(prog: str, err: TextIO) -> Callable[[Retry], None]:
    """A reader's ``on_retry``: one :func:`retry_line` per failed open on ``err``.

    Called on the reader threads; each line is one write.
    """
    last: dict[str, str] = {}

    def tell(retry: Retry) -> None:
        same = last.get(retry.reader) == retry.message
        last[retry.reader] = retry.message
        with contextlib.suppress(OSError, ValueError):  # a closed stderr
            err.write(retry_line(prog, retry, same) + "\n")
            err.flush()

    return tell


def _settings(args: argparse.Namespace) -> list[tuple[ReaderSettings, DeviceHooks]]:
    out: list[tuple[ReaderSettings, DeviceHooks]] = []
    if args.tracker:
        proto = tracker_protocol(args.tracker, args.tracker_protocol)
        big = args.hatire_big_endian and proto == "hatire"
        options = {"byte_order": "big"} if big else {}
        out.append((ReaderSettings(args.tracker, proto, "tracker", args.baud,
                                   watchdog_s=args.watchdog or None, decoder_options=options,
                                   retry=args.retry),
                    TrackerDriver(proto, commands_from_args(args),
                                  args.tracker_reset_on_open)))
    if args.dials:
        out.append((ReaderSettings(args.dials, "sgi", "dials", args.dials_baud,
                                   watchdog_s=args.dials_watchdog or None, retry=args.retry),
                    DialBoxDriver(args.reset_wait, args.lamps)))
    return out


class DeviceSession:
    """Readers, hub and listeners of one ``holo-devices`` run.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed command line.
    out, err : text streams
        Where the dump and the messages go.
    """

    def __init__(self, args: argparse.Namespace, out: TextIO, err: TextIO) -> None:
        self.args = args
        self.out = out
        self.stop = threading.Event()
        self.hub = EventHub()
        specs = _settings(args)
        self.header = LogHeader(log_devices([s for s, _ in specs]),
                                extra=header_extra([s for s, _ in specs],
                                                   args.dial_counts_per_turn))
        self.t0_ns = self.header.start_monotonic_ns
        self.writer: LogWriter | None = None
        self.publisher: Publisher | None = None
        self.forwarder: OpentrackForwarder | None = None
        self.listeners: list[Listener] = []
        self.open_errors: dict[str, str] = {}
        try:
            self._open_outputs(err)
        except HoloError:
            self._close_outputs()
            raise
        # events are published on the reader threads the moment they are decoded;
        # the hub carries the items on to the recorder, the dump and stderr
        sink = self.hub.put if self.forwarder is None else self.forwarder.sink(self.hub.put)
        sink = sink if self.publisher is None else self.publisher.sink(sink)
        tell = retry_teller("holo-devices", err)
        self.readers = [DeviceReader(s, sink, hooks=h, on_retry=tell) for s, h in specs]

    def _open_outputs(self, err: TextIO) -> None:
        a = self.args
        if a.record:
            self.writer = LogWriter(a.record, self.header)
            self.listeners.append(recorder_listener(self.writer))
        if a.pub:
            self.publisher = Publisher(a.pub, self.t0_ns, pose_address=a.pub_pose,
                                       counts_per_turn=a.dial_counts_per_turn)
        if a.forward_opentrack:
            host, port = a.forward_opentrack
            self.forwarder = OpentrackForwarder(
                ForwardSettings(host, port, a.forward_filter, a.forward_predict_ms))
        if a.dump:
            self.listeners.append(dump_listener(self.out, self.t0_ns, a.dial_counts_per_turn))
        self.listeners.append(stderr_listener(err, self.t0_ns))
        self.listeners.append(self._note_open_errors)

    def _note_open_errors(self, item: Item, events: list[Event]) -> None:
        """Keep each device's last open error, for the summary at exit."""
        for ev in events:
            if isinstance(ev, StatusEvent) and ev.details.get("reason") == "open_failed":
                self.open_errors[ev.device] = str(ev.details.get("message", ""))

    def stats(self) -> dict[str, Any]:
        """Every reader's statistics by device name."""
        return {r.name: r.stats() for r in self.readers}

    def run(self) -> None:
        """Start the readers and dispatch until stopped or ``--seconds`` are up."""
        for r in self.readers:
            r.start()
        seconds = self.args.seconds
        end = None if seconds is None else time.monotonic() + seconds
        while not self.stop.is_set() and (end is None or time.monotonic() < end):
            self._dispatch(0.05)
            if any(r.gave_up for r in self.readers):  # --no-retry and a port did not open
                return

    def _dispatch(self, timeout_s: float) -> int:
        n = self.hub.dispatch(self.listeners, timeout_s)
        if n:
            self.out.flush()
        if self.publisher is not None:
            self.publisher.service(self.stats)
        return n

    def close(self) -> None:
        """Stop and join the readers, drain the hub, close the log and the publisher."""
        for r in self.readers:
            r.stop()
        with contextlib.suppress(BrokenPipeError):
            while self._dispatch(0.0):
                pass
        self._close_outputs()

    def _close_outputs(self) -> None:
        if self.writer is not None:
            self.writer.close()
        if self.publisher is not None:
            self.publisher.close()
        if self.forwarder is not None:
            self.forwarder.close()


def never_opened(session: DeviceSession) -> list[str]:
    """``NAME (URL): last error`` for each reader that never opened its port."""
    out = []
    for r in session.readers:
        if r.counters.opens == 0:
            why = session.open_errors.get(r.name, "not tried")
            out.append(f"{r.name} ({r.settings.url}): {why}")
    return out


def gave_up(session: DeviceSession) -> list[str]:
    """What each reader that stopped trying (``--no-retry``) did, one string each.

    ``NAME (URL) did not open``, or ``... was lost and did not reopen``.
    """
    return [f"{r.name} ({r.settings.url}) "
            + ("was lost and did not reopen" if r.counters.opens else "did not open")
            for r in session.readers if r.gave_up]


def misframed(session: DeviceSession) -> list[str]:
    """``NAME (URL): ...`` for each reader whose bytes did not frame as its protocol.

    Most of the bytes rejected (:mod:`drivers.protocols.framing`): a tracker on the
    dial box's port, or the wrong ``--tracker-protocol``.  The SGI protocol has no
    framing, so such a port gives made-up button events rather than none.
    """
    out = []
    for r in session.readers:
        st = r.stream.decoder.stats
        check = FramingCheck(r.stream.protocol, st.bytes_in, st.bytes_discarded, st.resyncs,
                             st.frames, st.frames)
        if not check.frames:
            out.append(f"{r.name} ({r.settings.url}): the bytes read do not frame as "
                       f"{check.protocol} ({check.describe()}); the wrong port or protocol?")
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``holo-devices``; returns the exit status (see the module docstring)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not (args.tracker or args.dials):
        parser.error("give --tracker URL and/or --dials URL")
    if args.pub_pose and not args.pub:
        parser.error("--pub-pose needs --pub")
    if args.tracker:
        try:
            args.tracker_protocol = tracker_protocol(args.tracker, args.tracker_protocol)
        except SettingsError as exc:
            parser.error(str(exc))
    problem = output_problem(args.record) if args.record else None
    if args.record and not problem and os.path.lexists(args.record):
        problem = f"{args.record}: already exists (a log is never overwritten; name a new file)"
    if problem:  # the log's own error repeated the path and the errno
        print(f"holo-devices: --record {problem}", file=sys.stderr)
        return EXIT_USAGE
    try:
        session = DeviceSession(args, sys.stdout, sys.stderr)
    except HoloError as exc:
        print(f"holo-devices: {exc}", file=sys.stderr)
        return EXIT_USAGE
    if session.publisher is not None:
        print(publishing_line("holo-devices", session.publisher), file=sys.stderr, flush=True)
    if session.forwarder is not None:
        print(forwarding_line("holo-devices", session.forwarder), file=sys.stderr, flush=True)
    signum = None
    try:
        with stop_on_signals(session.stop) as got:
            session.run()
        signum = got.signum
    except KeyboardInterrupt:  # a Ctrl-C before the handler was in place
        signum = signal.SIGINT
    except BrokenPipeError:
        pass
    finally:
        session.close()
    if session.forwarder is not None:
        print(forwarding_line("holo-devices", session.forwarder, done=True), file=sys.stderr)
    print(json.dumps({"stats": session.stats()}), file=sys.stderr)
    missing = never_opened(session)
    for line in missing:
        print(f"holo-devices: never opened {line}", file=sys.stderr)
    for line in misframed(session):
        print(f"holo-devices: {line}", file=sys.stderr)
    ok = EXIT_FAILED if len(missing) == len(session.readers) else EXIT_OK
    if ok == EXIT_FAILED:
        print("holo-devices: no device could be opened; nothing was read", file=sys.stderr)
    elif stopped := gave_up(session):
        print(f"holo-devices: stopped: {', '.join(stopped)} (--no-retry)", file=sys.stderr)
        ok = EXIT_FAILED
    return exit_status(signum, ok)


if __name__ == "__main__":
    sys.exit(main())
