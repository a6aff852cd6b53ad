"""Simulated SGI dial and button box.

It answers the init handshake like the real box (0x20 for each reset), reports
dials and buttons only once they are enabled (``50``, ``71`` / ``73``), keeps the
lamp state (``75``, ``4B``, ``4C``) and dial filters (``53``), and plays a script
of turns and presses.  A dial turn of N counts is reported as ``steps`` packets
carrying the box's 16-bit counter (which wraps).
"""

from __future__ import annotations

import random
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from functools import partial

from drivers.protocols import sgi_dialbox as sgi
from service.base.errors import SettingsError


@dataclass(frozen=True)
class Turn:
    """At ``t`` s, turn dial ``dial`` by ``counts`` in ``steps`` reports over ``span_s``."""

    t: float
    dial: int
    counts: int
    steps: int = 4
    span_s: float = 0.04


@dataclass(frozen=True)
class Press:
    """At ``t`` s, press button ``button``; release it ``hold_s`` later."""

    t: float
    button: int
    hold_s: float = 0.1


Step = Turn | Press


#: Dials the ``view`` script turns: none of them is bound by the game (it steers with
#: dials 0-2 and its buttons move and pause), so the script shows the box alive in
#: ``holo-view`` and the event counts without playing the game.
VIEW_DIALS = (3, 4, 5, 6, 7)


def view_script(seed: int = 0, seconds: float = 5.0, rate_hz: float = 2.0) -> list[Step]:
    """A seeded script that only turns :data:`VIEW_DIALS`: no press, no steering."""
    rng = random.Random(seed)
    return [Turn(k / rate_hz, rng.choice(VIEW_DIALS), rng.choice((-1, 1)) * rng.randint(1, 30))
            for k in range(int(seconds * rate_hz))]


def no_script(seed: int = 0, seconds: float = 5.0) -> list[Step]:
    """Nothing: the box answers the host and reports only what a test turns."""
    return []


def demo_script(seed: int = 0, seconds: float = 5.0, rate_hz: float = 10.0) -> list[Step]:
    """A seeded script: turns of random dials and occasional presses of any button."""
    rng = random.Random(seed)
    steps: list[Step] = []
    n = int(seconds * rate_hz)
    for k in range(n):
        t = k / rate_hz
        if rng.random() < 0.8:
            steps.append(Turn(t, rng.randrange(8), rng.choice((-1, 1)) * rng.randint(1, 60)))
        else:
            steps.append(Press(t, rng.randrange(32), hold_s=0.5 / rate_hz))
    return steps


#: ``holo-sim dials --script NAME`` -> the script maker ``(seed, seconds) -> steps``.
SCRIPTS: dict[str, Callable[[int, float], list[Step]]] = {
    "view": view_script,
    "random": demo_script,
    "none": no_script,
}
#: The script a dial box plays unless asked otherwise: it never steers or pauses.
DEFAULT_SCRIPT = "view"


