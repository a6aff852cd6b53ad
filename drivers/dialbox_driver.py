"""SGI dial and button box driver: the init handshake, re-initialisation, lamps.

:class:`DialBoxDriver` plugs into a :class:`~drivers.reader.DeviceReader` as its
hooks.  Each time the port opens (the first time and after every reconnect) it runs
VRPN's handshake (:func:`drivers.protocols.sgi_dialbox.init_sequence`): reset twice,
wait for the box's ``0x20`` answer (at most ``reset_wait_s``), enable the dials, then
enable and auto-report the buttons, twice.  It re-sends the lamp state afterwards,
since a reset box has its lamps off.  When the decoder reports garbage with
``details.action == "reinit"`` it emits an ``info`` status (``message: "reinit"``,
which resets the decoder) and runs the handshake again.

Lamps are set from any thread (:meth:`DialBoxDriver.set_lamps`,
:meth:`~DialBoxDriver.set_lamp`, :meth:`~DialBoxDriver.all_lamps`); the state is
kept, so lamps set while the box is unplugged light up when it comes back.
"""

from __future__ import annotations

import threading

import serial

from drivers.events import Event, StatusEvent
from drivers.protocols import sgi_dialbox as sgi
from drivers.reader import DeviceReader
from service.base.errors import SettingsError

ALL_LAMPS = 0xFFFFFFFF


def _is_reset_ack(event: Event) -> bool:
    return isinstance(event, StatusEvent) and event.details.get("message") == "reset_ack"


class DialBoxDriver:
    """Hooks for a dial box reader (see the module docstring).

    Parameters
    ----------
    reset_wait_s : float
        Longest wait for the box's answer to the resets (VRPN waits 1 s).
    lamps : int
        Initial lamp state, bit k = lamp k.
    """

    def __init__(self, reset_wait_s: float = 1.0, lamps: int = 0) -> None:
        if reset_wait_s < 0:
            raise SettingsError("reset_wait_s must be >= 0")
        self.reset_wait_s = reset_wait_s
        self._lamps = lamps & ALL_LAMPS
        self._lock = threading.Lock()
        self._reader: DeviceReader | None = None
        self._in_init = False
        self.inits = 0

    # -- hooks (reader thread) ------------------------------------------------------
    def on_open(self, reader: DeviceReader) -> None:
        """Run the handshake on a freshly opened port."""
        self._reader = reader
        self.initialise(reader)

    def on_events(self, reader: DeviceReader, events: list[Event]) -> None:
        """Re-initialise when the decoder asks for it."""
        if self._in_init or not any(getattr(e, "needs_reinit", False) for e in events):
            return
        reader.emit("info", {"message": "reinit"}, reset=True)
        self.initialise(reader)

    def on_stop(self, reader: DeviceReader) -> None:
        """Nothing to say on a clean stop (the box keeps no session)."""

    def initialise(self, reader: DeviceReader) -> bool:
        """VRPN's init handshake, then the lamps; returns whether the box answered.

        Raises
        ------
        serial.SerialException
            A write failed (the reader then treats the device as lost).
        """
        self._in_init = True
        acked = False
        try:
            for step in sgi.init_sequence(self.reset_wait_s):
                self._send(reader, step.data)
                if step.wait_s or step.expect:
                    acked = reader.pump(lambda evs: any(map(_is_reset_ack, evs)),
                                        step.wait_s) or acked
            self._send(reader, sgi.encode_lamps(self._lamps))
        finally:
            self._in_init = False
        self.inits += 1
        reader.emit("info", {"message": "init", "reset_ack": acked})
        return acked

    @staticmethod
    def _send(reader: DeviceReader, data: bytes) -> None:
        if not reader.write(data):
            raise serial.SerialException("dial box write failed")

    # -- lamps (any thread) ----------------------------------------------------------
    @property
    def lamps(self) -> int:
        """Lamp state, bit k = lamp k."""
        return self._lamps

    def set_lamps(self, mask: int) -> bool:
        """Set all 32 lamps from a bit mask; False if the box is not connected now."""
        with self._lock:
            self._lamps = mask & ALL_LAMPS
            reader = self._reader
        return reader is not None and reader.write(sgi.encode_lamps(self._lamps))

    def set_lamp(self, index: int, on: bool) -> bool:
        """Switch lamp ``index`` (0-31) on or off."""
        if not 0 <= index < sgi.NUM_BUTTONS:
            raise SettingsError(f"lamp {index} not in 0..31")
        bit = 1 << index
        return self.set_lamps(self._lamps | bit if on else self._lamps & ~bit)

    def all_lamps(self, on: bool) -> bool:
        """All lamps on or off."""
        return self.set_lamps(ALL_LAMPS if on else 0)
