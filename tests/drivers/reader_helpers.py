"""Helpers of the reader tests: a thread-safe event sink.

A module of its own (not ``conftest``) so test files import it by a name no other
test folder uses.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from drivers.events import PoseEvent, StatusEvent


class Collector:
    """A thread-safe sink keeping every item and event a reader hands it."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.items: list = []
        self.events: list = []

    def __call__(self, item, events) -> None:
        with self.lock:
            self.items.append(item)
            self.events.extend(events)

    def snapshot(self) -> list:
        with self.lock:
            return list(self.events)

    def seqs(self) -> list[int]:
        return [e.seq for e in self.snapshot() if isinstance(e, PoseEvent)]

    def status(self, name: str) -> list[StatusEvent]:
        return [e for e in self.snapshot() if isinstance(e, StatusEvent) and e.event == name]

    def poses_after(self, match: Callable[[StatusEvent], bool]) -> list[PoseEvent]:
        """Poses that came after the last status event matching ``match``."""
        events = self.snapshot()
        marks = [i for i, e in enumerate(events) if isinstance(e, StatusEvent) and match(e)]
        if not marks:
            return []
        return [e for e in events[marks[-1]:] if isinstance(e, PoseEvent)]
