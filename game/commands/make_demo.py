"""The whole loop (``make demo``): holo-service, holo-sim, holo-devices and holo-game.

Starts the render service, a simulated head tracker (swaying) and dial box
(its ``view`` script: turns of dials the game does not bind, so it never steers
or pauses) on pty pairs, the device driver publishing their
events (with the game's button lamps lit), and the game.  With a display the game
opens its window in attract mode until a key; without one the bot plays headless
for ``--seconds`` (20, counted from the first frame: on a first run the service
first compiles its kernels, a minute or more, while the game shows "waiting for the
render service") and writes screenshots of each mode, a film strip, a GIF and
``stats.json`` into a folder of its own, ``<--out>/<time>/`` (``demo-out/latest``
names the newest; :mod:`game.run_folders`), and a summary is printed.  Earlier runs'
folders are never touched.  Progress goes to stderr as it happens (processes
started, the service's warm-up n/m, play time).  Every process started here is
stopped at the end, on SIGINT (Ctrl-C) and SIGTERM (exit status 128 + the
signal's number), and when one of them fails (exit status 1); on a signal the
game is given :data:`GAME_GRACE_S` to write what it has, and the run's
``stats.json`` says ``"interrupted"``.  ``--local`` leaves the service out (the game
renders in process).

The look adapts to the machine: unless ``--light`` or ``--size`` is given, the game
runs ``holo-game --adapt`` (:mod:`game.adapt`): through the service it will play
through, it measures renders a second for a second and a half per look, from
per-zone Blinn-Phong light at 240x180 per zone (the system at its best: 19.8
renders/s on this project's quiet 2-core machine) down to flat ambient at 120x90,
and plays with the best look that keeps :data:`MEANT_HZ`'s 10 renders a second
with a margin.  The summary (stderr, and ``stats.json``'s ``look``) says what was
measured, what was chosen and why, and warns (exit status 1 when no frame came at
all) when the rates still fall below :data:`MEANT_HZ`.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

from game.actions import lamp_mask
from game.adapt import LADDER
from game.display import has_display, headless_env
from game.run_folders import new_run_folder, point_latest
from service.base.cli_args import float_range, plain_help, size
from service.base.errors import HoloError
from service.base.signals import (
    EXIT_FAILED,
    EXIT_RULE,
    Interrupted,
    end_process,
    exit_status,
    stop_on_signals,
)

ANY = "tcp://127.0.0.1:0"
#: Seconds the game has, once asked to stop, to write its film and stats.json.
GAME_GRACE_S = 30.0
#: The demo's look when only one of ``--light`` and ``--size`` is given: the best rung.
DEMO_LOOK = LADDER[0]
#: Rates the demo is meant to show (refreshes, renders per second); below: a warning.
MEANT_HZ = {"refresh_hz": 50.0, "update_hz": 10.0}
#: Seconds the game waits for its first frame (the service's first warm-up).
WAIT_S = 1200.0
#: Seconds between looks at a child while waiting for it.
POLL_S = 0.02


class Signals:
    """SIGINT and SIGTERM while the demo runs, caught by :func:`stop_on_signals`."""

    def __init__(self) -> None:
        self.events = {sig: threading.Event() for sig in (signal.SIGINT, signal.SIGTERM)}

    @contextlib.contextmanager
    def caught(self) -> Iterator[None]:
        """Within the block each signal only sets its event (no KeyboardInterrupt)."""
        with contextlib.ExitStack() as stack:
            for sig, event in self.events.items():
                stack.enter_context(stop_on_signals(event, (sig,)))
            yield

    def check(self) -> None:
        """Raise :class:`~service.base.signals.Interrupted` if a signal came."""
        for sig, event in self.events.items():
            if event.is_set():
                raise Interrupted(sig)


class Proc:
    """A child process whose output lines are collected by threads.

    Parameters
    ----------
    name : str
    args : list of str
    env : dict, optional
    check : callable, optional
        Called while waiting on the child; raises to stop waiting (a signal came).
    echo : callable, optional
        Called with each stderr line; lines it returns true for are shown on this
        process's stderr (progress).
    """

    def __init__(
        self,
        name: str,
        args: list[str],
        env: dict | None = None,
        check: Callable[[], None] = lambda: None,
        echo: Callable[[str], bool] = lambda line: False,
    ) -> None:
        self.name, self.check = name, check
        #: seconds it has to end after SIGTERM before it is killed
        self.grace_s = 5.0
        self.p = subprocess.Popen(
            args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env
        )
        self.out: list[str] = []
        self.err: list[str] = []
        pumps = ((self.p.stdout, self.out, None), (self.p.stderr, self.err, echo))
        for stream, lines, show in pumps:
            threading.Thread(target=_pump, args=(stream, lines, show), daemon=True).start()

    def wait_line(self, lines: list[str], pred: Callable[[str], bool], timeout: float) -> str:
        """The first line satisfying ``pred``, polled until ``timeout`` seconds pass."""
        deadline = time.monotonic() + timeout
        tick = threading.Event()
        while time.monotonic() < deadline:
            self.check()
            found = next((ln for ln in list(lines) if pred(ln)), None)
            if found is not None:
                return found
            if self.p.poll() is not None:
                break
            tick.wait(POLL_S)
        raise RuntimeError(f"{self.name} did not start (rc={self.p.poll()}): {self.err[-5:]}")

    def stop(self) -> None:
        """Terminate, then kill if it does not go within its ``grace_s`` seconds."""
        end_process(self.p, self.grace_s)


class Children:
    """The processes the demo started, stopped together.

    Parameters
    ----------
    check : callable
        Passed to every :class:`Proc` (a signal stops waits).
    """

    def __init__(self, check: Callable[[], None] = lambda: None) -> None:
        self.procs: list[Proc] = []
        self.check = check

    def start(
        self,
        name: str,
        args: list[str],
        env: dict | None = None,
        echo: Callable[[str], bool] = lambda line: False,
    ) -> Proc:
        """Start a child and keep it for :meth:`stop_all` (``echo``: see :class:`Proc`)."""
        proc = Proc(name, args, env, self.check, echo)
        self.procs.append(proc)
        return proc

    def wait_for(self, proc: Proc, timeout: float | None) -> int:
        """``proc``'s exit status; raises if another child exits first or time runs out.

        Raises
        ------
        RuntimeError
            Another child exited while ``proc`` ran (every child runs until stopped).
        subprocess.TimeoutExpired
        Interrupted
            From ``check``: a signal came.
        """
        deadline = None if timeout is None else time.monotonic() + timeout
        tick = threading.Event()
        while (rc := proc.p.poll()) is None:
            self.check()
            for other in self.procs:
                if other is not proc and other.p.poll() is not None:
                    self.check()  # a Ctrl-C reaches the children too: it is the signal
                    why = f"{other.name} exited {other.p.returncode} while {proc.name} ran"
                    raise RuntimeError(f"{why}: {other.err[-5:]}")
            if deadline is not None and time.monotonic() > deadline:
                raise subprocess.TimeoutExpired(proc.p.args, timeout)
            tick.wait(POLL_S)
        return rc

    def stop_all(self) -> None:
        """Stop every child, the last started first."""
        for proc in reversed(self.procs):
            proc.stop()


def _pump(stream: object, lines: list[str], echo: Callable[[str], bool] | None) -> None:
    for line in stream:
        lines.append(line.rstrip("\n"))
        if echo is not None and echo(lines[-1]):
            say(lines[-1])


def say(line: str) -> None:
    """One progress line on stderr, ``holo-demo: ...``."""
    print(f"holo-demo: {line}", file=sys.stderr, flush=True)


def mark_stopped(run: Path, why: dict) -> Path:
    """Add ``why`` (e.g. ``{"interrupted": "SIGINT"}``) to the run's ``stats.json``.

    The game's own stats.json is kept (it says how far the run got); where the game
    wrote none (stopped before its first frame, or killed), one is written with
    ``why`` and the files the run left.
    """
    path = run / "stats.json"
    try:
        stats = json.loads(path.read_text())
    except (OSError, ValueError):
        stats = {"files": sorted(p.name for p in run.iterdir() if p.name != "stats.json")}
    stats.update(why)
    temp = path.with_suffix(".json.tmp")
    temp.write_text(json.dumps(stats, indent=1))
    temp.replace(path)
    return path


def _service_progress(line: str) -> bool:
    return line.startswith("holo-service: ") and any(
        word in line for word in ("warming up", "ready", "stopped")
    )


def _game_progress(line: str) -> bool:
    return line.startswith("holo-game: ")


def _script(name: str) -> list[str]:
    return [sys.executable, "-m", name]


def start_devices(children: Children, seconds: float) -> str:
    """holo-sim tracker and dial box on ptys, holo-devices publishing; returns its address."""
    sim = _script("sim_devices.commands.holo_sim")
    tracker = children.start(
        "holo-sim tracker", [*sim, "tracker", "--pty", "--motion", "sway:scale=2"]
    )
    dials = children.start(
        "holo-sim dials",
        [*sim, "dials", "--pty", "--seconds", str(seconds + 30), "--seed", "1"],
    )
    t_path = tracker.wait_line(tracker.out, lambda ln: ln.startswith("/dev/"), 20)
    d_path = dials.wait_line(dials.out, lambda ln: ln.startswith("/dev/"), 20)
    devices = children.start(
        "holo-devices",
        [
            *_script("drivers.commands.holo_devices"),
            "--tracker", t_path,
            "--dials", d_path,
            "--pub", ANY,
            "--reset-wait", "0.5",
            "--lamps", hex(lamp_mask()),
        ],
    )  # fmt: skip
    line = devices.wait_line(devices.err, lambda ln: "publishing on" in ln, 20)
    say(f"devices: simulated tracker {t_path} and dial box {d_path}, events on {line.split()[-1]}")
    return line.split()[-1]


def start_service(children: Children, extra: Sequence[str] = ()) -> str:
    """holo-service on free ports (plus ``extra`` arguments); returns its control address."""
    say("starting holo-service")
    svc = children.start(
        "holo-service",
        [
            *_script("service.commands.holo_service"),
            "--control", ANY,
            "--frames", ANY,
            "--worker-address", ANY,
            *extra,
        ],
        echo=_service_progress,
    )  # fmt: skip
    line = svc.wait_line(svc.err, lambda ln: ln.startswith("holo-service: control"), 30)
    say(f"holo-service listening on {line.split()[2]}")
    return line.split()[2]


def game_args(
    args: argparse.Namespace, control: str | None, devices: str, headless: bool
) -> list[str]:
    """The holo-game command line."""
    cmd = [
        *_script("game.commands.holo_game"),
        "--devices", devices,
        *look_args(args),
        "--bot",
        "--highscores", str(Path(args.run) / "highscores.json"),
    ]  # fmt: skip
    cmd += ["--local"] if control is None else ["--service", control]
    if headless:
        cmd += [
            "--headless",
            "--seconds", str(args.seconds),
            "--out", str(args.run),
            "--bot-gives-up", str(args.gives_up),
            "--wait", str(args.wait),
        ]  # fmt: skip
    return cmd


def look_args(args: argparse.Namespace) -> list[str]:
    """The game's look options: ``--adapt``, or the light and size given (one filled in)."""
    if args.light is None and args.size is None:
        return ["--adapt"]
    size = args.size or DEMO_LOOK.size
    return ["--light", args.light or DEMO_LOOK.light, "--size", f"{size[0]}x{size[1]}"]


