"""Fault injection: each fault class, seeded, with exact counts checked against decoders."""

from __future__ import annotations

import pytest

from drivers.events import PoseEvent
from drivers.protocols import make_decoder
from service.base.errors import SettingsError
from sim_devices.faults import (
    Disconnect,
    FaultInjector,
    FaultSpec,
    Pause,
    Write,
    wrong_baud_bytes,
)
from sim_devices.motion import make_motion
from sim_devices.tracker import TrackerSim

N = 400


def run_offline(protocol: str, spec: FaultSpec, n: int = N):
    """Frames through the injector into one byte string, decoded in one go."""
    sim = TrackerSim(protocol, make_motion("walk", seed=1), rate_hz=100)
    inj = FaultInjector(spec)
    actions = [a for _t, make in sim.frames(n / 100) for a in inj.apply(make())]
    data = b"".join(a.data for a in actions if isinstance(a, Write))
    dec = make_decoder(protocol)
    events = dec.feed(data, 0) + dec.flush(0)
    seqs = [e.seq for e in events if isinstance(e, PoseEvent)]
    return inj.ledger, dec, seqs, actions


def expected_gaps(seqs: list[int]) -> int:
    return sum(1 for a, b in zip(seqs, seqs[1:], strict=False) if b != a + 1)


def damaged(ledger, kind: str) -> dict[int, int]:
    return {i: d for i, (k, d) in ledger.damaged.items() if k == kind}


@pytest.mark.parametrize("protocol", ["native", "hatire"])
def test_no_faults_is_lossless(protocol):
    ledger, dec, seqs, _ = run_offline(protocol, FaultSpec())
    assert seqs == list(range(N)) and ledger.intact == seqs
    assert dec.stats.bytes_discarded == 0 and not ledger.counts


def test_corrupt_native_every_intact_frame_and_exact_crc_errors():
    ledger, dec, seqs, _ = run_offline("native", FaultSpec(corrupt=0.1, seed=11))
    hits = damaged(ledger, "corrupt")
    assert len(hits) == ledger.counts["corrupt"] > 20
    assert seqs == ledger.intact  # every intact frame recovered, none invented
    assert dec.stats.crc_errors == sum(1 for pos in hits.values() if pos >= 5)
    assert dec.stats.counter_gaps == expected_gaps(ledger.intact)


def test_corrupt_hatire_only_framing_hits_lose_frames():
    ledger, dec, seqs, _ = run_offline("hatire", FaultSpec(corrupt=0.1, seed=12))
    hits = damaged(ledger, "corrupt")
    framing = {i for i, pos in hits.items() if pos in (0, 1, 28, 29)}
    code_hit = {i for i, pos in hits.items() if pos in (2, 3)}
    assert set(ledger.intact) <= set(seqs) | code_hit
    assert dec.stats.frames == N - len(framing)  # no checksum: payload hits pass
    assert not framing & set(seqs)


@pytest.mark.parametrize("protocol", ["native", "hatire"])
def test_truncate_counts(protocol):
    ledger, dec, seqs, _ = run_offline(protocol, FaultSpec(truncate=0.08, seed=13))
    cut = damaged(ledger, "truncate")
    assert len(cut) == ledger.counts["truncate"] > 15
    assert seqs == ledger.intact
    last = N - 1
    if protocol == "native":
        # a cut frame with a full header fails its CRC against the next frame's bytes
        assert dec.stats.crc_errors == sum(1 for i, k in cut.items() if k >= 5 and i != last)
    else:
        # a cut frame with header + code is reported as truncated; shorter cuts are garbage
        assert dec.stats.truncated == sum(1 for i, k in cut.items() if k >= 4 or i == last)
    assert dec.stats.counter_gaps == expected_gaps(ledger.intact)


@pytest.mark.parametrize("protocol", ["native", "hatire"])
def test_drop_bytes_loses_only_damaged_frames(protocol):
    ledger, dec, seqs, _ = run_offline(protocol, FaultSpec(drop=0.08, seed=14))
    assert ledger.counts["drop"] > 15
    assert seqs == ledger.intact
    assert dec.stats.counter_gaps == expected_gaps(ledger.intact)


@pytest.mark.parametrize("protocol", ["native", "hatire"])
def test_bursts_discard_exactly_the_garbage(protocol):
    ledger, dec, seqs, _ = run_offline(protocol, FaultSpec(burst=0.1, seed=15))
    assert ledger.counts["burst"] > 20
    assert seqs == list(range(N))
    assert dec.stats.bytes_discarded == ledger.burst_bytes
    assert dec.stats.counter_gaps == 0


