"""``holo-view``: watch a device publisher live (as python-can's ``can.viewer`` does).

Examples::

    holo-view                                   # tcp://127.0.0.1:5560, holo-devices --pub
    holo-view tcp://127.0.0.1:5560 --pose tcp://127.0.0.1:5561
    holo-view tcp://127.0.0.1:5560 --once --json          # one snapshot for a script
    holo-view tcp://127.0.0.1:5560 --json --count 100     # 100 snapshots, one per line

It subscribes to a ``holo-devices --pub`` (or ``holo-replay --pub``) stream and shows
the latest pose, the absolute value of the 8 dials, which of the 32 buttons are
held, the last dial, button and status events and the stream's counters.  On a
terminal the panel is redrawn in place (plain ANSI escapes) up to ``--rate`` times a
second; otherwise, and with ``--json``, each change gives one line: plain text, or a
JSON snapshot::

    {"t": 1.25, "address": "tcp://127.0.0.1:5560", "session": "3fa9c2d1",
     "pose": {"yaw": 10.5, "pitch": -2.25, "roll": 0.75, "x": 1.0, "y": 2.0, "z": 3.0,
              "seq": 417}, "poses": 417, "dials": [0, 0, 40, 0, 0, 0, 0, 0],
     "buttons": [3], "dials_seq": 12, "events": [{"device": "dials", "kind": "dial",
     "index": 2, "delta": 10, "value": 40}],
     "messages": 455, "gaps": 0, "malformed": 0}

``t`` is seconds since ``holo-view`` started, ``pose`` null until one came,
``buttons`` the indices held, ``events`` the dial / button / status events since the
previous snapshot (dump schema without ``t`` and ``turns``).  ``--once`` prints one snapshot once
something has arrived, ``--count N`` stops after N.

Exit status: 0 after ``--once`` / ``--count``; 1 when nothing arrived within
``--timeout`` seconds (default 10 with ``--once`` / ``--count``, else wait for ever);
2 for bad options; 130 / 143 after a clean stop on Ctrl-C / SIGTERM (the rule of
:mod:`service.base.signals`).
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from collections import deque
from collections.abc import Sequence
from typing import Any, TextIO

from drivers.events import Event
from drivers.subscriber import DeviceSubscriber
from service.base.addresses import default_address
from service.base.cli_args import endpoint, float_range, int_range, plain_help
from service.base.signals import (
    EXIT_FAILED,
    EXIT_OK,
    EXIT_RULE,
    EXIT_USAGE,
    exit_status,
    stop_on_signals,
)

#: Topics shown (the publisher's ``stats`` too).
TOPICS = (b"pose", b"dials", b"status", b"stats")
#: Events kept for the panel's "last events" lines.
RECENT = 6
POSE_KEYS = ("yaw", "pitch", "roll", "x", "y", "z", "seq")
# ANSI: cursor home, clear to end of line / of screen, hide / show the cursor
HOME, EOL, EOS, HIDE, SHOW = "\x1b[H", "\x1b[K", "\x1b[J", "\x1b[?25l", "\x1b[?25h"


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (also used for ``--help``)."""
    p = argparse.ArgumentParser(
        prog="holo-view",
        description="Show a holo-devices / holo-replay event stream live: the latest pose, "
        "dial values, held buttons and the last events.",
        epilog=plain_help(EXIT_RULE + " 1: nothing arrived within --timeout."))
    p.add_argument("address", nargs="?", default=default_address("devices"), metavar="ADDR",
                   type=endpoint(bind=False),
                   help="the publisher's address (default: %(default)s)")
    p.add_argument("--pose", metavar="ADDR", type=endpoint(bind=False),
                   help="take poses from this pose-only endpoint (holo-devices --pub-pose)")
    p.add_argument("--json", action="store_true", help="one JSON snapshot per line")
    stop = p.add_mutually_exclusive_group()
    stop.add_argument("--once", action="store_true",
                      help="print one snapshot once something arrived, then exit")
    stop.add_argument("--count", type=int_range(1), metavar="N",
                      help="exit after N snapshots")
    p.add_argument("--timeout", type=float_range(0, lo_open=True), metavar="S",
                   help="give up (exit 1) when nothing arrived within S seconds "
                   "(default: 10 with --once / --count, else wait for ever)")
    p.add_argument("--rate", type=float_range(0, 1000, lo_open=True), default=20.0,
                   metavar="HZ", help="most snapshots or redraws per second "
                   "(default: %(default)s)")
    web = p.add_argument_group("web view (--web: a running holo-service in a browser)")
    web.add_argument("--web", action="store_true",
                     help="serve a live page of a running holo-service instead: its frame "
                     "(zone, strip, quilt, depth, autostereogram), rates, stats, viewer pose "
                     "and warm-up, at http://HOST:PORT/")
    web.add_argument("--port", type=int_range(0, 65535), default=8080, metavar="NUMBER",
                     help="the web view's port (default: %(default)s; 0 picks a free one)")
    web.add_argument("--host", default="127.0.0.1", metavar="IP",
                     help="where the web view listens (default: %(default)s, loopback only)")
    web.add_argument("--service", type=endpoint(bind=False), metavar="ADDR",
                     default=default_address("control"),
                     help="the service's control address (default: %(default)s)")
    web.add_argument("--frames", type=endpoint(bind=False), metavar="ADDR",
                     default=default_address("frames"),
                     help="the service's frame stream (default: %(default)s)")
    return p


