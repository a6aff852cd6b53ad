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
follows the big-endian layout of the issue / xf86Dial (the offsets ``_HI`` /
``_LO`` below; swap them for a low-byte-first box).

Resync: a byte not in 20, 30-37, C0-FF is discarded; each run of discarded bytes is
reported by one ``resync`` status when the next good packet arrives.  A dial packet
whose remaining bytes arrive more than ``dial_timeout_ns`` (10 ms) after its first
byte is discarded (``truncated`` status) and the late bytes are parsed afresh.  After
``garbage_limit`` discarded bytes without a good packet the decoder emits one
``error`` status with ``details.action == "reinit"``; the driver then re-runs
:func:`init_sequence` and calls :meth:`SgiDecoder.reset`.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, fields
from itertools import repeat
from types import MappingProxyType
from typing import Any

import numpy as np

from drivers.events import ButtonEvent, DecoderStats, DialEvent, Event, StatusEvent
from service.base.errors import ProtocolError

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


#: Chunks at least this long (from where the scan starts) are tokenised with numpy
#: (:meth:`SgiDecoder._scan_bulk`); shorter ones, the usual case at 9600 baud, go
#: through the byte loop (:meth:`SgiDecoder._scan`).  Both give the same events.
BULK_MIN_BYTES = 256
#: Offsets of the high and low counter byte in a dial packet (big-endian, as
#: xf86Dial); swap them here if a box proves to send the low byte first (VRPN).
_HI, _LO = 1, 2
_KIND_NP = np.frombuffer(_KIND, dtype=np.uint8)
#: byte -> button index (meaningful for C0-FF).
_BUTTON = bytes((b & 0x1F) ^ 0x18 for b in range(256))
_BUTTON_NP = np.frombuffer(_BUTTON, dtype=np.uint8)
#: Running dial values stay below this in magnitude for the int64 bulk path.
_BULK_VALUE_LIMIT = 1 << 62

# Events are built with ``object.__new__`` and the slot setters of the (frozen,
# slotted) event dataclasses: the generated ``__init__`` costs one
# ``object.__setattr__`` per field and dominated decoding time.  The objects are the
# same as the constructor's (same class, same field values, compare equal).
_new = object.__new__
_consume = deque(maxlen=0).extend


def _slot_setters(cls: type, *names: str) -> tuple:
    if tuple(f.name for f in fields(cls)) != names:
        raise TypeError(f"{cls.__name__} fields changed; update sgi_dialbox._slot_setters")
    return tuple(cls.__dict__[name].__set__ for name in names)


_DIAL_SET = _slot_setters(DialEvent, "t_ns", "index", "delta", "value")
_BUTTON_SET = _slot_setters(ButtonEvent, "t_ns", "index", "pressed")
_STATUS_SET = _slot_setters(StatusEvent, "t_ns", "device", "event", "details")


def _status(t_ns: int, event: str, details: dict[str, Any]) -> StatusEvent:
    """``StatusEvent(t_ns, "dials", event, details)`` for a valid ``event``, faster."""
    set_t, set_device, set_event, set_details = _STATUS_SET
    ev = _new(StatusEvent)
    set_t(ev, t_ns)
    set_device(ev, "dials")
    set_event(ev, event)
    set_details(ev, MappingProxyType(details))
    return ev


def _statuses(t_ns: int, event: str, key: str, values: list[Any]) -> list[StatusEvent]:
    """``[StatusEvent(t_ns, "dials", event, {key: v}) for v in values]``, faster."""
    count = len(values)
    out = list(map(_new, repeat(StatusEvent, count)))
    set_t, set_device, set_event, set_details = _STATUS_SET
    _consume(map(set_t, out, repeat(t_ns, count)))
    _consume(map(set_device, out, repeat("dials", count)))
    _consume(map(set_event, out, repeat(event, count)))
    _consume(map(set_details, out, map(MappingProxyType, [{key: v} for v in values])))
    return out


def _reinit(t_ns: int) -> StatusEvent:
    return _status(t_ns, "error", {"reason": "repeated_garbage", "action": "reinit"})


