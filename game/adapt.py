"""Choose the zone size and light from a short measurement at start (``holo-game --adapt``).

The demo (``make demo``) and ``holo-game --adapt`` do not trust a fixed look: on a
busy machine (another program on one core) the demo's lit 240x180 zones fell to
1.4-6.7 renders a second, under the 10 it aims for.  So, before play, the game's own
backend (the service it will play through, or ``--local``'s renderer) renders the
game's scene with its objects moving for :attr:`AdaptSettings.probe_s` seconds per
look (after :attr:`AdaptSettings.settle_s`, the median rate of
:attr:`AdaptSettings.windows` windows: one 1.5 s count measured 5.3, 7.3 and 10.7
renders/s for the same look in three cold demos), and the game plays with the best
look of :data:`LADDER` whose measured rate leaves a margin over the target (when none
does, the lightest look measured).  A look that met the target and predicts that a
better one would too has that one measured (again, at most once): a short count
does not cost the run its look.

The choice (:func:`choose`) and the order of measurements (:func:`next_probe`) are
pure functions of the measurements, tested on given numbers; :func:`measure` is the
only part that touches a backend.  Render time grows with the pixels per zone (the
demo's renders/s times pixels stayed within 6 % from 240x180 to 320x240) and is
lower in ambient light (:data:`LIGHT_COST`), so after a look falls short the next
one measured is the first that this cost model predicts to meet the target, not
the next rung.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

from service.base.errors import HoloError
from service.render.light import LightSettings

#: The service's default light model (one source: :class:`service.render.light.LightSettings`).
DEFAULT_LIGHT = LightSettings.model


class NoFrameError(HoloError):
    """No frame came within the wait while measuring (the service never got ready)."""


@dataclass(frozen=True)
class Look:
    """A light model and a size per zone.

    Attributes
    ----------
    light : str
        ``ambient``, ``phong`` or ``blinn``.
    size : tuple of 2 ints
        (cols, rows) per zone.
    """

    light: str
    size: tuple[int, int]

    @property
    def pixels(self) -> int:
        """Pixels per zone."""
        return self.size[0] * self.size[1]

    @property
    def cost(self) -> float:
        """Relative render time: pixels times :data:`LIGHT_COST`."""
        return self.pixels * LIGHT_COST.get(self.light, 1.0)

    def __str__(self) -> str:
        return f"{self.light} {self.size[0]}x{self.size[1]}"


#: Render time relative to Blinn-Phong: the game's scene at 160x120 in 5 zones took
#: 66.5 ms of CPU per render in ambient light against 83.5 ms lit (medians of 20,
#: interleaved, on a loaded 2-core machine).
LIGHT_COST = {"ambient": 0.8, "phong": 1.0, "blinn": 1.0}
#: Looks best first, each a lighter load than the one before: lit at three sizes,
#: then flat ambient (thesis 5.1.1) at two.
LADDER: tuple[Look, ...] = (
    Look(DEFAULT_LIGHT, (240, 180)),
    Look(DEFAULT_LIGHT, (200, 150)),
    Look(DEFAULT_LIGHT, (160, 120)),
    Look("ambient", (160, 120)),
    Look("ambient", (120, 90)),
)


@dataclass(frozen=True)
class AdaptSettings:
    """How the look is chosen.

    Attributes
    ----------
    target_hz : float
        Renders a second the run must keep.
    margin : float
        A look is taken when it measured ``margin`` times the target: the game's
        own drawing and the load's ups and downs take some.
    probe_s : float
        Seconds of renders counted per look, after its first frame and ``settle_s``.
    windows : int
        The counted seconds are cut into this many equal windows and the look's rate
        is the median of theirs (:func:`median_rate`): one window slowed by a burst
        of other work, or sped up by a lull, does not decide.
    settle_s : float
        Seconds after a look's first frame that are not counted: its first renders
        pay for loading the scene at the new size (buffers, level-of-detail chains).
    max_probes : int
        Looks measured at most.
    """

    target_hz: float = 10.0
    margin: float = 1.3
    probe_s: float = 3.0
    windows: int = 3
    settle_s: float = 0.5
    max_probes: int = 3

    @property
    def need_hz(self) -> float:
        """Renders a second a look must measure to be taken."""
        return self.target_hz * self.margin


@dataclass(frozen=True)
class Choice:
    """The look chosen, and why.

    Attributes
    ----------
    look : Look
    measured : tuple of (Look, float)
        Renders a second of each look measured, in the order measured.
    met : bool
        The look measured at least :attr:`AdaptSettings.need_hz`.
    reason : str
        One line: what was measured and why this look.
    background : dict, optional
        The service's background compile as the last measurement ended (``stats``'
        ``compile``: ``phase``, ``done``, ``total``, ``priority``), when it had one.
    """

    look: Look
    measured: tuple[tuple[Look, float], ...]
    met: bool
    reason: str
    background: dict | None = None

    def as_dict(self) -> dict:
        """For ``stats.json``: light, size, adapted, met, measured (renders/s), reason.

        With ``background_compile`` too when the service had a background compile.
        """
        out = {
            "light": self.look.light,
            "size": list(self.look.size),
            "adapted": True,
            "met": self.met,
            "measured": {str(look): round(hz, 2) for look, hz in self.measured},
            "reason": self.reason,
        }
        if self.background is not None:
            out["background_compile"] = dict(self.background)
        return out


def with_background(choice: Choice, background: dict | None) -> Choice:
    """``choice`` with the service's background compile during the measurement, and why.

    Parameters
    ----------
    choice : Choice
    background : dict or None
        ``stats``' ``compile`` as the last measurement ended (:mod:`service.readiness`).

    Returns
    -------
    Choice
        With :attr:`Choice.background` set and the reason saying what ran beside the
        measurement, when a background compile ran at all.
    """
    if not background or background.get("phase") in (None, "none"):
        return choice
    done, total = background.get("done", "?"), background.get("total", "?")
    priority = background.get("priority", "low priority")
    if background.get("phase") != "compiling":
        note = f"the service's background compile had ended ({background.get('phase')})"
    elif priority == "idle":
        note = (f"measured beside the service's background compile ({done} of {total} jobs) "
                "at idle priority: it takes only CPU time nothing else wants")
    else:
        note = (f"measured beside the service's background compile ({done} of {total} jobs) "
                f"at {priority}")
    return replace(choice, reason=f"{choice.reason}; {note}", background=dict(background))


def predicted_hz(measured: dict[Look, float], look: Look, base: Look | None = None) -> float:
    """The rate ``look`` should reach from ``base`` (default: the lightest look measured)."""
    base = min(measured, key=lambda m: m.cost) if base is None else base
    return measured[base] * base.cost / look.cost


def next_probe(
    ladder: tuple[Look, ...], measured: dict[Look, float], settings: AdaptSettings,
    retried: frozenset[Look] = frozenset(),
) -> Look | None:
    """The next look to measure; None when :func:`choose` can decide.

    The first rung comes first; after a shortfall, the best untried look lighter
    than every one measured that is predicted (:func:`predicted_hz`) to meet the
    need, else the lightest untried one.  Once a look meets the need, a better one
    that it predicts to meet as well is measured (:func:`_recheck`): one short count
    (a burst of other work, the first renders of a cold service) does not cost the
    whole run its look.  ``retried`` are the looks measured twice; they are not
    measured again, and they count against ``max_probes``.
    """
    if len(measured) + len(retried) >= settings.max_probes:
        return None
    if any(hz >= settings.need_hz for hz in measured.values()):
        return _recheck(ladder, measured, settings, retried)
    if not measured:
        return ladder[0]
    lightest = min(m.cost for m in measured)
    below = [look for look in ladder if look not in measured and look.cost < lightest]
    if not below:
        return None
    meets = [look for look in below if predicted_hz(measured, look) >= settings.need_hz]
    return meets[0] if meets else below[-1]


def _recheck(
    ladder: tuple[Look, ...], measured: dict[Look, float], settings: AdaptSettings,
    retried: frozenset[Look],
) -> Look | None:
    """The best look above the best one that met which that one predicts to meet, if any.

    A look is measured at most twice (``retried``: those measured twice).
    """
    best = next(look for look in ladder if measured.get(look, 0.0) >= settings.need_hz)
    for look in ladder[:ladder.index(best)]:
        if look not in retried and predicted_hz(measured, look, best) >= settings.need_hz:
            return look
    return None


def choose(
    ladder: tuple[Look, ...], measured: dict[Look, float], settings: AdaptSettings
) -> Choice:
    """The best look that measured the need, else the lightest measured, with the reason.

    Raises
    ------
    ValueError
        Nothing was measured.
    """
    if not measured:
        raise ValueError("no look was measured")
    order = tuple(measured.items())
    need = settings.need_hz
    why = f"{settings.target_hz:g} renders/s needed with a {settings.margin:g}x margin"
    meets = [look for look in ladder if measured.get(look, 0.0) >= need]
    short = [f"{look} {hz:.1f}" for look, hz in order if hz < need]
    if meets:
        look = meets[0]
        reason = (f"{look}: {measured[look]:.1f} renders/s measured ({why})"
                  + (f"; too few at {', '.join(short)}" if short else ""))
        return Choice(look, order, True, reason)
    # the lightest: on a busy machine one 1.5 s measurement can be off by 3x or more
    # (load 14 on 2 cores: 12.6 then 2.7 renders/s for the same look), the cost is not
    look = min(measured, key=lambda m: m.cost)
    reason = (f"{look}: the lightest measured ({', '.join(short)} renders/s), none reached "
              f"{need:g} ({why}): the machine is busy")
    return Choice(look, order, False, reason)


def adapt(
    measure_look: Callable[[Look], float],
    ladder: tuple[Look, ...] = LADDER,
    settings: AdaptSettings | None = None,
) -> Choice:
    """Measure looks (``measure_look(look)`` -> renders/s) as :func:`next_probe` says; choose."""
    settings = settings or AdaptSettings()
    measured: dict[Look, float] = {}
    first: dict[Look, float] = {}  # the first count of a look measured again
    while (look := next_probe(ladder, measured, settings, frozenset(first))) is not None:
        if look in measured:
            first[look] = measured[look]
        measured[look] = measure_look(look)
    choice = choose(ladder, measured, settings)
    if not first:
        return choice
    again = ", ".join(f"{look} {first[look]:.1f} then {measured[look]:.1f}" for look in first)
    return replace(choice, reason=f"{choice.reason}; measured again: {again}")


def measure(
    backend: object,
    step: Callable[[float], list[dict]],
    probe_s: float,
    wait_s: float,
    on_wait: Callable[[object], None] = lambda backend: None,
    clock: Callable[[], float] = time.monotonic,
    tick_s: float = 1 / 30,
    busy: Callable[[], str | None] = lambda: None,
    busy_wait_s: float = 180.0,
    on_busy: Callable[[str], None] = lambda why: None,
    windows: int = 1,
    settle_s: float = 0.0,
) -> float:
    """Renders a second a started backend grafts while the objects move.

    A rate measured while the service compiles kernels in the background (on the
    same cores) is not the machine's: while ``busy()`` says so, frames are taken but
    not counted, for at most ``busy_wait_s`` seconds (then counted anyway).

    Parameters
    ----------
    backend : object
        A :mod:`game.backends` backend, started on the game's scene.
    step : callable
        ``step(dt)`` -> the objects' states ``dt`` seconds on (the game's rules).
    probe_s : float
        Seconds counted, from the first frame of a render.
    wait_s : float
        Seconds to wait for that first frame (a service warming up).
    on_wait : callable
        Called about every 5 s while waiting (progress).
    busy : callable
        ``busy()`` -> why not to count yet (a line, e.g. a background compile's
        progress), or None; asked about once a second once frames come.
    busy_wait_s : float
        Seconds to wait for ``busy`` to end before counting anyway.
    on_busy : callable
        ``on_busy(why)`` about every 5 s while ``busy`` holds the count back.
    windows : int
        ``probe_s`` is cut into this many windows; the rate is their median
        (:func:`median_rate`).
    settle_s : float
        Seconds after the first counted frame left out before ``probe_s`` begins.

    Returns
    -------
    float
        Distinct renders shown per second (the median of the windows').

    Raises
    ------
    NoFrameError
        No frame came within ``wait_s``.
    """
    start = last = clock()
    first: float | None = None
    seen: dict[int, float] = {}  # render id -> when it was first shown
    next_say = start + 5.0
    gate = _BusyGate(busy, busy_wait_s, on_busy)
    while True:
        now = clock()
        if first is None and now - start > wait_s + gate.waited_s:
            raise NoFrameError(f"no frame came within {wait_s:g} s")
        if first is not None and now - first >= settle_s + probe_s:
            return median_rate(list(seen.values()), first + settle_s, probe_s, windows)
        if first is None and gate.since is None and now >= next_say:  # (the gate says its own)
            next_say = now + 5.0
            on_wait(backend)
        backend.update(step(min(now - last, 0.1)))
        last = now
        frame = backend.frame(tick_s)
        if frame is not None and frame.render_id >= 0 and gate.clear(now):
            first = now if first is None else first
            seen.setdefault(frame.render_id, now)


def median_rate(shown_at: list[float], start: float, span_s: float, windows: int = 1) -> float:
    """Renders a second: the median over ``windows`` equal windows of ``span_s`` from ``start``.

    Parameters
    ----------
    shown_at : list of float
        When each distinct render was first shown (seconds, the clock of ``start``).
    start : float
        Start of the first window; a render shown at ``start`` exactly is not
        counted (it was already there when counting began).
    span_s : float
        Seconds of all windows together.
    windows : int
        Windows; with one, the plain rate over ``span_s``.

    Returns
    -------
    float
        The median of the windows' renders a second.
    """
    width = span_s / windows
    counts = [0] * windows
    for t in shown_at:
        if start < t <= start + span_s:
            counts[min(int((t - start) / width), windows - 1)] += 1
    return statistics.median(counts) / width


class _BusyGate:
    """Holds a measurement back while ``busy()`` names a reason, up to ``limit_s``."""

    def __init__(self, busy: Callable[[], str | None], limit_s: float,
                 say: Callable[[str], None]) -> None:
        self.busy, self.limit_s, self.say = busy, limit_s, say
        self.since: float | None = None
        self.waited_s = 0.0
        self._next_ask = self._next_say = float("-inf")
        self._open = False

    def clear(self, now: float) -> bool:
        """True once nothing holds the count back (asked at most once a second)."""
        if self._open:
            return True
        if now < self._next_ask:
            return False
        self._next_ask = now + 1.0
        self.since = now if self.since is None else self.since
        self.waited_s = now - self.since
        why = self.busy()
        if why is None or self.waited_s >= self.limit_s:
            self._open = True
            return True
        if now >= self._next_say:
            self._next_say = now + 5.0
            self.say(why)
        return False