def run_web(args: argparse.Namespace) -> int:
    """``holo-view --web``: serve the page until Ctrl-C / SIGTERM; the exit status."""
    # deferred: --help and usage errors answer before pygame and the numba kernels load
    from service.web_view import WebSettings, serve

    settings = WebSettings(control=args.service, frames=args.frames, host=args.host,
                           port=args.port)
    try:
        server, watcher = serve(settings)
    except OSError as exc:
        print(f"holo-view: error: cannot listen on {args.host}:{args.port}: "
              f"{exc.strerror or exc}", file=sys.stderr)
        return EXIT_USAGE
    host, port = server.server_address[:2]
    print(f"holo-view: web view of {args.service} at http://{host}:{port}/ (Ctrl-C quits)",
          file=sys.stderr, flush=True)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    stop = threading.Event()
    with stop_on_signals(stop) as got:
        stop.wait()
    server.stopping.set()
    server.shutdown()
    server.server_close()
    watcher.stop()
    return exit_status(got.signum, EXIT_OK)


def event_dict(ev: Event) -> dict[str, Any]:
    """An event in the dump schema without ``t`` (the publisher's clock) and ``turns``.

    ``turns`` depends on the publisher's ``--dial-counts-per-turn``, which a
    subscriber does not know.
    """
    d = ev.to_dict()
    d.pop("t", None)
    d.pop("turns", None)
    return d


def snapshot(sub: DeviceSubscriber, events: list[Event], t: float) -> dict[str, Any]:
    """What the viewer shows, as one JSON-ready dict (keys: the module docstring)."""
    pose = None if sub.pose is None else {k: getattr(sub.pose, k) for k in POSE_KEYS}
    return {"t": round(t, 3), "address": sub.address, "session": sub.session,
            "pose": pose, "poses": sub.pose_count, "dials": list(sub.dials),
            "buttons": [i for i, held in enumerate(sub.buttons) if held],
            "dials_seq": sub.seq, "events": [event_dict(e) for e in events],
            "messages": sub.stats.messages, "gaps": sub.stats.gaps,
            "malformed": sub.stats.malformed}


def pose_text(pose: dict[str, Any] | None) -> str:
    """``yaw +10.50  pitch ...  #417``, or ``no pose yet``."""
    if pose is None:
        return "no pose yet"
    angles = "  ".join(f"{k} {pose[k]:+8.2f}" for k in ("yaw", "pitch", "roll"))
    place = "  ".join(f"{k} {pose[k]:+8.1f}" for k in ("x", "y", "z"))
    return f"{angles}   {place}   #{pose['seq']}"


def event_text(d: dict[str, Any]) -> str:
    """One event in words: ``dials dial 2 +10 -> 40``, ``tracker status reconnect {...}``."""
    kind = d["kind"]
    if kind == "dial":
        return f"dials dial {d['index']} {d['delta']:+d} -> {d['value']}"
    if kind == "button":
        return f"dials button {d['index']} {'pressed' if d['pressed'] else 'released'}"
    if kind == "pose":
        return f"tracker pose #{d['seq']}"
    return f"{d['device']} {kind} {d.get('event', '')} {json.dumps(d.get('details', {}))}"