def build_parser() -> argparse.ArgumentParser:
    """The command line."""
    ap = argparse.ArgumentParser(
        prog="holo-demo", description=plain_help(__doc__.split("\n\n")[0]),
        epilog=EXIT_RULE + " 1: a program failed to start or stopped, or no frame came.")
    ap.add_argument("--out", default="demo-out", metavar="DIR",
                    help="each run writes screenshots, film and stats.json into a new "
                    "folder DIR/<time>/; DIR/latest names the newest (default demo-out)")
    ap.add_argument("--seconds", type=float_range(0, lo_open=True), default=20.0,
                    metavar="N", help="seconds of play, from the first frame (default 20)")
    ap.add_argument(
        "--wait",
        type=float_range(0, lo_open=True),
        default=WAIT_S,
        metavar="S",
        help="give up when the game shows no frame within S seconds (the service's "
        "first warm-up)",
    )
    ap.add_argument("--gives-up", type=float_range(0), default=6.0, metavar="S",
                    help="the bot stops dodging after S game seconds (default 6)")
    ap.add_argument("--light", choices=("blinn", "ambient"), default=None,
                    help="per-zone Blinn-Phong light, or flat ambient (default: chosen by "
                    "measuring, see --size)")
    ap.add_argument("--size", type=size, default=None, metavar="WxH",
                    help="pixels per zone (default: measured at the start; the best of "
                    + ", ".join(str(look) for look in LADDER)
                    + " that keeps 10 renders/s)")
    ap.add_argument("--local", action="store_true", help="no service: render in the game")
    ap.add_argument("--headless", action="store_true", help="even with a display")
    ap.add_argument(
        "--service-arg",
        action="append",
        default=[],
        metavar="ARG",
        help="one more holo-service argument (repeat it; write --service-arg=--workers=2)",
    )
    return ap