class DialBoxSim:
    """The box: host command handling, state, and scripted reports.

    Parameters
    ----------
    script : sequence of Turn / Press
        What the user does; times in seconds from the moment the box is enabled.
    enabled : bool
        Start with dials and buttons enabled (skip the handshake; for tests).
    """

    def __init__(self, script: Sequence[Step] = (), enabled: bool = False) -> None:
        self.script = sorted(script, key=lambda s: s.t)
        self.counters = [0] * sgi.NUM_DIALS
        self.lamps = 0
        self.filters = [0] * sgi.NUM_DIALS
        self.dial_mask = 0xFF if enabled else 0
        self.button_mask = 0xFFFFFFFF if enabled else 0
        self.auto_mask = 0xFFFFFFFF if enabled else 0
        self.resets = 0
        self._parser = sgi.SgiCommandParser()
        self._commands = {sgi.RESET: self._reset, sgi.ENABLE_DIALS: self._enable_dials,
                          sgi.ENABLE_BUTTONS: self._enable_buttons,
                          sgi.AUTO_BUTTONS: self._auto_buttons, sgi.SET_LAMPS: self._set_lamps,
                          sgi.LAMPS_ON: self._lamps_on, sgi.LAMPS_OFF: self._lamps_off,
                          sgi.SET_FILTER: self._set_filter}

    @property
    def baud(self) -> int:
        """9600."""
        return sgi.BAUD

    @property
    def streaming(self) -> bool:
        """True once some dial or button reports are enabled."""
        return bool(self.dial_mask or (self.button_mask & self.auto_mask))

    def lamp(self, index: int) -> bool:
        """Whether lamp ``index`` (0-31) is on."""
        return bool(self.lamps >> index & 1)

    def receive(self, data: bytes, t: float = 0.0) -> bytes:
        """Act on host command bytes; return the reply (0x20 per reset)."""
        return b"".join(self._commands[c](args) for c, args in self._parser.feed(data))

    def turn(self, dial: int, counts: int, steps: int = 1) -> list[bytes]:
        """Reports for turning ``dial`` by ``counts`` (empty if the dial is disabled)."""
        if not 0 <= dial < sgi.NUM_DIALS:
            raise SettingsError(f"dial {dial} not in 0..7")
        steps = max(1, min(steps, abs(counts) or 1))
        start = self.counters[dial]
        out = []
        for k in range(1, steps + 1):
            self.counters[dial] = start + counts * k // steps
            out.append(sgi.encode_dial(dial, self.counters[dial]))
        return out if self.dial_mask >> dial & 1 else []

    def button(self, index: int, pressed: bool) -> bytes:
        """The report for a press / release (b"" if not enabled and auto-reported)."""
        bit = 1 << index
        if self.button_mask & self.auto_mask & bit:
            return sgi.encode_button(index, pressed)
        return b""

    def frames(self, seconds: float | None = None) -> Iterator[tuple[float, Callable[[], bytes]]]:
        """``(t, make_report)`` of the script in time order; ``make_report()`` may give b""."""
        timeline: list[tuple[float, int, object]] = []
        for n, step in enumerate(self.script):
            if isinstance(step, Turn):
                for k in range(step.steps):
                    timeline.append((step.t + step.span_s * k / step.steps, n, (step, k)))
            else:
                timeline.append((step.t, n, (step, True)))
                timeline.append((step.t + step.hold_s, n, (step, False)))
        timeline.sort(key=lambda item: (item[0], item[1]))
        for t, _n, (step, arg) in timeline:
            if seconds is not None and t >= seconds:
                return
            yield t, partial(self._play, step, arg)

    def _play(self, step: Step, arg: object) -> bytes:
        if isinstance(step, Press):
            return self.button(step.button, bool(arg))
        k = int(arg)  # type: ignore[call-overload]
        share = step.counts * (k + 1) // step.steps - step.counts * k // step.steps
        if share == 0:
            return b""
        return b"".join(self.turn(step.dial, share))

    def _reset(self, args: bytes) -> bytes:
        self.resets += 1
        self.counters = [0] * sgi.NUM_DIALS
        self.dial_mask = self.button_mask = self.auto_mask = 0
        return bytes((sgi.RESET,))

    def _enable_dials(self, args: bytes) -> bytes:
        self.dial_mask = args[1]
        return b""

    def _enable_buttons(self, args: bytes) -> bytes:
        self.button_mask = int.from_bytes(args, "little")
        return b""

    def _auto_buttons(self, args: bytes) -> bytes:
        self.auto_mask = int.from_bytes(args, "little")
        return b""

    def _set_lamps(self, args: bytes) -> bytes:
        self.lamps = int.from_bytes(args, "little")
        return b""

    def _lamps_on(self, args: bytes) -> bytes:
        self.lamps = 0xFFFFFFFF
        return b""

    def _lamps_off(self, args: bytes) -> bytes:
        self.lamps = 0
        return b""

    def _set_filter(self, args: bytes) -> bytes:
        if args[0] < sgi.NUM_DIALS:
            self.filters[args[0]] = args[1] & 7
        return b""