@pytest.mark.parametrize("protocol", ["native", "hatire"])
def test_wrong_baud_garbage(protocol):
    ledger, dec, seqs, _ = run_offline(protocol, FaultSpec(wrong_baud=0.1, seed=16))
    assert ledger.counts["wrong_baud"] > 20
    assert seqs == ledger.intact
    assert dec.stats.bytes_discarded == sum(damaged(ledger, "wrong_baud").values())


@pytest.mark.parametrize("protocol", ["native", "hatire"])
def test_split_writes_same_events(protocol):
    ledger, dec, seqs, actions = run_offline(protocol, FaultSpec(split=True, max_split=7,
                                                                 seed=17))
    sizes = [len(a.data) for a in actions]
    assert max(sizes) <= 7 and ledger.counts["split"] == N
    assert seqs == list(range(N))
    dec2 = make_decoder(protocol)
    events = [e for a in actions for e in dec2.feed(a.data, 0)]
    assert [e.seq for e in events] == seqs


def test_pause_and_disconnect_actions_are_placed_and_counted():
    ledger, _dec, seqs, actions = run_offline(
        "native", FaultSpec(pause=0.05, disconnect=0.02, pause_s=0.5, reconnect_s=2, seed=18))
    pauses = [a for a in actions if isinstance(a, Pause)]
    drops = [a for a in actions if isinstance(a, Disconnect)]
    assert len(pauses) == ledger.counts["pause"] > 5
    assert len(drops) == ledger.counts["disconnect"] > 2
    assert {a.seconds for a in pauses} == {0.5} and {a.seconds for a in drops} == {2}
    assert seqs == list(range(N))


def test_same_seed_same_faults_different_seed_different():
    def run(seed):
        inj = FaultInjector(FaultSpec(corrupt=0.1, burst=0.1, split=True, seed=seed))
        return [inj.apply(bytes(range(40))) for _ in range(50)]
    assert run(1) == run(1)
    assert run(1) != run(2)


def test_mixed_faults_native_recovers_every_intact_frame():
    spec = FaultSpec(corrupt=0.03, drop=0.03, truncate=0.03, wrong_baud=0.02, burst=0.05,
                     split=True, seed=19)
    ledger, dec, seqs, _ = run_offline("native", spec, n=600)
    assert seqs == ledger.intact
    assert len(ledger.intact) + len(ledger.damaged) == 600


def test_wrong_baud_model():
    assert wrong_baud_bytes(b"hello", 1.0) == b"hello"
    assert wrong_baud_bytes(b"hello", 12.0) != b"hello"
    assert len(wrong_baud_bytes(bytes(30), 12.0)) < 30  # slow reader sees fewer bytes
    assert len(wrong_baud_bytes(b"\x55" * 3, 1 / 12)) > 3  # fast reader sees more


def test_spec_parsing_and_validation():
    spec = FaultSpec.parse("corrupt=0.1, split, burst_len=2-5, seed=9, max_split=4")
    assert spec == FaultSpec(corrupt=0.1, split=True, burst_len=(2, 5), seed=9, max_split=4)
    assert FaultSpec.parse("") == FaultSpec() and not FaultSpec().any and spec.any
    for bad in ("corrupt=2", "melt=0.1", "corrupt=x", "corrupt=0.6,drop=0.6"):
        with pytest.raises(SettingsError):
            FaultSpec.parse(bad)


@pytest.mark.parametrize(("bad", "says"), [
    ("reconnect_s=inf", "reconnect_s must be a finite number of seconds >= 0"),  # never back
    ("pause_s=-1", "pause_s must be a finite number of seconds >= 0"),
    ("pause_s=nan", "pause_s must be a finite number of seconds >= 0"),
    ("baud_ratio=0", "baud_ratio must be a finite number > 0"),
    ("baud_ratio=inf", "baud_ratio must be a finite number > 0"),  # crashed the run
    ("drop=0.1,drop=0.2", "fault drop given twice"),  # the later one silently won
    ("burst_len=-3", "fault burst_len='-3' is not a count or a LO-HI range"),
])
def test_spec_values_that_would_hang_crash_or_mislead_are_refused(bad, says):
    with pytest.raises(SettingsError, match=says):
        FaultSpec.parse(bad)
