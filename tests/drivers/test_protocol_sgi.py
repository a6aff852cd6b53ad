"""SGI dial and button box codec: packets, wrap, resync, 10 ms rule, re-init request."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.events import ButtonEvent, DialEvent, StatusEvent
from drivers.protocols.sgi_dialbox import (
    SgiCommandParser,
    SgiDecoder,
    button_code,
    button_index,
    encode_all_lamps,
    encode_auto_report_buttons,
    encode_button,
    encode_dial,
    encode_enable_buttons,
    encode_enable_dials,
    encode_filter,
    encode_lamps,
    encode_reset,
    init_sequence,
)
from service.base.errors import ProtocolError

MS = 1_000_000


def test_button_numbering_matches_vrpn():
    assert button_code(0, True) == 0xD8 and button_code(31, True) == 0xC7
    assert button_code(7, True) == 0xDF and button_code(8, True) == 0xD0
    assert button_code(16, False) == 0xE8 and button_code(0, False) == 0xF8
    events = SgiDecoder().feed(bytes(range(0xC0, 0x100)), 0)
    assert sorted(e.index for e in events if e.pressed) == list(range(32))
    assert sorted(e.index for e in events if not e.pressed) == list(range(32))


def test_dial_unwraps_across_16_bit_wrap():
    dec = SgiDecoder()
    counters = [32000, 32767, -32768, -32000, 32000]
    events = dec.feed(b"".join(encode_dial(3, c) for c in counters), 0)
    assert [e.delta for e in events] == [32000, 767, 1, 768, -1536]
    assert [e.value for e in events] == [32000, 32767, 32768, 33536, 32000]
    assert events[2].turns() == pytest.approx(32768 / 200)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.one_of(st.tuples(st.just("d"), st.integers(0, 7), st.integers(-400, 400)),
                          st.tuples(st.just("b"), st.integers(0, 31), st.booleans())),
                max_size=30),
       st.lists(st.integers(0, 100), max_size=10))
def test_round_trip_any_split(script, cuts):
    counters, data, expected = [0] * 8, b"", []
    for kind, idx, arg in script:
        if kind == "d":
            counters[idx] += arg
            data += encode_dial(idx, counters[idx])
            expected.append(("dial", idx, counters[idx]))
        else:
            data += encode_button(idx, arg)
            expected.append(("button", idx, arg))
    dec, events, prev = SgiDecoder(), [], 0
    for c in sorted(set(cuts)) + [len(data)]:
        events += dec.feed(data[prev:c], 0)
        prev = c
    got = [("dial", e.index, e.value) if isinstance(e, DialEvent) else
           ("button", e.index, e.pressed) for e in events]
    assert got == expected


def test_unknown_bytes_discarded_and_reported_per_run():
    data = b"\x01\x02" + encode_button(5, True) + b"\x99" + encode_dial(1, 10) + b"\x40\x41"
    dec = SgiDecoder()
    events = dec.feed(data, 0) + dec.flush(0)
    assert [e.details["discarded"] for e in events if isinstance(e, StatusEvent)] == [2, 1, 2]
    assert [type(e).__name__ for e in events if not isinstance(e, StatusEvent)] == [
        "ButtonEvent", "DialEvent"]
    assert dec.stats.bytes_discarded == 5 and dec.stats.resyncs == 3


def test_dial_packet_not_completed_in_10ms_is_discarded():
    dec = SgiDecoder()
    assert dec.feed(b"\x32\x00", 0) == []
    late = dec.feed(b"\x05" + encode_button(0, True), 11 * MS)
    assert [e.event for e in late if isinstance(e, StatusEvent)] == ["truncated", "resync"]
    assert [e.index for e in late if isinstance(e, ButtonEvent)] == [0]
    assert dec.stats.truncated == 1


def test_dial_packet_completed_within_10ms_is_kept():
    dec = SgiDecoder()
    dec.feed(b"\x32\x00", 0)
    events = dec.feed(b"\x05", 9 * MS)
    assert events == [DialEvent(9 * MS, 2, 5, 5)]


def test_repeated_garbage_requests_reinit_once():
    dec = SgiDecoder(garbage_limit=8)
    events = dec.feed(b"\x01" * 20, 0)
    reinit = [e for e in events if isinstance(e, StatusEvent) and e.needs_reinit]
    assert len(reinit) == 1
    after_good = dec.feed(encode_button(1, True) + b"\x01" * 7, 1)
    assert not any(getattr(e, "needs_reinit", False) for e in after_good)
    assert [e.needs_reinit for e in dec.feed(b"\x01", 2)] == [True]


def test_reset_ack_is_info_and_reset_zeroes_counters():
    dec = SgiDecoder()
    dec.feed(encode_dial(0, 50), 0)
    dec.reset()
    events = dec.feed(b"\x20" + encode_dial(0, 60), 0)
    assert events[0].details == {"message": "reset_ack"}
    assert events[1].delta == 60 and events[1].value == 60


def test_host_commands_encode_and_parse():
    assert encode_lamps(0b1_0000_0001) == bytes((0x75, 0x01, 0x01, 0x00, 0x00))
    assert encode_lamps(1 << 31) == bytes((0x75, 0, 0, 0, 0x80))
    assert encode_all_lamps(True) == b"\x4b" and encode_all_lamps(False) == b"\x4c"
    assert encode_enable_dials() == b"\x50\xff\xff"
    assert encode_filter(2, 7) == b"\x53\x02\x07"
    with pytest.raises(ProtocolError):
        encode_filter(8, 0)
    steps = init_sequence(0.5)
    stream = b"".join(s.data for s in steps)
    parsed = SgiCommandParser().feed(b"\x00" + stream)
    assert [c for c, _ in parsed] == [0x20, 0x20, 0x50, 0x71, 0x73, 0x71, 0x73]
    assert steps[1].wait_s == 0.5 and steps[1].expect == b"\x20"


def test_dial_event_schema():
    ev = SgiDecoder().feed(encode_dial(7, -3), 1_000_000_000)[0]
    assert ev.to_dict() == {"t": 1.0, "device": "dials", "kind": "dial", "index": 7,
                            "delta": -3, "value": -3, "turns": -3 / 200}
    assert ev.to_json() == (
        '{"t":1.0,"device":"dials","kind":"dial","index":7,"delta":-3,"value":-3,'
        '"turns":-0.015}')
    # turns follow the configured counts per turn; the event itself stays a count
    assert ev.to_dict(0, counts_per_turn=4)["turns"] == -0.75
    assert ev.to_json(0, 4).endswith('"value":-3,"turns":-0.75}')


class ReferenceSgi:
    """Byte-at-a-time reading of the documented rules (slow, obviously right)."""

    def __init__(self, dial_timeout_ns: int = 10 * MS, garbage_limit: int = 16) -> None:
        self.timeout, self.limit = dial_timeout_ns, garbage_limit
        self.counters, self.values = [0] * 8, [0] * 8
        self.partial, self.t_start, self.garbage, self.since = b"", 0, 0, 0
        self.stats = dict.fromkeys(("frames", "bytes_in", "bytes_discarded", "resyncs",
                                    "truncated"), 0)

    def _status(self, t, event, details, out):
        out.append(StatusEvent(t, "dials", event, details))

    def _end_garbage(self, t, out):
        if self.garbage:
            self.stats["resyncs"] += 1
            self._status(t, "resync", {"discarded": self.garbage}, out)
            self.garbage = 0

    def _drop(self, t, out):
        self._end_garbage(t, out)
        self.stats["truncated"] += 1
        self.stats["bytes_discarded"] += len(self.partial)
        self._status(t, "truncated", {"bytes": len(self.partial), "dial": self.partial[0] - 0x30},
                     out)
        self.partial = b""

    def _good(self, t, out):
        self._end_garbage(t, out)
        self.since = 0
        self.stats["frames"] += 1

    def feed(self, data, t):
        self.stats["bytes_in"] += len(data)
        out = []
        for b in data:
            if self.partial and t - self.t_start > self.timeout:
                self._drop(t, out)
            if self.partial:
                self.partial += bytes((b,))
                if len(self.partial) == 3:
                    self._good(t, out)
                    index, counter = self.partial[0] - 0x30, int.from_bytes(self.partial[1:], "big")
                    delta = (counter - self.counters[index] + 0x8000) % 0x10000 - 0x8000
                    self.counters[index] = counter
                    self.values[index] += delta
                    out.append(DialEvent(t, index, delta, self.values[index]))
                    self.partial = b""
            elif b == 0x20:
                self._good(t, out)
                self._status(t, "info", {"message": "reset_ack"}, out)
            elif 0x30 <= b <= 0x37:
                self.partial, self.t_start = bytes((b,)), t
            elif b >= 0xC0:
                self._good(t, out)
                out.append(ButtonEvent(t, ((b & 0x1F) ^ 0x18), b < 0xE0))
            else:
                self.garbage += 1
                self.since += 1
                self.stats["bytes_discarded"] += 1
                if self.since == self.limit:
                    self._status(t, "error", {"reason": "repeated_garbage", "action": "reinit"},
                                 out)
        return out

    def flush(self, t):
        out = []
        if self.partial:
            self._drop(t, out)
        self._end_garbage(t, out)
        return out


def _exact(events):
    """Events as comparable values, with the exact Python types of their fields."""
    return [(type(e).__name__, e.to_json(), tuple(type(v).__name__ for v in e.payload().values()))
            for e in events]


_PARTS = st.one_of(
    st.builds(encode_dial, st.integers(0, 7), st.integers(-40000, 40000)),
    st.builds(encode_button, st.integers(0, 31), st.booleans()),
    st.just(b"\x20"),
    st.binary(max_size=40),
    st.lists(st.sampled_from(b"\x00\x20\x30\x31\x37\x38\x7f\xc0\xdf\xe0\xff"),
             max_size=12).map(bytes),
)


@pytest.mark.parametrize("bulk_min, value_limit", [(0, None), (10**9, None), (24, None), (0, 300)])
@settings(max_examples=150, deadline=None)
@given(data=st.data())
def test_fast_paths_match_byte_at_a_time_reference(bulk_min, value_limit, data):
    """Numpy path (bulk_min 0), byte loop (huge), both mixed; same events and stats."""
    import drivers.protocols.sgi_dialbox as sgi

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(sgi, "BULK_MIN_BYTES", bulk_min)
        if value_limit is not None:  # dials outgrow the int64-safe range: byte loop fallback
            mp.setattr(sgi, "_BULK_VALUE_LIMIT", value_limit)
        _check_against_reference(data)


def _check_against_reference(data):
    stream = b"".join(data.draw(st.lists(_PARTS, max_size=40)))
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=10)))
    steps = data.draw(st.lists(st.sampled_from([0, 1, 5 * MS, 10 * MS, 11 * MS]),
                               min_size=len(cuts) + 2, max_size=len(cuts) + 2))
    limit = data.draw(st.integers(0, 20))
    dec, ref = SgiDecoder(garbage_limit=limit), ReferenceSgi(garbage_limit=limit)
    got, expected, prev, t = [], [], 0, 0
    for c, step in zip(cuts + [len(stream)], steps, strict=False):
        t += step
        got += dec.feed(stream[prev:c], t)
        expected += ref.feed(stream[prev:c], t)
        prev = c
    t += steps[-1]
    got += dec.flush(t)
    expected += ref.flush(t)
    assert got == expected
    assert _exact(got) == _exact(expected)
    assert {k: dec.stats.as_dict()[k] for k in ref.stats} == ref.stats


def test_bulk_path_long_chunks_match_reference():
    import random

    rng = random.Random(3)
    parts = []
    for i in range(6000):
        r = rng.random()
        parts.append(encode_dial(i % 8, rng.randrange(-70000, 70000)) if r < 0.7 else
                     encode_button(i % 32, r < 0.8) if r < 0.9 else
                     bytes(rng.randrange(256) for _ in range(rng.randrange(1, 30))))
    stream = b"".join(parts)
    for chunk in (257, 4096, len(stream)):
        dec, ref = SgiDecoder(), ReferenceSgi()
        got, expected = [], []
        for i in range(0, len(stream), chunk):
            got += dec.feed(stream[i:i + chunk], i)
            expected += ref.feed(stream[i:i + chunk], i)
        got += dec.flush(len(stream))
        expected += ref.flush(len(stream))
        assert _exact(got) == _exact(expected) and got == expected
        assert {k: dec.stats.as_dict()[k] for k in ref.stats} == ref.stats


@pytest.mark.parametrize("bulk_min", [0, 10**9])
def test_reinit_counts_garbage_across_a_timed_out_packet(bulk_min):
    """The truncated status reports the garbage so far; the re-init count goes on."""
    import drivers.protocols.sgi_dialbox as sgi

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(sgi, "BULK_MIN_BYTES", bulk_min)
        dec = SgiDecoder(garbage_limit=8)
        assert dec.feed(b"\x01" * 5 + b"\x32", 0) == []
        late = dec.feed(b"\x01\x01", 20 * MS)
        assert [(e.event, dict(e.details)) for e in late] == [
            ("resync", {"discarded": 5}), ("truncated", {"bytes": 1, "dial": 2})]
        assert [e.needs_reinit for e in dec.feed(b"\x01", 20 * MS)] == [True]
        assert [e.details["discarded"] for e in dec.flush(20 * MS)] == [3]


def test_button_index_inverts_button_code_for_every_button():
    # mutants: button_index's `(code & 0x1F) ^ 0x18` changed (no test called it)
    assert [button_index(button_code(i, p)) for p in (True, False) for i in range(32)] \
        == list(range(32)) * 2


def test_button_and_dial_indices_out_of_range_are_refused():
    # mutants: the index checks' `<` as `<=` and their raises deleted
    assert encode_button(31, True) == b"\xc7" and encode_dial(7, 1) == b"\x37\x00\x01"
    for bad in (-1, 32):
        with pytest.raises(ProtocolError, match="button index"):
            button_code(bad, True)
    for bad in (-1, 8):
        with pytest.raises(ProtocolError, match="dial index"):
            encode_dial(bad, 0)


def test_every_host_command_parses_with_its_argument_count():
    # mutants: HOST_COMMAND_ARGS' counts and the masks' 0xFFFFFFFF defaults changed
    stream = (encode_reset() + encode_enable_dials(0x0F) + encode_enable_buttons()
              + encode_auto_report_buttons() + encode_lamps(2) + encode_all_lamps(True)
              + encode_all_lamps(False) + encode_filter(3, 4))
    assert SgiCommandParser().feed(stream) == [
        (0x20, b""), (0x50, b"\xff\x0f"), (0x71, b"\xff" * 4), (0x73, b"\xff" * 4),
        (0x75, b"\x02\0\0\0"), (0x4B, b""), (0x4C, b""), (0x53, b"\x03\x04")]


def test_a_dial_packet_completed_10_ms_after_its_first_byte_is_kept_1_ns_later_dropped():
    # mutant: DIAL_TIMEOUT_NS one more (the rule is "more than 10 ms", not "at least")
    kept, dropped = SgiDecoder(), SgiDecoder()
    kept.feed(b"\x32\x00", 5)
    dropped.feed(b"\x32\x00", 5)
    assert kept.feed(b"\x05", 5 + 10 * MS) == [DialEvent(5 + 10 * MS, 2, 5, 5)]
    assert [e.event for e in dropped.feed(b"\x05", 5 + 10 * MS + 1)] == ["truncated"]


@pytest.mark.parametrize("bulk_min", [0, 10**9])
def test_a_dial_packet_completed_across_feeds_restarts_the_garbage_count(bulk_min):
    # mutant: the packet completed by a later feed left the count at 1, not 0, so the
    # re-init came one garbage byte early
    import drivers.protocols.sgi_dialbox as sgi

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(sgi, "BULK_MIN_BYTES", bulk_min)
        dec = SgiDecoder(garbage_limit=3)
        assert dec.feed(b"\x32\x00", 0) == []
        assert dec.feed(b"\x05", 1) == [DialEvent(1, 2, 5, 5)]
        assert dec.feed(b"\x01\x01", 2) == []
        assert [e.needs_reinit for e in dec.feed(b"\x01", 3)] == [True]


def test_a_long_chunk_of_good_packets_restarts_the_garbage_count():
    # mutant: the numpy path (a chunk of 256 bytes or more, no garbage in it) left the
    # count at 1, not 0
    dec = SgiDecoder(garbage_limit=3)
    assert len(dec.feed(encode_button(4, True) * 300, 0)) == 300
    assert dec.feed(b"\x01\x01", 1) == []
    assert [e.needs_reinit for e in dec.feed(b"\x01", 2)] == [True]


def test_garbage_limit_1_requests_a_reinit_for_every_run_in_a_long_chunk():
    # mutant: the numpy path's `limit > 0` for later runs as `limit > 1`
    press = encode_button(4, True)
    data = (press + b"\x01" + press + b"\x01\x01" + press) * 60  # 300 bytes
    dec, ref = SgiDecoder(garbage_limit=1), ReferenceSgi(garbage_limit=1)
    got, expected = dec.feed(data, 0), ref.feed(data, 0)
    assert sum(getattr(e, "needs_reinit", False) for e in expected) == 120
    assert got == expected


def test_filter_command_takes_dials_and_levels_0_to_7_only():
    # mutants: encode_filter's bounds (0 <= dial < 8, 0 <= level <= 7) moved by one
    assert encode_filter(0, 0) == b"\x53\x00\x00" and encode_filter(7, 7) == b"\x53\x07\x07"
    for dial, level in ((-1, 0), (8, 0), (0, -1), (0, 8)):
        with pytest.raises(ProtocolError, match="dial filter"):
            encode_filter(dial, level)


def test_command_parser_counts_unknown_bytes_and_keeps_a_partial_command():
    # mutants: `unknown` not counted (or counted down), the partial-command `break`
    # deleted (a command was returned with its arguments cut short)
    parser = SgiCommandParser()
    assert parser.feed(b"\x00\x99" + b"\x75\x01") == []
    assert parser.unknown == 2
    assert parser.feed(b"\x02\x03") == []
    assert parser.feed(b"\x04\x4c") == [(0x75, b"\x01\x02\x03\x04"), (0x4C, b"")]
    assert parser.unknown == 2


@pytest.mark.parametrize("sign", [1, -1])
def test_dial_values_stay_exact_past_the_int64_range(sign):
    """``value`` is unbounded (module docstring); the numpy path must not wrap it.

    Reaching 2**63 by turning takes centuries, so the running value is set directly.
    """
    # mutants: _BULK_VALUE_LIMIT raised to 2**63, its `and` with the chunk length an `or`,
    # a `<` of its range check as `>` (each lets a long chunk take the int64 path with a
    # value about to overflow)
    dec = SgiDecoder()
    start = sign * ((1 << 63) - 1000)
    dec._values[:] = [start] * 8  # every dial: the range check looks at all eight
    data = b"".join(encode_dial(3, sign * 100 * k) for k in range(1, 101))  # 300 bytes
    assert len(data) >= 256  # long enough for the numpy path
    assert [e.value for e in dec.feed(data, 0)] == [
        start + sign * 100 * k for k in range(1, 101)]


def test_the_event_setters_refuse_an_event_class_whose_fields_changed():
    # mutant: the guard's raise deleted (the setters would write the wrong fields)
    import drivers.protocols.sgi_dialbox as sgi

    with pytest.raises(TypeError, match="fields changed"):
        sgi._slot_setters(DialEvent, "t_ns", "index", "value", "delta")


def test_init_steps_are_frozen_and_the_box_talks_at_9600_baud():
    # mutants: InitStep not frozen; BAUD moved (holo-devices opens the box at BAUD)
    from dataclasses import FrozenInstanceError

    import drivers.protocols.sgi_dialbox as sgi
    from drivers.commands.holo_devices import build_parser

    with pytest.raises(FrozenInstanceError):
        init_sequence()[1].wait_s = 0.0
    assert sgi.BAUD == 9600 == build_parser().parse_args([]).dials_baud


@pytest.mark.parametrize(("head", "dials"), [
    (b"\x31\x32\x33", [DialEvent(0, 1, 0x3233, 0x3233)]),
    (b"\x30\x31\x00\x32\x00\x05", [DialEvent(0, 0, 0x3100, 0x3100), DialEvent(0, 2, 5, 5)]),
])
def test_dial_header_bytes_as_counter_bytes_in_a_long_chunk(head, dials):
    # mutants of the numpy tokeniser's swallowed-header rule: `j >= 2` as `j > 2` and
    # `h - hl[j - 2] <= 2` as `<= 1` (the third header byte, a counter byte of the first
    # packet, taken for a packet of its own), that `<= 2` as `<= 3` (the header just
    # after a whole packet taken for a counter byte)
    press = encode_button(0, True)
    events = SgiDecoder().feed(head + press * 300, 0)
    assert events[:len(dials)] == dials
    assert events[len(dials):] == SgiDecoder().feed(press * 300, 0)
