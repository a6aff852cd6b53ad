"""``holo-sim``: run a simulated tracker or dial box on a pty or a TCP port.

Examples::

    holo-sim tracker --pty                       # prints /dev/pts/N, streams Hatire
    holo-sim tracker --protocol native --tcp 7001 --motion turn:amplitude=45
    holo-sim tracker --faults corrupt=0.02,burst=0.01,split,seed=3 --seconds 30
    holo-sim tracker --udp 127.0.0.1:4242        # opentrack's UDP poses, one datagram each
    holo-sim dials --pty --seconds 20            # answers the init handshake, then plays
    holo-sim dials --pty --script random         # any dial, any button (the game's pause too)

The first stdout line is the path or URL a client opens (flushed at once).  When the
run ends a JSON summary (bytes sent, faults applied; for a tracker, the host
commands it received) is printed on stdout.  Ctrl-C (SIGINT) and SIGTERM stop it at
once, without waiting for a client to read what is queued: exit status 130 / 143,
the rule of :mod:`service.base.signals`; 0 after ``--seconds``; 1 when it served nobody
(no client came to ``--tcp`` within 30 s); 2 for bad settings.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import signal
import sys
from collections.abc import Sequence

from drivers.pty_link import PtyLink
from drivers.tracker_driver import add_command_options, commands_from_args
from service.base.addresses import host_port
from service.base.cli_args import float_range, int_range, output_problem, plain_help
from service.base.errors import HoloError
from service.base.signals import EXIT_FAILED, EXIT_RULE, EXIT_USAGE, exit_status, stop_on_signals
from sim_devices.dialbox import DEFAULT_SCRIPT, SCRIPTS, VIEW_DIALS, DialBoxSim
from sim_devices.endpoints import DeviceRunner, TcpLink, UdpLink
from sim_devices.faults import FaultSpec
from sim_devices.motion import MOTIONS, make_motion
from sim_devices.tracker import PROTOCOLS, TrackerSim

FAULT_HELP = ("comma-separated faults, e.g. 'corrupt=0.02,drop=0.01,truncate=0.01,"
              "burst=0.01,burst_len=4-40,wrong_baud=0.005,split,max_split=8,pause=0.01,"
              "pause_s=0.1,disconnect=0.001,reconnect_s=1,seed=3' (probabilities per frame)")


def _udp_arg(text: str) -> tuple[str, int]:
    """``--udp HOST:PORT`` (argparse prints the one-line reason)."""
    try:
        return host_port(text)
    except HoloError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (also used for ``--help``)."""
    p = argparse.ArgumentParser(
        prog="holo-sim", description="Simulated head tracker (Hatire or native protocol, "
        "or opentrack's UDP poses) or SGI dial and button box, served on a pty pair or a TCP "
        "port on 127.0.0.1 (opentrack: sent to --udp HOST:PORT).",
        epilog=plain_help("The first line on stdout is what a client opens (a /dev/pts "
                          "path or a socket:// URL); a JSON summary follows when the run "
                          "ends. " + EXIT_RULE + " 1: no client came to --tcp within "
                          "30 s."))
    p.add_argument("device", choices=("tracker", "dials"), help="which device to simulate")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--pty", action="store_true", help="serve on a pty pair (default)")
    where.add_argument("--tcp", type=int_range(0, 65535), metavar="PORT",
                       help="serve on 127.0.0.1:PORT (0 = any free port)")
    where.add_argument("--udp", type=_udp_arg, metavar="HOST:PORT",
                       help="tracker: send opentrack UDP poses to HOST:PORT (as opentrack's "
                       "'UDP over network' output does; implies --protocol opentrack)")
    p.add_argument("--pty-link", metavar="PATH",
                   help="keep a symlink at PATH to the current pty (survives reconnects)")
    p.add_argument("--protocol", choices=PROTOCOLS, default=None,
                   help="tracker protocol (default: opentrack with --udp, else hatire)")
    p.add_argument("--motion", metavar="NAME[:KEY=VALUE,...]", default="sway",
                   help=f"tracker motion: {', '.join(MOTIONS)}, options as "
                   "name:key=value,... (e.g. turn:amplitude=45, replay:file=log; "
                   "default: %(default)s)")
    p.add_argument("--noise", type=float_range(0), default=0.0, metavar="DEG",
                   help="Gaussian angle noise (std, degrees; position noise = 2.5x in mm)")
    p.add_argument("--rate", type=float_range(0, lo_open=True), default=60.0, metavar="HZ",
                   help="tracker frame rate (default: %(default)s)")
    p.add_argument("--byte-order", choices=("little", "big"), default="little",
                   help="Hatire byte order (default: %(default)s)")
    p.add_argument("--wait-start", action="store_true",
                   help="tracker waits for the host's start command before streaming "
                   "(again after each simulated unplug)")
    add_command_options(p)
    p.add_argument("--script", choices=tuple(SCRIPTS), default=DEFAULT_SCRIPT,
                   help="what the dial box plays: view turns only dials "
                   f"{VIEW_DIALS[0]}-{VIEW_DIALS[-1]} (no game binds them: it never steers "
                   "or pauses), random turns any dial and presses any button (the game's "
                   "pause too), none plays nothing (default: %(default)s)")
    p.add_argument("--enabled", action="store_true",
                   help="dial box reports without waiting for the init handshake")
    p.add_argument("--faults", metavar="FAULT[=V],...", default="", help=FAULT_HELP)
    p.add_argument("--seconds", type=float_range(0), default=None, metavar="N",
                   help="stop after N seconds of device time (default: until Ctrl-C; "
                   "dials: 30)")
    p.add_argument("--seed", metavar="N", type=int, default=0,
                   help="seed for motion, script and noise (default: %(default)s)")
    p.add_argument("--baud", type=int_range(1), default=None, metavar="N",
                   help="rate writes are paced to (default: 115200 tracker, 9600 dials)")
    p.add_argument("--no-pace", action="store_true",
                   help="do not pace writes to the baud rate")
    p.add_argument("--fast", action="store_true",
                   help="send frames as fast as possible instead of in real time")
    return p


