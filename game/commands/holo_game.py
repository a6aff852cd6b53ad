"""``holo-game``: the holo-video dodge game (seed 000, chapter 5) as a service client.

::

    holo-game                                   # service on tcp://127.0.0.1:5555, a window
    holo-game --local                           # no service: in-process renderer
    holo-game --devices tcp://127.0.0.1:5560    # dial box, buttons and head tracker
    holo-game --local --bot --headless --seconds 20 --out demo-out

Every key, dial-box and gamepad binding is listed by ``holo-game --help``, made
from :mod:`game.actions`' tables.  The dial box's bound buttons have their lamps lit
when ``holo-devices --lamps`` is given ``holo-game --print-lamps``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from game.actions import binding_help, lamp_mask
from game.adapt import DEFAULT_LIGHT, LADDER, Choice, Look
from game.display import MODES, UNAVAILABLE, choose_mode, has_display, headless_env
from game.rules import DIFFICULTIES, GameSettings
from service.base.cli_args import (
    endpoint,
    float_range,
    int_range,
    output_problem,
    plain_help,
    size,
)
from service.base.errors import HoloError
from service.base.signals import (
    EXIT_FAILED,
    EXIT_OK,
    EXIT_RULE,
    EXIT_USAGE,
    Interrupted,
    interruptible,
    stop_on_signals,
)
from service.display import DisplaySettings
from service.frame_settings import FrameSettings
from service.lod.options import add_lod_options, lod_settings
from service.lookingglass import DEFAULT_VIEWS, Interleaver, parse_display
from service.process import setup_frame_process
from service.render.light import MODELS as LIGHT_MODELS
from service.render.light import LightSettings
from service.render.pipeline import RenderSettings

DEFAULT_SERVICE = "tcp://127.0.0.1:5555"
#: Pixels per zone without ``--size`` or ``--adapt``.
DEFAULT_SIZE = (200, 150)


def build_parser() -> argparse.ArgumentParser:
    """The command line."""
    p = argparse.ArgumentParser(
        prog="holo-game",
        description=plain_help(__doc__.split("\n\n")[0]),
        epilog=plain_help(binding_help({f"mode_{m}": "not available" for m in UNAVAILABLE}))
        + "\n\n" + EXIT_RULE
        + " 1: with --seconds, no frame came within --wait.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _add_connection_args(p)
    _add_display_args(p)
    _add_play_args(p)
    _add_output_args(p)
    _add_game_args(p)
    return p


def _add_connection_args(p: argparse.ArgumentParser) -> None:
    """Where the service and the devices are, or ``--local``."""
    p.add_argument("--service", default=DEFAULT_SERVICE, type=endpoint(bind=False),
                   metavar="ADDR",
                   help=f"holo-service control address (default {DEFAULT_SERVICE})")
    p.add_argument("--frames", default=None, type=endpoint(bind=False), metavar="ADDR",
                   help="frame stream address (default: from hello)")
    p.add_argument("--devices", default=None, type=endpoint(bind=False), metavar="ADDR",
                   help="holo-devices PUB address (input, head)")
    p.add_argument("--local", action="store_true", help="render in this process, no service")


def _add_play_args(p: argparse.ArgumentParser) -> None:
    """Who plays (``--bot``) and when the run stops."""
    p.add_argument("--bot", action="store_true", help="attract mode: the bot plays")
    p.add_argument(
        "--bot-gives-up",
        type=float_range(0),
        default=None,
        metavar="S",
        help="attract mode: the bot stops dodging after S game seconds",
    )
    p.add_argument(
        "--seconds",
        type=float_range(0, lo_open=True),
        default=None,
        metavar="N",
        help="stop after N seconds of play, counted from the first frame shown",
    )
    p.add_argument(
        "--games",
        type=int_range(1),
        default=None,
        metavar="N",
        help="stop once N games are over (the score screen of the Nth shown); with "
        "--seconds, whichever comes first",
    )
    p.add_argument(
        "--wait",
        type=float_range(0, lo_open=True),
        default=1200.0,
        metavar="S",
        help="with --seconds: give up when no frame came within S seconds (a service "
        "warming up on a first run compiles for minutes: 8 on a loaded 2-core machine; "
        "default 1200)",
    )


def _add_output_args(p: argparse.ArgumentParser) -> None:
    """Window, output folder, light and level of detail."""
    p.add_argument("--headless", action="store_true", help="SDL dummy video and audio")
    p.add_argument("--out", metavar="DIR", default=None,
                   help="write screenshots, film and stats.json here")
    p.add_argument("--light", choices=sorted(LIGHT_MODELS), default=None,
                   help="light model: per-zone Blinn-Phong or Phong, or flat ambient "
                   "silhouettes (thesis 5.1.1: the lightest load) (default: "
                   f"{DEFAULT_LIGHT}, the service's)")
    p.add_argument("--full-light", dest="light", action="store_const", const="blinn",
                   help="the same as --light blinn")
    p.add_argument("--adapt", action="store_true",
                   help="measure renders/s through the service (or --local) for a few "
                   "seconds and choose light and size from "
                   + ", ".join(str(look) for look in LADDER)
                   + ": the best that keeps 10 renders/s (not with --light or --size)")
    add_lod_options(p)


def _add_game_args(p: argparse.ArgumentParser) -> None:
    """The game's rules, attackers, high scores and the lamp mask."""
    p.add_argument("--difficulty", default="normal", choices=sorted(DIFFICULTIES),
                   help="the attackers' speed, how fast it grows and how near they may "
                   "come (default normal)")
    p.add_argument("--seed", metavar="N", type=int, default=0,
                   help="seed of the attackers' starts and the bot (default 0)")
    p.add_argument("--attackers", default=None, metavar="FILE",
                   help="attacker mesh file (.obj, .ply, .hobj)")
    p.add_argument("--highscores", default=str(Path.home() / ".holo-game-scores.json"),
                   metavar="FILE", help="the high-score table (default "
                   "~/.holo-game-scores.json)")
    p.add_argument("--name", default=os.environ.get("USER", "player"),
                   help="your name in the high scores (default $USER)")
    p.add_argument(
        "--shatter",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="service: game over loads the player in flying pieces (default on; "
        "--no-shatter flings the whole objects instead)",
    )
    p.add_argument(
        "--print-lamps",
        action="store_true",
        help="print the lamp mask for holo-devices --lamps and exit",
    )


