"""Does a byte stream frame as a protocol?  Counts, and the one rule that decides.

Every decoder resynchronises past bytes it cannot frame and counts them
(``stats.bytes_discarded``), so bytes in the wrong protocol are never an exception.
For the Hatire and native trackers that is enough: their frames have headers,
trailers or CRCs, so another protocol's bytes give no event at all.  The SGI dial
box has no framing: every byte C0-FF is a button report and 30-37 starts a dial
report, so a Hatire capture read as ``sgi`` "decodes" into thousands of button and
dial events (the PuTTY Hatire capture: 19,650 events, with 84 % of its bytes
discarded in 15,478 runs).  A real box's stream discards nothing but line noise.

The rule (:meth:`FramingCheck.frames`): a stream does **not** frame as a protocol
when more than :data:`MAX_REJECTED_FRACTION` of its bytes were discarded and at least
:data:`MIN_REJECTED_BYTES` of them (so a few bytes of noise around a short capture
are not judged), or when, of at least :data:`MIN_FRAMES` frames, fewer than half
gave device events (Hatire in the wrong byte order).  Measured: each protocol's own
stream discards 0 %, a noisy real capture (the Hatire fixture with its PuTTY banner)
0.1 %; another protocol's bytes, random bytes and text discard 67-100 % whichever
protocol reads them.

Pure: bytes in, counts out; no files, clocks or ports.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from drivers.events import StatusEvent
from drivers.protocols import make_decoder

#: More than this fraction of the bytes discarded: the stream is not this protocol.
MAX_REJECTED_FRACTION = 0.5
#: ... provided at least this many bytes were discarded.
MIN_REJECTED_BYTES = 64
#: Bytes :func:`check_framing` reads by default (a prefix is enough to tell).
PREFIX_BYTES = 64 * 1024
#: With at least this many frames, fewer than half of them giving device events is
#: not the protocol either (Hatire read in the wrong byte order: its frame counter
#: becomes a text or undefined code, 4,689 of the fixture's 4,765 frames).
MIN_FRAMES = 20
#: What :func:`protocols_that_frame` tries: a label to show, the decoder, its options.
CANDIDATES: tuple[tuple[str, str, dict[str, Any]], ...] = (
    ("hatire", "hatire", {}),
    ("hatire --hatire-big-endian", "hatire", {"byte_order": "big"}),
    ("native", "native", {}),
    ("sgi", "sgi", {}),
)


@dataclass(frozen=True)
class FramingCheck:
    """What one protocol's decoder made of some bytes.

    Attributes
    ----------
    protocol : str
    bytes_in, bytes_discarded : int
        Bytes fed and bytes thrown away resynchronising.
    resyncs : int
        Runs of discarded bytes.
    events : int
        Device events decoded (poses, dials, buttons; not statuses).
    packets : int
        Frames the decoder found intact (``stats.frames``: device events, text).
    """

    protocol: str
    bytes_in: int = 0
    bytes_discarded: int = 0
    resyncs: int = 0
    events: int = 0
    packets: int = 0

    @property
    def rejected_fraction(self) -> float:
        """Discarded bytes over bytes fed (0 for no bytes)."""
        return self.bytes_discarded / self.bytes_in if self.bytes_in else 0.0

    @property
    def rejected(self) -> bool:
        """More than half of the bytes (and at least 64) discarded."""
        return (self.bytes_discarded >= MIN_REJECTED_BYTES
                and self.rejected_fraction > MAX_REJECTED_FRACTION)

    @property
    def eventless(self) -> bool:
        """Frames found, but fewer than half of them gave device events."""
        return self.packets >= MIN_FRAMES and 2 * self.events < self.packets

    @property
    def frames(self) -> bool:
        """False when the bytes do not frame as ``protocol`` (the module's rule)."""
        return not (self.rejected or self.eventless)

    def __add__(self, other: FramingCheck) -> FramingCheck:
        """Counts of two parts of one stream."""
        return FramingCheck(self.protocol, self.bytes_in + other.bytes_in,
                            self.bytes_discarded + other.bytes_discarded,
                            self.resyncs + other.resyncs, self.events + other.events,
                            self.packets + other.packets)

    def describe(self, of: str = "") -> str:
        """``"120748 of 143090 bytes (84 %) rejected in 15478 runs"``.

        ``of`` goes before the byte count (``"its first "``).
        """
        if self.eventless and not self.rejected:
            return (f"{self.packets - self.events} of {of}{self.packets} frames gave no "
                    "pose, dial or button")
        runs = "run" if self.resyncs == 1 else "runs"
        return (f"{self.bytes_discarded} of {of}{self.bytes_in} bytes "
                f"({100 * self.rejected_fraction:.0f} %) rejected in {self.resyncs} {runs}")


def count_events(events: Iterable[Any]) -> int:
    """Device events (not statuses) among ``events``."""
    return sum(not isinstance(e, StatusEvent) for e in events)


def check_framing(protocol: str, data: bytes, limit: int | None = PREFIX_BYTES,
                  **options: Any) -> FramingCheck:
    """Decode ``data`` (its first ``limit`` bytes; None: all) as ``protocol``; the counts.

    ``options`` are the decoder's (``byte_order="big"`` for Hatire).  The bytes are
    fed at one time stamp, so the SGI dial timeout never cuts a packet.
    """
    dec = make_decoder(protocol, **options)
    part = data if limit is None else data[:limit]
    events = count_events(dec.feed(part, 0)) + count_events(dec.flush(0))
    st = dec.stats
    return FramingCheck(protocol, st.bytes_in, st.bytes_discarded, st.resyncs, events,
                        st.frames)


def protocols_that_frame(data: bytes, limit: int | None = PREFIX_BYTES) -> list[str]:
    """The :data:`CANDIDATES` (labels) that frame ``data`` and find device events in it."""
    out = []
    for label, name, options in CANDIDATES:
        check = check_framing(name, data, limit, **options)
        if check.frames and check.events:
            out.append(label)
    return out