def panel(snap: dict[str, Any], recent: Sequence[dict[str, Any]]) -> list[str]:
    """The terminal panel's lines for a snapshot and the last events."""
    buttons = set(snap["buttons"])
    row = "".join("#" if i in buttons else "." for i in range(32))
    held = ", ".join(map(str, snap["buttons"])) or "none"
    dials = "  ".join(f"{i}:{v:+6d}" for i, v in enumerate(snap["dials"]))
    lines = [
        f"holo-view  {snap['address']}  session {snap['session'] or '-'}  "
        f"messages {snap['messages']}  gaps {snap['gaps']}  malformed {snap['malformed']}",
        "",
        f"pose     {pose_text(snap['pose'])}   ({snap['poses']} poses)",
        f"dials    {dials}",
        f"buttons  {' '.join(row[i:i + 8] for i in range(0, 32, 8))}   held: {held}",
        "",
        "last events:",
    ]
    lines += [f"  {event_text(d)}" for d in recent] or ["  none yet"]
    return [*lines, "", "Ctrl-C to quit"]


def line_text(snap: dict[str, Any]) -> str:
    """A snapshot as one line of plain text (stdout not a terminal, no ``--json``)."""
    held = ",".join(map(str, snap["buttons"])) or "-"
    dials = " ".join(str(v) for v in snap["dials"])
    return f"t {snap['t']:.3f}  pose {pose_text(snap['pose'])}  dials {dials}  buttons {held}"


class Viewer:
    """Poll a subscriber and write snapshots (see the module docstring).

    Parameters
    ----------
    args : argparse.Namespace
    out : text stream
    live : bool
        Redraw a panel in place (a terminal) instead of writing lines.
    """

    def __init__(self, args: argparse.Namespace, out: TextIO, live: bool) -> None:
        self.args, self.out, self.live = args, out, live and not args.json
        self.stop = threading.Event()
        topics = TOPICS if args.pose is None else tuple(t for t in TOPICS if t != b"pose")
        self.sub = DeviceSubscriber(args.address, topics, pose_address=args.pose)
        self.recent: deque[dict[str, Any]] = deque(maxlen=RECENT)
        self.written = 0
        self.start = time.monotonic()

    def run(self) -> bool:
        """Show snapshots until stopped or done; False if nothing came within the timeout."""
        limit = 1 if self.args.once else self.args.count
        timeout = self.args.timeout or (10.0 if limit else None)
        period, seen, next_at = 1.0 / self.args.rate, 0, 0.0
        if self.live:
            self.out.write(HIDE + HOME + EOS)
            self._draw(snapshot(self.sub, [], 0.0))
        while not self.stop.is_set() and (limit is None or self.written < limit):
            self.sub.poll(min(period, 0.05))
            now = time.monotonic() - self.start
            if not self.sub.stats.messages:
                if timeout is not None and now > timeout:
                    return False
                continue
            if self.sub.stats.messages == seen or now < next_at:
                continue
            seen, next_at = self.sub.stats.messages, now + period
            self._show(snapshot(self.sub, self.sub.take_events(), now))
        return True

    def _show(self, snap: dict[str, Any]) -> None:
        self.written += 1
        self.recent.extend(snap["events"])
        if self.live:
            self._draw(snap)
        elif self.args.json:
            self.out.write(json.dumps(snap) + "\n")
        else:
            self.out.write(line_text(snap) + "\n")
        self.out.flush()

    def _draw(self, snap: dict[str, Any]) -> None:
        text = "".join(line + EOL + "\n" for line in panel(snap, list(self.recent)))
        self.out.write(HOME + text + EOS)
        self.out.flush()

    def close(self) -> None:
        """Close the subscriber; on a terminal show the cursor again."""
        self.sub.close()
        if self.live:
            self.out.write(SHOW)
            self.out.flush()


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``holo-view``; returns the exit status (see the module docstring)."""
    args = build_parser().parse_args(argv)
    if args.web:
        return run_web(args)
    viewer = Viewer(args, sys.stdout, live=sys.stdout.isatty())
    got_any = True
    try:
        with stop_on_signals(viewer.stop) as got:
            got_any = viewer.run()
    except BrokenPipeError:
        return EXIT_OK
    finally:
        viewer.close()
    if not got_any:
        print(f"holo-view: nothing from {args.address} within {viewer.args.timeout or 10:g} s "
              "(is holo-devices --pub or holo-replay --pub running there?)", file=sys.stderr)
    return exit_status(got.signum, EXIT_OK if got_any else EXIT_FAILED)


if __name__ == "__main__":
    sys.exit(main())