def _add_display_args(p: argparse.ArgumentParser) -> None:
    """The display's options: mode, fixed zone, zones, size, refresh rate."""
    p.add_argument(
        "--mode",
        default="head",
        choices=[*MODES, *UNAVAILABLE],
        help="display mode (autostereogram: a random-dot stereogram of the depth)",
    )
    p.add_argument(
        "--zone",
        metavar="N",
        type=int,
        default=None,
        help="the fixed zone of --mode zone, 0 to --zones - 1 (default the middle one)",
    )
    p.add_argument("--zones", metavar="N", type=int_range(1, 64), default=None,
                   help="view zones, 1-64 (default 5; 45 with --display lookingglass:...)")
    p.add_argument(
        "--display", metavar="lookingglass:CALIBRATION.json", default=None,
        help="play on a Looking Glass: full screen at the panel's resolution, every view "
        "interleaved each refresh by the calibration (the device's visual.json), whose "
        "viewCone sets the viewing angle (--zones sets the view count, default 45)",
    )
    p.add_argument("--size", type=size, default=None, metavar="WxH",
                   help=f"pixels per zone (default: {DEFAULT_SIZE[0]}x{DEFAULT_SIZE[1]})")
    p.add_argument("--refresh", type=float_range(0, lo_open=True), default=60.0,
                   metavar="HZ", help="refresh rate, Hz (default 60)")


