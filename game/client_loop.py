"""The game loop: input -> rules -> object states to the renderer -> frame in the window.

One :meth:`GameClient.tick` follows the thesis (section 5.3): overyet on the state
as last rendered; if over, the game-over sequence (three beeps, the spectacular
display, the score screen); otherwise the player's moves (keys, pad, dial box, or
the bot in attract mode), then the attackers move, then the new object states go
to the renderer backend (:mod:`game.backends`: the service or the in-process
renderer).  The newest frame is drawn in the current display mode with the HUD;
while the backend is unreachable the window says "reconnecting" and the game is
paused until the link is back.  While the service warms up (compiles its kernels
on a first run) the window says "waiting for the render service: compiling (n/m)".

Attract mode: the bot plays and games restart by themselves; a key or a gamepad
button that makes a move or starts hands the game to the player.  The dial box does
not (the simulated box of the demo plays a script; the bot ignores its input).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import pygame

from game import actions
from game.bot import Bot
from game.display import MODES, UNAVAILABLE, GameWindow, Hud, choose_mode, zone_for_head
from game.gameover import Beeper, GameOverSequence
from game.highscores import HighScores
from game.pads import Pads
from game.rules import MOVES, GameSettings, GameState, new_game, nudge, tick
from game.scene import object_states

MAX_DT = 0.1
#: Seconds a level-of-detail note stays in the HUD (the log has it for good), and
#: the characters of it the HUD shows.
NOTE_S, NOTE_CHARS = 10.0, 90


class RateMeter:
    """Events per second over a sliding window.

    Parameters
    ----------
    window_s : float
    """

    def __init__(self, window_s: float = 2.0) -> None:
        self.window_s = window_s
        self._times: deque[float] = deque()
        self.count = 0

    def add(self, t: float) -> None:
        """One event at ``t`` seconds."""
        self._times.append(t)
        self.count += 1

    def rate(self, now: float) -> float:
        """Events per second in the last window."""
        while self._times and self._times[0] < now - self.window_s:
            self._times.popleft()
        span = min(self.window_s, max(now - self._times[0], 1e-3)) if self._times else 1.0
        return len(self._times) / span if len(self._times) > 1 else 0.0


@dataclass
class LoopSettings:
    """How the loop runs.

    Attributes
    ----------
    game : GameSettings
    mode : str
        Initial display mode (:data:`game.display.MODES`); an unavailable one
        (:data:`game.display.UNAVAILABLE`) shows ``head`` with a notice in the HUD.
    zone : int
        The fixed zone of ``zone`` mode, 0 to the display's zones - 1.
    attract : bool
        The bot plays until a key is pressed.
    tick_hz : float
        Window frames (and game ticks) per second.
    name : str
        Name for the high-score table.
    bot_gives_up : float or None
        Attract mode: game seconds after which the bot stops dodging.
    """

    game: GameSettings = field(default_factory=GameSettings)
    mode: str = "head"
    zone: int = 2
    attract: bool = False
    tick_hz: float = 30.0
    name: str = "player"
    bot_gives_up: float | None = None


def waiting_lines(warming: dict) -> list[str]:
    """The waiting screen's lines for a service's warm-up progress (``docs/protocol.md``).

    Parameters
    ----------
    warming : dict
        ``phase`` (``compiling``, ``loading``...), ``done``, ``total``, ``elapsed_s``.
    """
    phase = str(warming.get("phase") or "compiling")
    done, total = warming.get("done", 0), warming.get("total", 0)
    first = f"{phase} ({done}/{total})" if total else phase
    elapsed = warming.get("elapsed_s")
    lines = [first + (f", {float(elapsed):.0f} s" if elapsed is not None else "")]
    return [
        *lines,
        "the first run compiles the renderer's kernels once",
        "the game starts when it is ready",
    ]


def _hud_note(note: str) -> str:
    """A level-of-detail note as a HUD line of at most :data:`NOTE_CHARS`.

    A longer one loses its middle (a cache path), keeping what failed and what is done.
    """
    line = f"level of detail: {note}"
    if len(line) <= NOTE_CHARS:
        return line
    head = (NOTE_CHARS - 3) // 2
    return line[:head] + "..." + line[len(line) - (NOTE_CHARS - 3 - head):]


class GameClient:
    """The game loop over a backend, a window and optional devices.

    Parameters
    ----------
    backend : object
        A started :mod:`game.backends` backend.
    window : GameWindow
    settings : LoopSettings
    devices : drivers.subscriber.DeviceSubscriber, optional
    highscores : HighScores, optional
    beeper : Beeper, optional
    clock : callable
        Seconds (monotonic).
    """

    def __init__(
        self,
        backend: Any,
        window: GameWindow,
        settings: LoopSettings,
        devices: Any = None,
        highscores: HighScores | None = None,
        beeper: Beeper | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.backend, self.window, self.settings = backend, window, settings
        self.devices, self.highscores = devices, highscores
        self.beeper = beeper or Beeper(muted=True)
        self.clock = clock
        self.attract = settings.attract
        self.bot = Bot(give_up_after=settings.bot_gives_up)
        zones = backend.settings.display.zones
        if not 0 <= settings.zone < zones:
            raise ValueError(
                f"zone {settings.zone} is not one of the display's {zones} zones (0 to {zones - 1})"
            )
        self.mode, self.notice = choose_mode(settings.mode)
        self.backend.sird_wanted = self.mode == "autostereogram"
        self.zone, self.head_zone = settings.zone, zones // 2
        self.state: GameState = new_game(settings.game)
        self.over: GameOverSequence | None = None
        self.games, self.seed = 1, settings.game.seed
        self._init_stats()
        self.pads = Pads()
        self.pads.open_all()
        self.quit = False
        #: clock reading when the first frame was shown (None before).
        self.first_frame_t: float | None = None
        self._hold_for_frame = False
        #: a new game waits for its first frame (the window says "get ready")
        self._get_ready = False
        self._last = clock()
        self._render_id = -1
        #: whether the last frame taken held the last render, and how many did
        self.held, self.held_frames = False, 0
        self._was_connected = backend.connected
        self._commands = self._command_table()
        backend.update(object_states(self.state))

    def _init_stats(self) -> None:
        """What the loop counts and keeps of the frames: scores, rates, the last images."""
        self.scores: list[int] = []
        self.modes_shown: set[str] = set()
        self.colour: np.ndarray | None = None
        self.sird: np.ndarray | None = None  # the frame's autostereogram, if it has one
        self.fps, self.refreshes, self.renders = RateMeter(), RateMeter(), RateMeter()
        self.latencies: deque[float] = deque(maxlen=600)
        self.dial_events = self.disconnects = 0
        #: (clock reading, note): the renderer's level-of-detail notes, each once
        self.lod_notes: list[tuple[float, str]] = []

    def _command_table(self) -> dict[str, Callable[[], None]]:
        """Input action name -> what it does (pause, quit, start, zone and mode changes)."""
        return {
            "pause": self._pause,
            "quit": self._quit,
            "start": self._start,
            "zone_prev": lambda: self._step_zone(-1),
            "zone_next": lambda: self._step_zone(1),
            **{f"mode_{m}": (lambda m=m: self.set_mode(m)) for m in (*MODES, *UNAVAILABLE)},
        }

    # ------------------------------------------------------------- commands
    def set_mode(self, mode: str) -> None:
        """Switch the display mode; an unavailable one keeps the current mode.

        The HUD then says the mode is not available, until a mode that can be shown
        is chosen.
        """
        self.mode, self.notice = choose_mode(mode, self.mode)
        self.backend.sird_wanted = self.mode == "autostereogram"

    def _pause(self) -> None:
        self.state.paused = not self.state.paused

    def _quit(self) -> None:
        self.quit = True

    def _start(self) -> None:
        if self.over is not None or self.attract:
            self.attract = False
            self.new_game()

    def _step_zone(self, step: int) -> None:
        self.zone = (self.zone + step) % self.backend.settings.display.zones

    def new_game(self) -> None:
        """A fresh game (the next seed), renders following it again."""
        self.games += 1
        self.seed += 1
        self.state = new_game(replace(self.settings.game, seed=self.seed))
        self.over = None
        self.bot = Bot(give_up_after=self.settings.bot_gives_up)
        self.backend.resume()
        self.backend.update(object_states(self.state))
        # the backend shows no frame of the game before; until the new game's first
        # one arrives the window is cleared and says "get ready"
        self.colour = self.sird = None
        self._get_ready = True

    # ---------------------------------------------------------------- input
    def read_input(self, dt: float) -> tuple[actions.Input, actions.Input]:
        """Input of one tick: (window keys and pad, dial box); notes the head's zone."""
        events = pygame.event.get()
        local = actions.from_pygame(events).merge(self.pads.read(events, dt))
        if self.devices is None:
            return local, actions.Input()
        self.devices.poll()
        taken = self.devices.take_events()
        self.dial_events += sum(1 for ev in taken if type(ev) in actions.DEVICE_HANDLERS)
        pose = self.devices.pose
        if pose is not None:
            self.head_zone = zone_for_head(pose.x, pose.z, self.backend.settings.display)
        return local, actions.from_devices(taken)

    def _human_takes_over(self, local: actions.Input) -> bool:
        """A key or pad button in attract mode (the dial box's script never takes over)."""
        return self.attract and any(a in MOVES or a == "start" for a in local.actions)

    # ----------------------------------------------------------------- tick
    def tick(self) -> None:
        """One iteration: input, rules, backend, window."""
        now = self.clock()
        dt = min(max(now - self._last, 0.0), MAX_DT)
        self._last = now
        local, dev = self.read_input(dt)
        if self._human_takes_over(local):
            self.attract = False
            self.new_game()
            local = actions.Input([a for a in local.actions if a not in MOVES and a != "start"])
        got = local if self.attract else local.merge(dev)  # the bot ignores the dial box
        for name in got.actions:
            if name in self._commands:
                self._commands[name]()
        if self.over is None:
            self._play(got, dt, now)
        else:
            self._game_over(now)
        self._take_frame(now)
        self._take_notes(now)
        self._draw(now)

    def _play(self, got: actions.Input, dt: float, now: float) -> None:
        if not self.backend.connected:
            return  # frozen while reconnecting
        if self._hold_for_frame and self.first_frame_t is None:
            return  # a timed run's game starts with its first frame too
        if self._get_ready:
            return  # so does a new game: nothing moves before the player can see it
        moves = [a for a in got.actions if a in MOVES]
        if self.attract:
            moves = self.bot.act(self.state, dt)
        if np.any(got.shift) and not self.attract:
            nudge(self.state, got.shift)
        if tick(self.state, moves, dt):
            self._begin_game_over(now)
        self.backend.update(object_states(self.state))

    def _begin_game_over(self, now: float) -> None:
        self.over = GameOverSequence(now)
        self.scores.append(self.state.score)
        if self.highscores is not None:
            name = "bot" if self.attract else self.settings.name
            self.highscores.add(
                name, self.state.score, self.state.t, self.state.settings.difficulty
            )

    def _game_over(self, now: float) -> None:
        for step in self.over.due(now):
            if step == "beep":
                self.beeper.beep()
            elif step == "explode":
                self.backend.explode(self.seed)
        if self.attract and self.over.finished(now):
            self.new_game()

    def _take_frame(self, now: float) -> None:
        period = 1.0 / self.settings.tick_hz
        wait = max(0.0, period - (self.clock() - now))
        frame = self.backend.frame(wait)
        if frame is None:
            return
        self._get_ready = False
        self.colour = frame.colour
        if self.first_frame_t is None:
            self.first_frame_t = now
        self.sird = frame.sird
        self.held = frame.held
        self.held_frames += frame.held
        self.refreshes.add(now)
        if frame.render_id != self._render_id:
            self._render_id = frame.render_id
            self.renders.add(now)
            if frame.latency_ms is not None:
                self.latencies.append(frame.latency_ms)
        if frame.zone is not None and self.devices is None:
            self.head_zone = int(frame.zone)

    def _take_notes(self, now: float) -> None:
        """The backend's new level-of-detail notes (a backend without them has none)."""
        take = getattr(self.backend, "lod_notes", None)
        if take is not None:
            self.lod_notes += [(now, note) for note in take()]

    # ----------------------------------------------------------------- draw
    def shown_zone(self) -> int:
        """The zone the current mode shows."""
        return self.head_zone if self.mode == "head" else self.zone

    def hud(self, now: float) -> Hud:
        """The HUD's contents now."""
        lines = ["attract mode: press a key to play"] if self.attract else []
        lines += [self.notice] if self.notice else []
        lines += [_hud_note(n) for t, n in self.lod_notes if now - t < NOTE_S]
        lat = float(np.median(self.latencies)) if self.latencies else None
        return Hud(
            self.state.score,
            self.state.t,
            self.fps.rate(now),
            self.renders.rate(now),
            self.refreshes.rate(now),
            lat,
            self.mode,
            self.shown_zone(),
            lines,
            held=self.held,
        )

    def _draw(self, now: float) -> None:
        if self.first_frame_t is not None:  # the window's rate counts from the first frame
            self.fps.add(now)
        self.modes_shown.add(self.mode)
        self.window.draw(self.colour, self.mode, self.shown_zone(), self.hud(now), self.sird)
        connected = self.backend.connected
        warming = getattr(self.backend, "warming", None)
        if not connected and warming is not None:
            self.window.banner("waiting for the render service", waiting_lines(warming))
        elif not connected:
            self.window.banner(
                "reconnecting",
                ["the render service does not answer", "the game resumes when it is back"],
            )
        elif self.over is not None and self.over.phase == "score":
            self.window.banner("GAME OVER", self._score_lines())
        elif self._get_ready:
            self.window.banner("GET READY", ["the game starts with its first frame"])
        elif self.state.paused:
            self.window.banner("paused", ["press P to go on"])
        self.disconnects += int(self._was_connected and not connected and warming is None)
        self._was_connected = connected
        self.window.flip()

    def _score_lines(self) -> list[str]:
        lines = [f"score {self.state.score}   ({self.state.t:.1f} s, {self.state.points} points)"]
        if self.highscores is not None:
            lines += ["", "high scores"]
            lines += [
                f"{k + 1:2d}. {e['name']:<8s} {e['score']:6d}"
                for k, e in enumerate(self.highscores.scores[:5])
            ]
        lines += ["", "press SPACE to play again" if not self.attract else ""]
        return lines

    # ------------------------------------------------------------------ run
    def run(
        self,
        seconds: float | None = None,
        after_tick: Callable[[GameClient], None] | None = None,
        wait_s: float | None = None,
    ) -> None:
        """Tick until quit or ``seconds`` pass; ``after_tick(self)`` after each.

        With ``wait_s`` the ``seconds`` count from the first frame shown (a service
        warming up may take minutes to send one), the game itself starts then too,
        and the run gives up when no frame came within ``wait_s``; without it they
        count from now.
        """
        start = self.clock()
        end = None if seconds is None or wait_s is not None else start + seconds
        self._hold_for_frame = wait_s is not None
        while not self.quit:
            now = self.clock()
            if end is None and seconds is not None and self.first_frame_t is not None:
                end = self.first_frame_t + seconds
            if end is not None and now >= end:
                break
            if self.first_frame_t is None and wait_s is not None and now - start >= wait_s:
                break
            self.tick()
            if after_tick is not None:
                after_tick(self)

    def played_s(self) -> float:
        """Seconds since the first frame shown (0 before it)."""
        return 0.0 if self.first_frame_t is None else self.clock() - self.first_frame_t

    def stats(self, elapsed_s: float) -> dict:
        """What the run did (the demo's ``stats.json``)."""
        elapsed = max(elapsed_s, 1e-9)
        return {
            "refreshes": self.refreshes.count,
            "renders": self.renders.count,
            "refresh_hz": round(self.refreshes.count / elapsed, 2),
            "update_hz": round(self.renders.count / elapsed, 2),
            "fps": round(self.fps.count / elapsed, 2),
            "score": max([*self.scores, self.state.score]),
            "scores": self.scores,
            "games": self.games,
            "modes": sorted(self.modes_shown),
            "modes_unavailable": sorted(UNAVAILABLE),
            "tracker_events": self.devices.pose_count if self.devices is not None else 0,
            "dial_events": self.dial_events,
            "beeps": self.beeper.count,
            "disconnects": self.disconnects,
            # frames of a scene replaced since (the game over's), not shown
            "stale_frames": getattr(self.backend, "stale_frames", 0),
            # frames that held the last render (none came within its use-by date)
            "held_frames": self.held_frames,
            # frames with no colour to draw (another client's set_display), not shown
            "unusable_frames": getattr(self.backend, "unusable_frames", 0),
            "latency_ms_p50": float(np.median(self.latencies)) if self.latencies else None,
            "lod_notes": [note for _, note in self.lod_notes],
            "seconds": round(elapsed_s, 2),
        }