def _bulk_tokens(arr: np.ndarray, i0: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Where a long chunk's tokens start, from byte ``i0``, and their kinds.

    Parameters
    ----------
    arr : ndarray, shape (n,), uint8
        The chunk.
    i0 : int
        Where the scan starts.

    Returns
    -------
    pos : ndarray, shape (t,), intp
        Token starts in ``[i0, end)``: every byte but the counter bytes of the dial
        headers.
    tkind : ndarray, shape (t,), uint8
        Their kinds (:data:`_KIND_NP`; 0 is garbage).
    end : int
        Where a partial packet at the end starts (``n`` if none).
    """
    n = arr.size
    kinds = _KIND_NP[arr]
    # Dial headers, minus those swallowed as counter bytes by an earlier header
    # (only a header within two bytes of the previous one can be).
    heads = np.flatnonzero(kinds[i0:] == 2)
    if i0:
        heads += i0
    if heads.size > 1:
        close = np.flatnonzero(heads[1:] - heads[:-1] <= 2) + 1
        if close.size:
            hl, swallowed = heads.tolist(), set()
            for j in close.tolist():
                h = hl[j]
                if ((j - 1 not in swallowed and h - hl[j - 1] <= 2)
                        or (j >= 2 and j - 2 not in swallowed and h - hl[j - 2] <= 2)):
                    swallowed.add(j)
            if swallowed:
                heads = np.delete(heads, list(swallowed))
    end = n
    if heads.size and heads[-1] + 3 > n:  # a partial packet at the end
        end = int(heads[-1])
        heads = heads[:-1]
    starts = np.ones(end - i0, dtype=bool)
    starts[heads + (1 - i0)] = False
    starts[heads + (2 - i0)] = False
    pos = np.flatnonzero(starts)
    if i0:
        pos += i0
    return pos, kinds[pos], end


def _garbage_runs(pos: np.ndarray, tkind: np.ndarray) -> tuple:
    """Good tokens and the runs of garbage tokens (one byte each) between them.

    Returns
    -------
    gpos, gkind : ndarray, shape (g,)
        The good tokens' starts and kinds.
    run_len, run_at : ndarray, shape (r,), or None
        Each run's length and the number of good tokens before it; None when the
        chunk has no garbage.
    """
    bad = tkind == 0
    if not bad.any():
        return pos, tkind, None, None
    good = ~bad
    edge = np.diff(bad.view(np.int8), prepend=np.int8(0), append=np.int8(0))
    run_start = np.flatnonzero(edge == 1)
    run_len = np.flatnonzero(edge == -1) - run_start
    run_at = run_start - (np.cumsum(run_len) - run_len)
    return pos[good], tkind[good], run_len, run_at


def _place(events: list, built: list, ngood: int, stat_at: list[int],
           stat_obj: list) -> None:
    """Append the good events (``built``: ``(which, objs)`` per kind) and statuses in order.

    ``which`` is None when one kind fills every good slot; each status goes before
    the good event ``stat_at`` names.
    """
    nstat = len(stat_obj)
    if not nstat and len(built) == 1:
        events.extend(built[0][1])
        return
    if not (ngood or nstat):
        return
    s_at = np.array(stat_at, dtype=np.intp)
    good_dest = np.arange(ngood)
    good_dest += np.searchsorted(s_at, good_dest, side="right")
    out = np.empty(ngood + nstat, dtype=object)
    out[s_at + np.arange(nstat)] = np.fromiter(stat_obj, dtype=object, count=nstat)
    for which, objs in built:
        out[good_dest if which is None else good_dest[which]] = np.fromiter(
            objs, dtype=object, count=len(objs))
    events.extend(out.tolist())


def _merge_statuses(stat_at: list[int], stat_obj: list, resync_at: list[int],
                    resyncs: list) -> tuple[list[int], list]:
    """Re-init requests and resyncs in one list, each re-init before the resync at its place.

    Parameters
    ----------
    stat_at, resync_at : list of int, ascending
        The good events each goes before.
    stat_obj, resyncs : list of StatusEvent
        The re-init requests and the resyncs, as long as their places.

    Returns
    -------
    at : list of int
        The places, ascending.
    merged : list of StatusEvent
        The statuses in stream order.
    """
    keys = np.array([2 * a for a in stat_at] + [2 * a + 1 for a in resync_at])
    order = np.argsort(keys, kind="stable")
    merged = stat_obj + resyncs
    return (keys[order] >> 1).tolist(), [merged[k] for k in order.tolist()]


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
        if not data:
            return events
        i = 0
        partial = self._partial
        if partial:
            if t_ns - self._t_start > self.dial_timeout_ns:
                self._drop_partial(t_ns, events)
            else:
                i = 3 - len(partial)
                partial += data[:i]
                if len(partial) < 3:
                    return events
                self._dial_done(partial, t_ns, events)
                partial.clear()
        if len(data) - i >= BULK_MIN_BYTES and all(
                -_BULK_VALUE_LIMIT < v < _BULK_VALUE_LIMIT for v in self._values):
            self._scan_bulk(data, i, t_ns, events)
        else:
            self._scan(data, i, t_ns, events)
        return events

    def flush(self, t_ns: int) -> list[Event]:
        """End of input: an unfinished dial packet is truncated; report garbage."""
        events: list[Event] = []
        if self._partial:
            self._drop_partial(t_ns, events)
        self._end_garbage(t_ns, events)
        return events

    def _scan(self, data: bytes, i: int, t_ns: int, events: list[Event]) -> None:
        """Byte loop from ``i``: state in locals, events built inline."""
        n, kind, button = len(data), _KIND, _BUTTON
        counters, values = self._counters, self._values
        garbage, since = self._garbage, self._since_good
        frames = 0
        append, new, dial_cls, button_cls = events.append, _new, DialEvent, ButtonEvent
        d_t, d_index, d_delta, d_value = _DIAL_SET
        b_t, b_index, b_pressed = _BUTTON_SET
        while i < n:
            b = data[i]
            k = kind[b]
            if not k:  # a run of garbage
                i, garbage, since = self._skip_garbage(data, i, t_ns, garbage, since, append)
                continue
            if k == 2 and i + 3 > n:  # a partial dial packet: kept for the next chunk
                self._partial += data[i:]
                self._t_start = t_ns
                break
            if since:  # a good packet after garbage
                self._garbage = garbage
                self._end_garbage(t_ns, events)
                garbage = since = 0
            frames += 1
            if k == 2:
                index = b - 0x30
                counter = (data[i + _HI] << 8) | data[i + _LO]
                delta = ((counter - counters[index] + 0x8000) & 0xFFFF) - 0x8000
                counters[index] = counter
                value = values[index] + delta
                values[index] = value
                ev = new(dial_cls)
                d_t(ev, t_ns)
                d_index(ev, index)
                d_delta(ev, delta)
                d_value(ev, value)
                append(ev)
                i += 3
            elif k == 1:
                append(_status(t_ns, "info", {"message": "reset_ack"}))
                i += 1
            else:
                ev = new(button_cls)
                b_t(ev, t_ns)
                b_index(ev, button[b])
                b_pressed(ev, k == 3)
                append(ev)
                i += 1
        self._garbage, self._since_good = garbage, since
        self.stats.frames += frames

    def _skip_garbage(self, data: bytes, i: int, t_ns: int, garbage: int, since: int,
                      append: Callable[[Event], None]) -> tuple[int, int, int]:
        """Skip the run of garbage bytes at ``i`` (the byte loop's rare case).

        Appends the re-init request when the run takes the bytes discarded since
        the last good packet (``since``) to ``garbage_limit``; counts the run in
        the stats.  Returns where the run ends and the new ``garbage``, ``since``.
        """
        n, kind = len(data), _KIND
        j = i + 1
        while j < n and not kind[data[j]]:
            j += 1
        count = j - i
        if since < self.garbage_limit <= since + count:
            append(_reinit(t_ns))
        self.stats.bytes_discarded += count
        return j, garbage + count, since + count

    def _scan_bulk(self, data: bytes, i0: int, t_ns: int, events: list[Event]) -> None:
        """What :meth:`_scan` does, for a long chunk, with numpy.

        Tokenise with numpy (:func:`_bulk_tokens`), find the runs of garbage
        (:func:`_garbage_runs`), build the events of each kind with C-level ``map``
        calls, turn the runs into statuses (:meth:`_bulk_statuses`) and place
        everything in stream order (:func:`_place`).
        """
        arr = np.frombuffer(data, dtype=np.uint8)
        pos, tkind, end = _bulk_tokens(arr, i0)
        gpos, gkind, run_len, run_at = _garbage_runs(pos, tkind)
        ngood = gpos.size
        built = self._build(arr, gpos, gkind, t_ns)
        if run_len is None and not (self._garbage and ngood):  # no statuses
            _place(events, built, ngood, [], [])
            if ngood:
                self._since_good = 0
            self._finish(data, end, t_ns, ngood, 0, 0)
            return
        stat_at, stat_obj, nresync = self._bulk_statuses(run_len, run_at, ngood, t_ns)
        _place(events, built, ngood, stat_at, stat_obj)
        discarded = 0 if run_len is None else int(run_len.sum())
        self._finish(data, end, t_ns, ngood, discarded, nresync)

    def _bulk_statuses(self, run_len: np.ndarray | None, run_at: np.ndarray | None,
                       ngood: int, t_ns: int) -> tuple[list[int], list[Event], int]:
        """The statuses of a bulk chunk's garbage, and the garbage it leaves to carry.

        Each status goes before the good event at its place: the resync of the
        garbage before it (carried in, or a run), preceded by the re-init request of
        that run if it crossed the limit.  ``run_len``, ``run_at`` (None: no run in
        this chunk) are :func:`_garbage_runs`' runs.

        Returns
        -------
        stat_at : list of int
            Good events each status goes before, ascending.
        stat_obj : list of Event
            The statuses, in stream order.
        nresync : int
            Resyncs among them.
        """
        garbage, since = self._garbage, self._since_good
        if run_len is None:  # garbage carried in, then good packets only
            stat_at, stat_obj, resync_at, resync_n = [], [], [0], [garbage]
            self._garbage = self._since_good = 0
        else:
            stat_at, stat_obj, resync_at, resync_n = self._run_statuses(
                run_len, run_at, ngood, t_ns, garbage, since)
        if not resync_at:
            return stat_at, stat_obj, 0
        resyncs = _statuses(t_ns, "resync", "discarded", resync_n)
        if not stat_at:
            return resync_at, resyncs, len(resync_at)
        at, merged = _merge_statuses(stat_at, stat_obj, resync_at, resyncs)
        return at, merged, len(resync_at)

    def _run_statuses(self, run_len: np.ndarray, run_at: np.ndarray, ngood: int, t_ns: int,
                      garbage: int, since: int) -> tuple[list[int], list[Event], list, list]:
        """Re-init requests and resync places of a bulk chunk with garbage runs.

        ``garbage`` and ``since`` are carried in from the previous chunk; the
        garbage left to carry on (a last run that reaches the chunk's end) is kept.

        Returns
        -------
        stat_at, stat_obj : list
            The re-init requests: the good events they go before, and themselves.
        resync_at, resync_n : list of int
            Where each resync goes (ascending) and the bytes it discarded.
        """
        stat_at: list[int] = []
        stat_obj: list[Event] = []
        at_l, len_l = run_at.tolist(), run_len.tolist()
        limit = self.garbage_limit
        first_len = len_l[0]
        if at_l[0] == 0:  # continues the garbage carried in
            len_l[0] += garbage
            before = since
        else:
            before = 0
        if before < limit <= before + first_len:
            stat_at.append(at_l[0])
            stat_obj.append(_reinit(t_ns))
        if limit > 0:  # later runs follow a good packet
            for at, count in zip(at_l[1:], len_l[1:], strict=True):
                if count >= limit:
                    stat_at.append(at)
                    stat_obj.append(_reinit(t_ns))
        if garbage and at_l[0]:  # the carried-in garbage ends at the first packet
            resync_at, resync_n = [0], [garbage]
        else:
            resync_at, resync_n = [], []
        if at_l[-1] == ngood:  # the last run goes on into the next chunk
            garbage = len_l.pop()
            since = (before if ngood == 0 else 0) + (first_len if ngood == 0 else garbage)
            at_l.pop()
        else:
            garbage = since = 0
        self._garbage, self._since_good = garbage, since
        return stat_at, stat_obj, resync_at + at_l, resync_n + len_l

    def _finish(self, data: bytes, end: int, t_ns: int, frames: int, discarded: int,
                resyncs: int) -> None:
        stats = self.stats
        stats.frames += frames
        stats.bytes_discarded += discarded
        stats.resyncs += resyncs
        if end < len(data):
            self._partial += data[end:]
            self._t_start = t_ns

    def _build(self, arr: np.ndarray, gpos: np.ndarray, gkind: np.ndarray,
               t_ns: int) -> list[tuple[np.ndarray | None, list[Event]]]:
        """Events of the good tokens at ``gpos`` (kinds ``gkind``), per kind.

        Returns ``(which, events)`` pairs: ``which`` selects the tokens (a boolean
        mask, or None for all of them).
        """
        ngood = gpos.size
        if not ngood:
            return []
        is_dial = gkind == 2
        ndial = int(np.count_nonzero(is_dial))
        out: list[tuple[np.ndarray | None, list[Event]]] = []
        if ndial:
            dials = list(map(_new, repeat(DialEvent, ndial)))
            index, delta, value = self._dial_fields(arr, gpos[is_dial] if ndial < ngood else gpos)
            d_t, d_index, d_delta, d_value = _DIAL_SET
            _consume(map(d_t, dials, repeat(t_ns, ndial)))
            _consume(map(d_index, dials, index))
            _consume(map(d_delta, dials, delta))
            _consume(map(d_value, dials, value))
            out.append((None if ndial == ngood else is_dial, dials))
            if ndial == ngood:
                return out
        is_button = gkind >= 3
        nbutton = int(np.count_nonzero(is_button))
        if nbutton:
            buttons = list(map(_new, repeat(ButtonEvent, nbutton)))
            b_t, b_index, b_pressed = _BUTTON_SET
            _consume(map(b_t, buttons, repeat(t_ns, nbutton)))
            _consume(map(b_index, buttons, _BUTTON_NP[arr[gpos[is_button]]].tolist()))
            _consume(map(b_pressed, buttons, (gkind[is_button] == 3).tolist()))
            out.append((None if nbutton == ngood else is_button, buttons))
        if ndial + nbutton < ngood:
            is_ack = gkind == 1
            nack = ngood - ndial - nbutton
            out.append((None if nack == ngood else is_ack,
                        _statuses(t_ns, "info", "message", ["reset_ack"] * nack)))
        return out

    def _dial_fields(self, arr: np.ndarray, dpos: np.ndarray) -> tuple[list, list, list]:
        """Index, delta and value lists of the dial packets at ``dpos``.

        Updates the per-dial counters and values.
        """
        index = arr[dpos].astype(np.int64) - 0x30
        counter = (arr[dpos + _HI].astype(np.int64) << 8) | arr[dpos + _LO]
        # group by dial, stream order kept inside each group
        order = np.argsort(index, kind="stable")
        s_index, s_counter = index[order], counter[order]
        first = np.empty(s_index.size, dtype=bool)
        first[0] = True
        np.not_equal(s_index[1:], s_index[:-1], out=first[1:])
        prev = np.empty_like(s_counter)
        prev[1:] = s_counter[:-1]
        group_dials = s_index[first]
        prev[first] = np.array(self._counters, dtype=np.int64)[group_dials]
        s_delta = ((s_counter - prev + 0x8000) & 0xFFFF) - 0x8000
        total = np.cumsum(s_delta)
        group_start = np.flatnonzero(first)
        offset = np.array(self._values, dtype=np.int64)[group_dials] - (
            total[group_start] - s_delta[group_start])
        s_value = total + np.repeat(offset, np.diff(group_start, append=s_index.size))
        last = np.append(group_start[1:], s_index.size) - 1
        for d, c, v in zip(group_dials.tolist(), s_counter[last].tolist(),
                           s_value[last].tolist(), strict=True):
            self._counters[d] = c
            self._values[d] = v
        delta = np.empty_like(s_delta)
        delta[order] = s_delta
        value = np.empty_like(s_value)
        value[order] = s_value
        return index.tolist(), delta.tolist(), value.tolist()

    def _drop_partial(self, t_ns: int, events: list[Event]) -> None:
        self._end_garbage(t_ns, events)
        self.stats.truncated += 1
        self.stats.bytes_discarded += len(self._partial)
        events.append(_status(t_ns, "truncated", {"bytes": len(self._partial),
                                                  "dial": self._partial[0] - 0x30}))
        self._partial.clear()

    def _end_garbage(self, t_ns: int, events: list[Event]) -> None:
        if self._garbage:
            self.stats.resyncs += 1
            events.append(_status(t_ns, "resync", {"discarded": self._garbage}))
            self._garbage = 0

    def _dial_done(self, p: bytes | bytearray, t_ns: int, events: list[Event]) -> None:
        """A dial packet completed across ``feed`` calls (the scans decode inline)."""
        self._end_garbage(t_ns, events)
        self._since_good = 0
        self.stats.frames += 1
        index = p[0] - 0x30
        counter = (p[_HI] << 8) | p[_LO]
        delta = ((counter - self._counters[index] + 0x8000) & 0xFFFF) - 0x8000
        self._counters[index] = counter
        value = self._values[index] + delta
        self._values[index] = value
        events.append(DialEvent(t_ns, index, delta, value))


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
