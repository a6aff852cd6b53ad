"""SGI Dial and Button Box serial protocol (decoder and encoders; pure).

As VRPN (``vrpn_raw_sgibox``) and XFree86 (``xf86Dial``) drive it: 9600 baud, 8N1,
no flow control.  Eight dials (0-7), 32 buttons with lamps (0-31).

Host to box::

    20                 reset (the box answers 20)
    50 xx FF           enable all dials (xx ignored; 0xFF = all eight)
    71 b0 b1 b2 b3     enable buttons (mask, 0xFFFFFFFF = all)
    73 b0 b1 b2 b3     auto-report buttons (mask)
    75 b0 b1 b2 b3     set the 32 lamps; lamp k is bit (k % 8) of byte k // 8 (LSB first)
    4B / 4C            all lamps on / off
    53 dd ff           set dial dd's (0-7) filter to ff (0-7)

Box to host::

    20                 reset acknowledged                      -> info status
    3n HH LL           dial n (0-7), signed 16-bit big-endian counter that wraps
    C0..DF             button press,   button = (code & 0x1F) ^ 0x18   (D8 = 0, C7 = 31)
    E0..FF             button release, same numbering

Dial events: ``delta`` is the change of the 16-bit counter since the previous
report of that dial (wrapped into -32768..32767); ``value`` is the running sum of
deltas, so it is unwrapped and unbounded.  Counters are taken as 0 after a reset
(:meth:`SgiDecoder.reset`), as VRPN does.  A turn is ``counts_per_turn`` counts
(VRPN: 200).  Note: VRPN's source reads the counter low byte first; this module
follows the big-endian layout of the issue / xf86Dial.

Resync: a byte not in 20, 30-37, C0-FF is discarded; each run of discarded bytes is
reported by one ``resync`` status when the next good packet arrives.  A dial packet
whose remaining bytes arrive more than ``dial_timeout_ns`` (10 ms) after its first
byte is discarded (``truncated`` status) and the late bytes are parsed afresh.  After
``garbage_limit`` discarded bytes without a good packet the decoder emits one
``error`` status with ``details.action == "reinit"``; the driver then re-runs
:func:`init_sequence` and calls :meth:`SgiDecoder.reset`.
"""

from __future__ import annotations

from dataclasses import dataclass

from drivers.events import ButtonEvent, DecoderStats, DialEvent, Event, StatusEvent
from service.errors import ProtocolError

BAUD = 9600
NUM_DIALS = 8
NUM_BUTTONS = 32
RESET = 0x20
ENABLE_DIALS = 0x50
ENABLE_BUTTONS = 0x71
AUTO_BUTTONS = 0x73
SET_LAMPS = 0x75
LAMPS_ON = 0x4B
LAMPS_OFF = 0x4C
SET_FILTER = 0x53
#: host command byte -> number of argument bytes.
HOST_COMMAND_ARGS = {RESET: 0, ENABLE_DIALS: 2, ENABLE_BUTTONS: 4, AUTO_BUTTONS: 4,
                     SET_LAMPS: 4, LAMPS_ON: 0, LAMPS_OFF: 0, SET_FILTER: 2}
DIAL_TIMEOUT_NS = 10_000_000
COUNTS_PER_TURN = 200
#: byte -> kind code: 0 garbage, 1 reset ack, 2 dial header, 3 press, 4 release.
_KIND = bytes(1 if b == RESET else 2 if 0x30 <= b <= 0x37 else 3 if 0xC0 <= b <= 0xDF
              else 4 if b >= 0xE0 else 0 for b in range(256))


def button_code(index: int, pressed: bool) -> int:
    """Box-to-host byte for button ``index`` (0-31) pressed or released."""
    if not 0 <= index < NUM_BUTTONS:
        raise ProtocolError(f"button index {index} not in 0..31")
    return (0xC0 if pressed else 0xE0) | (index ^ 0x18)


def button_index(code: int) -> int:
    """Button number of a press/release byte (0xC0-0xFF)."""
    return (code & 0x1F) ^ 0x18


def encode_dial(index: int, counter: int) -> bytes:
    """Box-to-host dial report: ``3n HH LL``; ``counter`` is taken mod 2**16."""
    if not 0 <= index < NUM_DIALS:
        raise ProtocolError(f"dial index {index} not in 0..7")
    return bytes((0x30 + index,)) + (counter & 0xFFFF).to_bytes(2, "big")


