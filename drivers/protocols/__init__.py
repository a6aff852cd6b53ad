"""Byte protocols of the devices: pure decoders and encoders.

Every decoder follows one interface (:class:`Decoder`)::

    dec = DECODERS["hatire"]()          # or make_decoder("hatire", byte_order="big")
    events = dec.feed(chunk, time.monotonic_ns())   # any chunking, any sizes
    ...
    events += dec.flush(time.monotonic_ns())        # end of input (file, disconnect)
    dec.stats.as_dict()                 # frames, bytes_discarded, resyncs, ...

Rules every decoder keeps:

* ``feed(data, t_ns)`` takes arbitrary byte chunks (``opentrack`` excepted: it
  takes one UDP datagram a call, :mod:`drivers.protocols.opentrack`) and returns the events they
  complete, in stream order; a partial frame is kept for the next call.  Events carry
  ``t_ns`` (the receive time given to ``feed``; :func:`time.monotonic_ns` domain).
* The same bytes fed with the same ``t_ns`` give the same events however they are
  split (the SGI 10 ms dial timeout is the one rule that depends on ``t_ns``).
* Bad input never raises: it is counted in ``stats`` (:class:`DecoderStats`),
  reported as a :class:`~drivers.events.StatusEvent` (``resync``, ``truncated``,
  ``crc_error``, ``counter_gap``, ``error``) and parsing resynchronises; an intact
  frame is never lost.  A status whose ``needs_reinit`` is true asks the driver to
  re-initialise the device (SGI box after repeated garbage).
* ``reset()`` forgets buffered bytes and stream state (after a reconnect or re-init);
  ``stats`` keep counting.
* ``device`` is ``"tracker"`` or ``"dials"``.
* No port access, no clocks, no threads inside.

Encoders (module-level functions, pure, return ``bytes``):

=========  ===================================================================
hatire     ``encode_pose``, ``encode_text``, ``encode_command``
native     ``encode_pose``, ``encode_text``, ``encode_command``, ``encode_frame``
opentrack  ``encode_pose`` (our axes), ``encode_raw`` (opentrack's)
sgi        box to host: ``encode_dial``, ``encode_button``; host to box:
           ``encode_reset``, ``encode_enable_dials``, ``encode_enable_buttons``,
           ``encode_auto_report_buttons``, ``encode_lamps``, ``encode_all_lamps``,
           ``encode_filter``, ``init_sequence``
=========  ===================================================================

Frame layouts, value ranges and resync rules are in each module's docstring and in
``docs/device-protocols.md`` / ``docs/native-protocol.md``.
"""

from __future__ import annotations

from typing import Any, Protocol

from drivers.events import DecoderStats, Event
from drivers.protocols import hatire, native, opentrack, sgi_dialbox
from service.base.errors import ProtocolError

__all__ = ["DATAGRAM_PROTOCOLS", "DECODERS", "DEVICE_OF", "Decoder", "DecoderStats",
           "make_decoder"]


class Decoder(Protocol):
    """What every protocol decoder offers (see the package docstring)."""

    device: str
    stats: DecoderStats

    def feed(self, data: bytes, t_ns: int) -> list[Event]:
        """Decode a chunk received at ``t_ns``; return the completed events."""
        ...

    def flush(self, t_ns: int) -> list[Event]:
        """End of input: report what is left over."""
        ...

    def reset(self) -> None:
        """Forget buffered bytes and stream state."""
        ...


#: protocol name -> decoder class.
DECODERS: dict[str, type] = {
    "hatire": hatire.HatireDecoder,
    "native": native.NativeDecoder,
    "sgi": sgi_dialbox.SgiDecoder,
    "opentrack": opentrack.OpentrackDecoder,
}
#: Protocols whose ``feed`` takes one datagram a call (any other takes any chunking).
DATAGRAM_PROTOCOLS = frozenset({"opentrack"})
#: protocol name -> the device its events come from.
DEVICE_OF = {"hatire": "tracker", "native": "tracker", "sgi": "dials", "opentrack": "tracker"}


def make_decoder(name: str, **options: Any) -> Decoder:
    """A fresh decoder for protocol ``name`` (``hatire``, ``native``, ``sgi``).

    Raises
    ------
    ProtocolError
        For an unknown protocol name.
    """
    try:
        cls = DECODERS[name]
    except KeyError:
        raise ProtocolError(f"unknown protocol {name!r}; known: {sorted(DECODERS)}") from None
    return cls(**options)