def run(args: argparse.Namespace, children: Children, headless: bool) -> int:
    """Start every process, wait for the game; returns the exit status (0 or 1)."""
    say("starting the simulated head tracker, dial box and holo-devices")
    devices = start_devices(children, args.seconds + args.wait)
    control = None if args.local else start_service(children, args.service_arg)
    env = headless_env() if headless else None
    say("starting holo-game" + (f" (the bot plays {args.seconds:g} s from the first frame)"
                                if headless else ""))
    game = children.start(
        "holo-game", game_args(args, control, devices, headless), env, echo=_game_progress
    )
    game.grace_s = GAME_GRACE_S
    rc = children.wait_for(game, None if not headless else args.seconds + args.wait + 120)
    if rc != 0:
        print(f"holo-demo: holo-game exited {rc}: {game.err[-5:]}", file=sys.stderr)
        return 1
    if headless:
        return _summary(args, control)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Run the whole loop; returns the exit status.

    Every child is stopped before returning: at the end, on SIGINT or SIGTERM
    (status 128 + the signal), and when one fails or exits early (status 1).
    """
    args = build_parser().parse_args(argv)
    headless = args.headless or not has_display()
    try:
        args.run = new_run_folder(args.out)
        point_latest(args.out, args.run)
    except HoloError as exc:
        print(f"holo-demo: {exc}", file=sys.stderr)
        return EXIT_FAILED
    say(f"writing to {args.run}/ ({Path(args.out) / 'latest'} names it; earlier runs are kept)")
    signals = Signals()
    children = Children(signals.check)
    with signals.caught():
        try:
            return run(args, children, headless)
        except Interrupted as exc:
            print(f"holo-demo: {exc}: stopping every process", file=sys.stderr)
            children.stop_all()
            if headless:
                kept = mark_stopped(args.run, {"interrupted": str(exc)})
                print(f"holo-demo: kept what the run wrote in {args.run}/ ({kept.name} says "
                      "interrupted)", file=sys.stderr)
            return exit_status(exc.signum)
        except (RuntimeError, subprocess.TimeoutExpired) as exc:
            print(f"holo-demo: {exc}; stopping every process", file=sys.stderr)
            return 1
        finally:
            children.stop_all()


def _summary(args: argparse.Namespace, control: str | None) -> int:
    """Print what the run did; 1 when no frame was shown at all, else 0."""
    out = args.run
    stats = json.loads((Path(out) / "stats.json").read_text())
    where = "in process (--local)" if control is None else f"holo-service at {control}"
    look = stats.get("look") or {}
    w, h = look.get("size", ("?", "?"))
    light = "per-zone Blinn-Phong light" if look.get("light") == "blinn" else \
        f"{look.get('light')} light"
    print(f"holo-demo: rendered {where}, {light} at {w}x{h} per zone")
    if look.get("adapted"):
        measured = ", ".join(f"{k} {v:g}" for k, v in look["measured"].items())
        print(f"  chosen by measuring renders/s ({measured}): {look['reason']}")
    print(
        f"  {stats['refreshes']} refreshes ({stats['refresh_hz']} Hz), {stats['renders']} "
        f"renders ({stats['update_hz']} Hz), window {stats['fps']} fps"
    )
    if stats.get("first_frame_s") is not None:
        print(f"  first frame {stats['first_frame_s']} s after the game started (the "
              f"service's warm-up); the rates count from it, over {stats['seconds']} s")
    print(f"  score {stats['score']} over {stats['games']} games, beeps {stats['beeps']}")
    print(f"  tracker poses {stats['tracker_events']}, dial-box events {stats['dial_events']}")
    missing = stats["modes_unavailable"]
    print(f"  modes {', '.join(stats['modes'])}"
          + (f" (unavailable: {', '.join(missing)})" if missing else ""))
    print(f"  wrote {', '.join(stats.get('files', []))} and stats.json to {out}/")
    for line in rate_warnings(stats):
        print(f"holo-demo: warning: {line}", file=sys.stderr)
    return 1 if not stats["refreshes"] else 0


def rate_warnings(stats: dict) -> list[str]:
    """Lines saying where the run's rates fell short of :data:`MEANT_HZ`."""
    if not stats["refreshes"]:
        return ["refreshes 0.0 Hz: the game never got a frame; see the holo-service and "
                "holo-game lines above"]
    low = [f"{stats[k]} {what}/s (meant: {MEANT_HZ[k]:g})"
           for k, what in (("refresh_hz", "refreshes"), ("update_hz", "renders"))
           if stats[k] < MEANT_HZ[k]]
    if not low:
        return []
    # only what the run did not already use
    look = stats.get("look") or {}
    light, (w, h) = look.get("light", "?"), look.get("size", (0, 0))
    lighter = [o for o, used in (("--light ambient", light == "ambient"),
                                 ("--size 160x120", (w, h) <= (160, 120))) if not used]
    hint = f"; {' or '.join(lighter)} lightens the load" if lighter else ""
    return [f"{' and '.join(low)} at {w}x{h} per zone: the machine is "
            f"busy or slower than two quiet cores{hint}"]


if __name__ == "__main__":
    sys.exit(main())