def encode_button(index: int, pressed: bool) -> bytes:
    """Box-to-host button report (one byte)."""
    return bytes((button_code(index, pressed),))


def _mask_bytes(mask: int) -> bytes:
    return (mask & 0xFFFFFFFF).to_bytes(4, "little")


def encode_reset() -> bytes:
    """Host command: reset (the box answers 0x20)."""
    return bytes((RESET,))


def encode_enable_dials(mask: int = 0xFF) -> bytes:
    """Host command ``50 xx mask`` (bit n enables dial n)."""
    return bytes((ENABLE_DIALS, 0xFF, mask & 0xFF))


def encode_enable_buttons(mask: int = 0xFFFFFFFF) -> bytes:
    """Host command ``71`` + 4-byte mask, bit k enables button k."""
    return bytes((ENABLE_BUTTONS,)) + _mask_bytes(mask)


def encode_auto_report_buttons(mask: int = 0xFFFFFFFF) -> bytes:
    """Host command ``73`` + 4-byte mask, bit k makes button k report by itself."""
    return bytes((AUTO_BUTTONS,)) + _mask_bytes(mask)


def encode_lamps(lamps: int) -> bytes:
    """Host command ``75`` + 4 bytes: lamp k on when bit k of ``lamps`` is set."""
    return bytes((SET_LAMPS,)) + _mask_bytes(lamps)


def encode_all_lamps(on: bool) -> bytes:
    """Host command ``4B`` (all on) or ``4C`` (all off)."""
    return bytes((LAMPS_ON if on else LAMPS_OFF,))


def encode_filter(dial: int, level: int) -> bytes:
    """Host command ``53 dial level``; dial 0-7, level 0-7."""
    if not (0 <= dial < NUM_DIALS and 0 <= level <= 7):
        raise ProtocolError(f"dial filter needs dial 0..7 and level 0..7, got {dial}, {level}")
    return bytes((SET_FILTER, dial, level))


@dataclass(frozen=True)
class InitStep:
    """One step of the init handshake: write ``data``, then wait ``wait_s`` seconds.

    ``expect`` is the answer to read during the wait (``b" "`` after the resets).
    """

    data: bytes
    wait_s: float = 0.0
    expect: bytes = b""


def init_sequence(reset_wait_s: float = 1.0) -> list[InitStep]:
    """VRPN's initialisation: reset twice then wait, dials before buttons, buttons twice."""
    buttons = encode_enable_buttons() + encode_auto_report_buttons()
    return [InitStep(encode_reset()),
            InitStep(encode_reset(), reset_wait_s, bytes((RESET,))),
            InitStep(encode_enable_dials()),
            InitStep(buttons),
            InitStep(buttons)]