def _link(args: argparse.Namespace) -> TcpLink | PtyLink | UdpLink:
    if args.udp is not None:
        return UdpLink(*args.udp)
    return TcpLink(args.tcp) if args.tcp is not None else PtyLink(args.pty_link)


def _protocol_problem(args: argparse.Namespace) -> str | None:
    """Fill in ``args.protocol``; a one-line problem when it and the link do not fit."""
    udp = args.udp is not None
    args.protocol = args.protocol or ("opentrack" if udp else "hatire")
    if udp and args.device != "tracker":
        return "--udp is for the tracker (opentrack's UDP poses)"
    if udp != (args.protocol == "opentrack"):
        return (f"--protocol {args.protocol} does not fit: opentrack poses go over UDP "
                "(--udp HOST:PORT), hatire and native over --pty or --tcp")
    return None


def _device(args: argparse.Namespace) -> TrackerSim | DialBoxSim:
    if args.device == "tracker":
        motion = make_motion(args.motion, args.seed, args.noise, 2.5 * args.noise)
        return TrackerSim(args.protocol, motion, args.rate, args.byte_order,
                          commands_from_args(args),
                          autostart=not args.wait_start)
    script = SCRIPTS[args.script](args.seed, args.seconds or 30.0)
    return DialBoxSim(script, enabled=args.enabled)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the simulator; returns the exit status (see the module docstring)."""
    args = build_parser().parse_args(argv)
    problem = output_problem(args.pty_link) if args.pty_link else None
    if problem:  # the link is made once the pty is open: a traceback there before
        print(f"holo-sim: --pty-link {problem}", file=sys.stderr)
        return EXIT_USAGE
    problem = _protocol_problem(args)
    if problem:
        print(f"holo-sim: {problem}", file=sys.stderr)
        return EXIT_USAGE
    try:
        device = _device(args)
        faults = FaultSpec.parse(args.faults)
        link = _link(args)
        pace = not args.no_pace and args.udp is None  # datagrams are not paced to a baud rate
        runner = DeviceRunner(device, link, faults, args.seconds, realtime=not args.fast,
                              pace=pace, baud=args.baud)
    except HoloError as exc:
        print(f"holo-sim: {exc}", file=sys.stderr)
        return EXIT_USAGE
    print(getattr(link, "path", link.name), flush=True)  # what a client opens
    signum, failure = None, None
    try:
        if isinstance(link, PtyLink):
            link.stop = runner.stop_event
        # SIGINT too: a KeyboardInterrupt would leave the stop event unset, and the pty
        # would then wait (up to 10 s) for a client to read what was queued
        with stop_on_signals(runner.stop_event) as got:
            try:
                runner.run()
            except HoloError as exc:  # e.g. no client came to --tcp (or the stop ended the wait)
                failure = exc
        signum = got.signum
    except KeyboardInterrupt:  # before the handler was in place
        signum = signal.SIGINT
        runner.stop_event.set()
    finally:
        with contextlib.suppress(HoloError, OSError):
            runner.poll_host()  # count host commands that came in at the very end
        link.drain()
        link.close()
    led = runner.ledger
    summary = {"bytes_sent": runner.bytes_sent, "frames": led.frames,
               "intact": len(led.intact), "faults": dict(led.counts)}
    if isinstance(device, TrackerSim):
        summary["commands"] = dict(device.received)
    print(json.dumps(summary), flush=True)
    if failure is not None and signum is None:
        print(f"holo-sim: {failure}", file=sys.stderr)
        return exit_status(None, EXIT_FAILED)  # it ran, but served nobody
    return exit_status(signum)


if __name__ == "__main__":
    sys.exit(main())
