"""Forward a tracker's filtered poses as opentrack UDP datagrams (``--forward-opentrack``).

opentrack's own UDP input tracker ("UDP over network" as its input) takes the same
48-byte datagrams its UDP output sends, so our drivers can feed opentrack: its other
outputs (FreeTrack, TrackIR's NPClient, games, Wine) then follow a Hatire board, the
native protocol or a replayed session.  :class:`OpentrackForwarder` runs beside the
publisher on the reader's thread (:meth:`OpentrackForwarder.sink`): every pose goes
through a pose filter (:mod:`drivers.filters`, the service's ``alpha-beta`` by
default), optionally ahead by ``predict_ms``, angles wrapped to +/-180, and out as
one datagram (:func:`drivers.protocols.opentrack.encode_pose`: our axes and
millimetres into opentrack's axes and centimetres).  A status that reset the
decoder (a reconnect, a watchdog reopen) resets the filter too, so no velocity is
carried across an outage.  Positions are taken as millimetres (as the service
takes every tracker's).
"""

from __future__ import annotations

import socket
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from drivers.events import Event, PoseEvent, StatusEvent
from drivers.filters import FILTERS, make_filter, wrap_angles
from drivers.protocols.opentrack import encode_pose
from drivers.reader import Item, Sink
from service.base.errors import HoloError, SettingsError

#: The filter forwarded poses go through unless told otherwise (the service's).
DEFAULT_FILTER = "alpha-beta"


@dataclass(frozen=True)
class ForwardSettings:
    """Where forwarded poses go and how they are filtered.

    Parameters
    ----------
    host, port : str, int
        Destination of the datagrams (opentrack's UDP input listens on 4242).
    filter : str
        A :data:`drivers.filters.FILTERS` name.
    predict_ms : float
        Send the pose predicted this far ahead of the newest sample (>= 0).
    """

    host: str
    port: int
    filter: str = DEFAULT_FILTER
    predict_ms: float = 0.0

    def __post_init__(self) -> None:
        if self.filter not in FILTERS:
            raise SettingsError(f"unknown filter {self.filter!r}; known: {sorted(FILTERS)}")
        if not 0.0 <= self.predict_ms <= 1000.0:
            raise SettingsError("predict_ms must be in 0..1000")
        if not 1 <= self.port <= 65535:
            raise SettingsError(f"port {self.port} is not in 1-65535")


class OpentrackForwarder:
    """Filters poses and sends them as opentrack datagrams (see the module docstring).

    Attributes
    ----------
    sent, skipped, send_errors : int
        Datagrams sent; poses the filter refused (non-finite, out of order); sends
        that failed (no route: the datagram is lost, the next one is tried).
    """

    def __init__(self, settings: ForwardSettings) -> None:
        self.settings = settings
        self._filter = make_filter(settings.filter)
        self._lead_s = settings.predict_ms / 1000.0
        family = socket.AF_INET6 if ":" in settings.host else socket.AF_INET
        self._sock = socket.socket(family, socket.SOCK_DGRAM)
        self._to = (settings.host, settings.port)
        self.sent = self.skipped = self.send_errors = 0

    def forward(self, events: Iterable[Event]) -> None:
        """Send the filtered pose of one read's events (on the caller's thread).

        The poses of one read share its receive time, so only the newest goes through
        the filter (an older one at the same time would be refused as a duplicate).
        """
        newest: PoseEvent | None = None
        for ev in events:
            if isinstance(ev, PoseEvent):
                newest = ev
            elif isinstance(ev, StatusEvent) and ev.details.get("decoder_reset"):
                if newest is not None:
                    self._pose(newest)
                    newest = None
                self._filter.reset()
        if newest is not None:
            self._pose(newest)

    def _pose(self, ev: PoseEvent) -> None:
        sample = np.array([ev.x, ev.y, ev.z, ev.yaw, ev.pitch, ev.roll], float)
        try:
            self._filter.update_ns(ev.t_ns, sample)
        except HoloError:  # non-finite, or not after the last sample: the state is kept
            self.skipped += 1
            return
        x, y, z, yaw, pitch, roll = wrap_angles(self._filter.predict(self._lead_s))
        try:
            self._sock.sendto(encode_pose(x, y, z, yaw, pitch, roll), self._to)
        except OSError:
            self.send_errors += 1
            return
        self.sent += 1

    def sink(self, then: Sink | None = None) -> Sink:
        """A reader sink that forwards an item's poses at once, then calls ``then``."""

        def sink(item: Item, events: list[Event]) -> None:
            if events:
                self.forward(events)
            if then is not None:
                then(item, events)

        return sink

    def stats(self) -> dict[str, int]:
        """``sent``, ``skipped`` and ``send_errors``."""
        return {"sent": self.sent, "skipped": self.skipped, "send_errors": self.send_errors}

    def close(self) -> None:
        """Close the socket."""
        self._sock.close()