class SgiDecoder:
    """Incremental decoder of the box-to-host stream (see module docstring).

    Parameters
    ----------
    dial_timeout_ns : int
        A dial packet not completed within this time is discarded (10 ms).
    garbage_limit : int
        Discarded bytes without a good packet before a re-init is requested.
    """

    device = "dials"

    def __init__(self, dial_timeout_ns: int = DIAL_TIMEOUT_NS, garbage_limit: int = 16) -> None:
        self.dial_timeout_ns = dial_timeout_ns
        self.garbage_limit = garbage_limit
        self.stats = DecoderStats()
        # indexed by _KIND; garbage runs and dial packets are handled inline in _scan
        self._handlers = (None, self._reset_ack, None, self._press, self._release)
        self.reset()

    def reset(self) -> None:
        """Counters back to 0 (the box was reset), partial packet and garbage forgotten."""
        self._counters = [0] * NUM_DIALS
        self._values = [0] * NUM_DIALS
        self._partial = bytearray()
        self._t_start = 0
        self._garbage = 0
        self._since_good = 0

    def feed(self, data: bytes, t_ns: int) -> list[Event]:
        """Decode ``data`` received at ``t_ns``; keep a partial dial packet."""
        self.stats.bytes_in += len(data)
        events: list[Event] = []
        if self._partial and data and t_ns - self._t_start > self.dial_timeout_ns:
            self._drop_partial(t_ns, events)
        i = 0
        if self._partial:
            i = 3 - len(self._partial)
            self._partial += data[:i]
            if len(self._partial) < 3:
                return events
            self._dial_done(self._partial, 0, t_ns, events)
            self._partial.clear()
        self._scan(data, i, t_ns, events)
        return events

    def _scan(self, data: bytes, i: int, t_ns: int, events: list[Event]) -> None:
        """The hot loop: whole dial packets inline, other bytes via the handler table."""
        n, kind, handlers, dial_done = len(data), _KIND, self._handlers, self._dial_done
        while i < n:
            k = kind[data[i]]
            if k == 2:
                if i + 3 > n:
                    self._partial += data[i:]
                    self._t_start = t_ns
                    return
                dial_done(data, i, t_ns, events)
                i += 3
            elif k:
                handlers[k](data[i], t_ns, events)
                i += 1
            else:
                j = i + 1
                while j < n and not kind[data[j]]:
                    j += 1
                self._garbage_run(j - i, t_ns, events)
                i = j

    def flush(self, t_ns: int) -> list[Event]:
        """End of input: an unfinished dial packet is truncated; report garbage."""
        events: list[Event] = []
        if self._partial:
            self._drop_partial(t_ns, events)
        self._end_garbage(t_ns, events)
        return events

    def _drop_partial(self, t_ns: int, events: list[Event]) -> None:
        self._end_garbage(t_ns, events)
        self.stats.truncated += 1
        self.stats.bytes_discarded += len(self._partial)
        events.append(StatusEvent(t_ns, "dials", "truncated", {"bytes": len(self._partial),
                                                                "dial": self._partial[0] - 0x30}))
        self._partial.clear()

    def _end_garbage(self, t_ns: int, events: list[Event]) -> None:
        if self._garbage:
            self.stats.resyncs += 1
            events.append(StatusEvent(t_ns, "dials", "resync", {"discarded": self._garbage}))
            self._garbage = 0

    def _good(self, t_ns: int, events: list[Event]) -> None:
        self._end_garbage(t_ns, events)
        self._since_good = 0
        self.stats.frames += 1

    def _garbage_run(self, count: int, t_ns: int, events: list[Event]) -> None:
        before = self._since_good
        self._garbage += count
        self._since_good += count
        self.stats.bytes_discarded += count
        if before < self.garbage_limit <= self._since_good:
            events.append(StatusEvent(t_ns, "dials", "error",
                                      {"reason": "repeated_garbage", "action": "reinit"}))

    def _reset_ack(self, b: int, t_ns: int, events: list[Event]) -> None:
        self._good(t_ns, events)
        events.append(StatusEvent(t_ns, "dials", "info", {"message": "reset_ack"}))

    def _dial_done(self, p: bytes | bytearray, i: int, t_ns: int, events: list[Event]) -> None:
        if self._garbage:
            self._end_garbage(t_ns, events)
        self._since_good = 0
        self.stats.frames += 1
        index = p[i] - 0x30
        counter = (p[i + 1] << 8) | p[i + 2]
        delta = ((counter - self._counters[index] + 0x8000) & 0xFFFF) - 0x8000
        self._counters[index] = counter
        value = self._values[index] + delta
        self._values[index] = value
        events.append(DialEvent(t_ns, index, delta, value))

    def _press(self, b: int, t_ns: int, events: list[Event]) -> None:
        self._good(t_ns, events)
        events.append(ButtonEvent(t_ns, button_index(b), True))

    def _release(self, b: int, t_ns: int, events: list[Event]) -> None:
        self._good(t_ns, events)
        events.append(ButtonEvent(t_ns, button_index(b), False))


class SgiCommandParser:
    """Box-side parser of host commands (used by the simulator; pure).

    ``feed`` returns ``(command_byte, args)`` tuples; unknown bytes are skipped and
    counted in ``unknown``.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self.unknown = 0

    def feed(self, data: bytes) -> list[tuple[int, bytes]]:
        """Parse complete commands; keep a partial one."""
        buf = self._buf
        buf += data
        out: list[tuple[int, bytes]] = []
        pos = 0
        while pos < len(buf):
            nargs = HOST_COMMAND_ARGS.get(buf[pos])
            if nargs is None:
                self.unknown += 1
                pos += 1
                continue
            if len(buf) - pos < 1 + nargs:
                break
            out.append((buf[pos], bytes(buf[pos + 1:pos + 1 + nargs])))
            pos += 1 + nargs
        del buf[:pos]
        return out