def check_args(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Check the arguments against each other; a bad one exits as argparse does (2).

    Fills in ``args.zone`` (the middle zone) when it was not given.
    """
    args.calibration = None
    if args.display is not None:
        try:
            args.calibration = parse_display(args.display, args.zones or DEFAULT_VIEWS)
        except HoloError as exc:
            parser.error(str(exc))
        args.zones = args.calibration.views
    args.zones = args.zones or 5
    if args.zones < 1:
        parser.error(f"--zones {args.zones}: the display needs at least one zone")
    if args.zone is None:
        args.zone = args.zones // 2
    elif not 0 <= args.zone < args.zones:
        parser.error(
            f"--zone {args.zone}: the display has {args.zones} zones, 0 to {args.zones - 1}"
        )
    if args.adapt and (args.light is not None or args.size is not None):
        parser.error("--adapt chooses the light and size itself: leave out --light, "
                     "--full-light and --size, or --adapt")
    args.light = args.light or DEFAULT_LIGHT
    args.size = args.size or DEFAULT_SIZE
    problem = output_problem(args.out, folder=True) if args.out else None
    if problem:
        parser.error(f"--out {problem}")


def _backend(args: argparse.Namespace, settings: object) -> object:
    # deferred: --help and usage errors answer before pygame and the numba kernels load
    from game.backends import LocalRenderer, ServiceBackend

    if args.local:
        return LocalRenderer(settings)
    return ServiceBackend(args.service, args.frames, args.devices, settings, shatter=args.shatter)


def _backend_settings(args: argparse.Namespace, look: Look) -> FrameSettings:
    """The backends' settings for ``look`` and the other arguments."""
    lod = lod_settings(args)
    cal = args.calibration
    angle = cal.view_cone if cal is not None else DisplaySettings.angle_deg
    display = DisplaySettings(zones=args.zones, angle_deg=angle, cols=look.size[0],
                              rows=look.size[1])
    render = RenderSettings(light=LightSettings(look.light), lod=lod)
    return FrameSettings(display, render, refresh_hz=args.refresh)


def _start(args: argparse.Namespace, look: Look, game: GameSettings) -> object:
    """A backend for ``look``, started on the game's scene as its first game begins."""
    # deferred: --help and usage errors answer before pygame and the numba kernels load
    from game.rules import new_game
    from game.scene import apply_states, attacker_mesh, game_scene, object_states
    from service.base.errors import ServiceError

    first = new_game(game)  # the scene starts as the first game does (no frame at the origin)
    scene = apply_states(game_scene(
        len(first.attackers),
        look.light != "ambient",
        attacker_mesh(args.attackers) if args.attackers else None,
    ), object_states(first))
    backend = _backend(args, _backend_settings(args, look))
    try:
        backend.start(scene)
    except ServiceError as exc:
        print(f"holo-game: service not reachable yet ({exc}); retrying (is holo-service "
              "running there? --local plays without it)", file=sys.stderr)
    return backend


def choose_look(args: argparse.Namespace, game: GameSettings) -> Choice:
    """``--adapt``: measure looks through the game's own backend and choose one."""
    # deferred: --help and usage errors answer before pygame and the numba kernels load
    from game.adapt import AdaptSettings, adapt, measure, with_background
    from game.bot import Bot
    from game.rules import new_game, tick
    from game.scene import object_states

    settings = AdaptSettings()
    background: list[dict | None] = [None]  # the service's background compile, last seen

    def measure_look(look: Look) -> float:
        state, bot = new_game(game), Bot()

        def step(dt: float) -> list[dict]:
            nonlocal state
            if tick(state, bot.act(state, dt), dt):
                state = new_game(game)  # a game over: the probe goes on with a new one
            return object_states(state)

        backend = _start(args, look, game)
        try:
            hz = measure(backend, step, settings.probe_s, args.wait, on_wait=_say_waiting,
                         busy=backend.compiling, on_busy=_say_busy,
                         windows=settings.windows, settle_s=settings.settle_s)
            background[0] = backend.background()
        finally:
            backend.close()
        print(f"holo-game: measured {look} per zone: {hz:.1f} renders/s", file=sys.stderr,
              flush=True)
        return hz

    print("holo-game: measuring this machine's renders/s to choose light and size "
          f"(needs {settings.need_hz:g}: {settings.target_hz:g} with a {settings.margin:g}x "
          "margin)", file=sys.stderr, flush=True)
    choice = with_background(adapt(measure_look, settings=settings), background[0])
    print(f"holo-game: chose {choice.reason}", file=sys.stderr, flush=True)
    return choice


def _say_busy(why: str) -> None:
    print(f"holo-game: {why}; measuring once it is done", file=sys.stderr, flush=True)


def _say_waiting(backend: object) -> None:
    # deferred: --help and usage errors answer before pygame and the numba kernels load
    from game.client_loop import waiting_lines

    warming = getattr(backend, "warming", None)
    what = ("waiting for the render service: " + waiting_lines(warming)[0]
            if warming is not None else "waiting for the first frame")
    print(f"holo-game: {what} (to measure)", file=sys.stderr, flush=True)


def _setup(args: argparse.Namespace) -> tuple:
    """Scene, backend, devices, window, high scores and beeper from the arguments.

    With ``--adapt`` the light and size are measured first (:func:`choose_look`);
    ``args.look`` keeps what was used and why (``stats.json``'s ``look``).
    """
    # deferred: --help and usage errors answer before pygame and the numba kernels load
    from game.display import GameWindow
    from game.highscores import HighScores
    from game.sound import start_pygame

    game = GameSettings(seed=args.seed, difficulty=args.difficulty)
    if args.adapt:
        choice = choose_look(args, game)
        args.light, args.size = choice.look.light, choice.look.size
        args.look = choice.as_dict()
    else:
        args.look = {"light": args.light, "size": list(args.size), "adapted": False,
                     "reason": "as given"}
    backend = _start(args, Look(args.light, tuple(args.size)), game)
    devices = None
    if args.devices:
        # deferred: --help and usage errors answer before pygame and the numba kernels load
        from drivers.subscriber import DeviceSubscriber

        devices = DeviceSubscriber(args.devices)
    beeper, no_sound, other = start_pygame(muted=args.headless)
    for line in other:
        print(line, file=sys.stderr)
    if no_sound is not None:
        print(f"holo-game: no sound device ({no_sound}): the beeps are muted", file=sys.stderr)
    cal = args.calibration
    window = GameWindow(panel=Interleaver(cal) if cal is not None else None)
    scores = HighScores.load(args.highscores, recover=True)
    if scores.recovered_from is not None:
        print(f"holo-game: {scores.recovered_from}; starting a new table", file=sys.stderr)
    return game, backend, devices, window, scores, beeper


def run(args: argparse.Namespace) -> dict:
    """Play (or let the bot play) until quit or ``--seconds``; returns the stats.

    The stats are also kept in ``args.stats``, written and closed down even when a
    signal (:func:`~service.base.signals.interruptible`) ends the game.
    """
    # deferred: --help and usage errors answer before pygame and the numba kernels load
    from game.capture import Capture
    from game.client_loop import GameClient, LoopSettings

    game, backend, devices, window, scores, beeper = _setup(args)
    loop = LoopSettings(
        game, args.mode, args.zone, args.bot, name=args.name, bot_gives_up=args.bot_gives_up,
        press_start=not args.headless,  # headless, no one could press SPACE
    )
    client = GameClient(backend, window, loop, devices, scores, beeper)
    start = time.monotonic()
    capture = Capture(args.out, start) if args.out else None
    cols, rows = args.size
    where = "in process" if args.local else f"by {args.service}"
    print(f"holo-game: started, {args.mode} mode, {args.zones} zones of {cols}x{rows} "
          f"rendered {where}", file=sys.stderr, flush=True)
    progress = Progress(args.seconds, start)

    def after_tick(c: GameClient) -> None:
        progress(c, capture)
        if games_over(c, args.games):
            c.quit = True

    stopped_by: Interrupted | None = None
    try:
        client.run(args.seconds, after_tick, args.wait if args.seconds is not None else None)
    except Interrupted as exc:
        stopped_by = exc
        raise
    finally:
        # a second signal (Ctrl-C reaches the demo too, which then sends SIGTERM) must
        # not cut the film and stats.json short: it waits until they are written
        with stop_on_signals(threading.Event()) as later:
            _finish(args, client, backend, devices, capture, start, stopped_by)
        if later.signum is not None and stopped_by is None:
            raise Interrupted(later.signum)
    return args.stats


def _finish(args: argparse.Namespace, client: Any, backend: Any, devices: Any, capture: Any,
            start: float, stopped_by: Interrupted | None) -> None:
    """Close down and write the run's files; the stats go to ``args.stats``."""
    # deferred: pygame (SDL) loads only where a window, pad or picture needs it
    import pygame

    stats = client.stats(client.played_s())
    stats["first_frame_s"] = (None if client.first_frame_t is None
                              else round(client.first_frame_t - start, 2))
    stats["look"] = args.look  # the light and size used, and why
    if stopped_by is not None:
        stats["interrupted"] = str(stopped_by)  # "SIGINT": what was written so far
    backend.close()
    if devices is not None:
        devices.close()
    if capture is not None:
        stats["files"] = [p.name for p in capture.finish()]
        (Path(args.out) / "stats.json").write_text(json.dumps(stats, indent=1))
    pygame.quit()
    args.stats = stats


def games_over(client: Any, games: int | None) -> bool:
    """Whether ``--games N`` is done: N games over, the last one's score screen shown.

    A condition, not a time: on a loaded machine the game runs slower than the wall
    clock (a tick advances it at most ``MAX_DT``), so a game over may come late.
    """
    over = client.over
    return (games is not None and len(client.scores) >= games and over is not None
            and over.phase == "score")


class Progress:
    """Lines on stderr as a run goes: waiting, first frame, play time, level-of-detail notes.

    Each level-of-detail note of the renderer is said once, as it comes.

    Parameters
    ----------
    seconds : float or None
        The run's play time (``--seconds``).
    start : float
        Monotonic clock reading at the start.
    every_s : float
        Seconds between lines.
    """

    def __init__(self, seconds: float | None, start: float, every_s: float = 5.0) -> None:
        self.seconds, self.start, self.every_s = seconds, start, every_s
        self._next = start + every_s
        self._first = False
        self._notes = 0  # the client's level-of-detail notes said so far

    def __call__(self, client: object, capture: object = None) -> None:
        """After each tick (calls ``capture(client)`` first when given)."""
        if capture is not None:
            capture(client)
        notes = getattr(client, "lod_notes", [])
        for _, note in notes[self._notes:]:
            print(f"holo-game: level of detail: {note}", file=sys.stderr, flush=True)
        self._notes = len(notes)
        now = time.monotonic()
        if client.first_frame_t is not None and not self._first:
            self._first = True
            self._next = now + self.every_s
            print(f"holo-game: first frame after {now - self.start:.1f} s; playing"
                  + (f" {self.seconds:g} s" if self.seconds else ""), file=sys.stderr, flush=True)
        if now < self._next:
            return
        self._next = now + self.every_s
        if client.first_frame_t is None:
            # deferred: --help and usage errors answer before pygame and the numba kernels load
            from game.client_loop import waiting_lines

            warming = getattr(client.backend, "warming", None)
            what = ("waiting for the render service: " + waiting_lines(warming)[0]
                    if warming is not None else "waiting for the first frame")
            print(f"holo-game: {what}", file=sys.stderr, flush=True)
        elif self.seconds:
            print(f"holo-game: playing {client.played_s():.0f}/{self.seconds:g} s",
                  file=sys.stderr, flush=True)


def _play(args: argparse.Namespace) -> int:
    # deferred: --help and usage errors answer before pygame and the numba kernels load
    from game.adapt import NoFrameError

    try:
        stats = run(args)
    except NoFrameError:  # while measuring for --adapt
        stats, args.seconds = {"first_frame_s": None}, args.wait
    if args.seconds is not None and stats.get("first_frame_s") is None:
        print(f"holo-game: no frame came within {args.wait:g} s; see the service's output",
              file=sys.stderr)
        return EXIT_FAILED
    return EXIT_OK


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``holo-game``; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    check_args(parser, args)
    args.mode, notice = choose_mode(args.mode)
    if notice:
        print(f"holo-game: {notice}", file=sys.stderr)
    setup_frame_process()  # heap reuse and one BLAS thread (service.process)
    if args.print_lamps:
        print(f"0x{lamp_mask():08x}")
        return 0
    if args.headless or not has_display():
        args.headless = True
        os.environ.update(headless_env({}))
    try:
        status = interruptible("holo-game", lambda: _play(args))
    except (HoloError, ValueError, OSError) as exc:
        print(f"holo-game: {exc}", file=sys.stderr)
        return EXIT_USAGE
    if getattr(args, "stats", None) is not None:
        print(json.dumps(args.stats))
    return status


if __name__ == "__main__":
    sys.exit(main())
