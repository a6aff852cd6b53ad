"""Replay scheduling: hand out recorded items at their recorded timing, without drift.

Each item is scheduled against the replay's start, never against the previous
item: ``target = start + (t_item - t_first) / speed``.  A late wake-up (the OS
sleeps longer than asked, a slow consumer) therefore delays one item and is not
carried into the next, the fix python-can made to its ``MessageSync``.  The clock
and the sleep function are injected, so tests run on a fake clock with no real
sleeping.

The scheduler knows nothing about files or decoders: it takes any re-iterable of
items and a function giving each item's time in ns (``Record.t_ns`` by default).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Generic, TypeVar

from service.base.errors import SettingsError

T = TypeVar("T")

#: What happens to items before the skip point: dropped, or yielded at once.
SKIP_MODES = ("drop", "fast")


@dataclass(frozen=True)
class ReplaySettings:
    """How to replay.

    Parameters
    ----------
    speed : float
        Playback speed factor (2.0 plays twice as fast); > 0.
    as_fast_as_possible : bool
        Never sleep (equivalent to infinite speed).
    skip_s : float
        Start this many recorded seconds after the first item.
    skip_mode : {"drop", "fast"}
        Items before the skip point are dropped, or yielded without waiting
        (so a stateful decoder sees every byte).
    loop : bool
        Start again from the beginning after the last item (each pass follows
        the previous one's last target by ``loop_gap_s``).
    loop_gap_s : float
        Pause (real seconds) between passes.
    max_passes : int or None
        Stop after this many passes when looping (None: forever).
    """

    speed: float = 1.0
    as_fast_as_possible: bool = False
    skip_s: float = 0.0
    skip_mode: str = "drop"
    loop: bool = False
    loop_gap_s: float = 0.0
    max_passes: int | None = None

    def __post_init__(self) -> None:
        if not (self.speed > 0 and math.isfinite(self.speed)):
            raise SettingsError(f"speed must be a finite number > 0, not {self.speed}")
        if not (self.skip_s >= 0 and self.loop_gap_s >= 0):
            raise SettingsError("skip_s and loop_gap_s must be >= 0")
        if self.skip_mode not in SKIP_MODES:
            raise SettingsError(f"skip_mode must be one of {SKIP_MODES}, not {self.skip_mode!r}")
        if self.max_passes is not None and self.max_passes < 1:
            raise SettingsError(f"max_passes must be >= 1 or None, not {self.max_passes}")


@dataclass
class ReplayStats:
    """Timing quality of a replay so far.

    Attributes
    ----------
    items : int
        Items yielded.
    passes : int
        Passes started.
    max_late_ns : int
        Worst lateness: clock at hand-out minus target (0 when never late).
    sleeps : int
        Calls to the sleep function.
    """

    items: int = 0
    passes: int = 0
    max_late_ns: int = 0
    sleeps: int = 0


def _record_time(item: object) -> int:
    """Default time accessor: ``item.t_ns``."""
    return item.t_ns  # type: ignore[attr-defined]


class ReplayScheduler(Generic[T]):
    """Yield items at their recorded times, scheduled from a fixed start.

    Parameters
    ----------
    settings : ReplaySettings, optional
    clock_ns : callable () -> int
        Monotonic clock in ns; ``time.monotonic_ns`` by default.
    sleep : callable (float) -> None
        Sleeps for a number of seconds; ``time.sleep`` by default.
    time_of : callable (item) -> int
        Recorded time of an item in ns; ``item.t_ns`` by default.

    Attributes
    ----------
    stats : ReplayStats
    """

    def __init__(
        self,
        settings: ReplaySettings | None = None,
        *,
        clock_ns: Callable[[], int] = time.monotonic_ns,
        sleep: Callable[[float], None] = time.sleep,
        time_of: Callable[[T], int] = _record_time,
    ) -> None:
        self.settings = settings or ReplaySettings()
        self._clock = clock_ns
        self._sleep = sleep
        self._time_of = time_of
        self.stats = ReplayStats()
        self._stopped = False

    def stop(self) -> None:
        """Make the running :meth:`play` return before its next item."""
        self._stopped = True

    def play(self, items: Iterable[T]) -> Iterator[T]:
        """Yield ``items`` paced by their recorded times.

        Parameters
        ----------
        items : iterable
            Must be re-iterable (a list, a :class:`~drivers.recording.LogReader`)
            when looping.

        Yields
        ------
        item
            Each item once its target time has come.
        """
        s = self.settings
        self._stopped = False
        start_ns: int | None = None
        while not self._stopped:
            self.stats.passes += 1
            end_ns = yield from self._one_pass(items, start_ns)
            more = s.max_passes is None or self.stats.passes < s.max_passes
            if not (s.loop and more) or end_ns is None:
                return
            start_ns = end_ns + round(s.loop_gap_s * 1e9)

    def _one_pass(self, items: Iterable[T], start_ns: int | None) -> Iterator[T]:
        """One pass; returns the last target time (None if nothing was played)."""
        s = self.settings
        t_first: int | None = None
        target: int | None = None
        for item in items:
            if self._stopped:
                break
            t = self._time_of(item)
            t_first = t if t_first is None else t_first
            if t - t_first < s.skip_s * 1e9:
                if s.skip_mode == "fast":
                    self.stats.items += 1
                    yield item
                continue
            if target is None:  # first item played in this pass
                start_ns = self._clock() if start_ns is None else start_ns
                t_ref = t
            target = start_ns + round((t - t_ref) / s.speed)
            self._wait_until(target)
            self.stats.items += 1
            yield item
        return target

    def _wait_until(self, target_ns: int) -> None:
        """Sleep until ``target_ns`` (unless as fast as possible); track lateness."""
        if self.settings.as_fast_as_possible:
            return
        now = self._clock()
        while target_ns > now:  # a sleep may wake early: sleep again for the rest
            self.stats.sleeps += 1
            self._sleep((target_ns - now) * 1e-9)
            now = self._clock()
        self.stats.max_late_ns = max(self.stats.max_late_ns, now - target_ns)


def replay(
    items: Iterable[T],
    settings: ReplaySettings | None = None,
    **kwargs: object,
) -> Iterator[T]:
    """Shorthand for ``ReplayScheduler(settings, **kwargs).play(items)``."""
    return ReplayScheduler(settings, **kwargs).play(items)
