"""holo-replay refuses bytes that do not frame as the chosen protocol (no silent garbage).

The SGI dial box protocol has no framing (any byte C0-FF is a button), so a Hatire
capture read as ``sgi`` used to "decode" into ~20,000 button and dial events, exit 0.
"""

from __future__ import annotations

import json
import random

import pytest
from drivers_fixtures import MISSING, hatire_capture

from drivers.commands import holo_replay as cli_replay
from drivers.commands.holo_devices import log_devices
from drivers.protocols import hatire
from drivers.protocols import sgi_dialbox as sgi
from drivers.protocols.framing import FramingCheck, check_framing, protocols_that_frame
from drivers.reader import ReaderSettings
from drivers.recording import LogHeader, LogWriter
from sim_devices.dialbox import DialBoxSim, demo_script
from sim_devices.tracker import TrackerSim

FIXTURE = hatire_capture()


def stream(protocol: str) -> bytes:
    """A few seconds of a simulated device speaking ``protocol``."""
    if protocol == "sgi":
        box = DialBoxSim(demo_script(seconds=10), enabled=True)
        return b"".join(make() for _, make in box.frames())
    return b"".join(make() for _, make in TrackerSim(protocol).frames(3))


def replay(capsys, *argv: str) -> tuple[int, list[str], list[str]]:
    rc = cli_replay.main([*argv, "--as-fast-as-possible", "--dump"])
    out = capsys.readouterr()
    return rc, out.out.splitlines(), out.err.splitlines()


def test_the_hatire_fixture_read_as_sgi_is_refused_before_any_output(capsys):
    if not FIXTURE.is_file():
        pytest.skip(MISSING)
    rc, out, err = replay(capsys, str(FIXTURE), "--protocol", "sgi")
    assert rc == 2 and out == []
    assert err[-1] == (f"holo-replay: {FIXTURE}: does not frame as sgi: 54425 of its first "
                       "65536 bytes (83 %) rejected in 7609 runs; it frames as hatire: "
                       "pass --protocol hatire")
    # the whole file, counted: what the decoder used to turn into 19,650 events
    whole = check_framing("sgi", FIXTURE.read_bytes(), limit=None)
    assert (whole.bytes_discarded, whole.events, whole.frames) == (120748, 19650, False)
    assert check_framing("hatire", FIXTURE.read_bytes(), limit=None).frames


@pytest.mark.parametrize("chosen", ["hatire", "native", "sgi"])
@pytest.mark.parametrize("actual", ["hatire", "native", "sgi"])
def test_every_protocol_and_recording_combination(tmp_path, capsys, chosen, actual):
    capture = tmp_path / f"{actual}.bin"
    capture.write_bytes(stream(actual))
    rc, out, err = replay(capsys, str(capture), "--protocol", chosen)
    if chosen == actual:
        assert rc == 0 and out
        assert not any("frame" in line for line in err)
    else:
        assert rc == 2 and out == []
        assert f"does not frame as {chosen}: " in err[-1]
        assert err[-1].endswith(f"it frames as {actual}: pass --protocol {actual}")


def test_noise_that_frames_as_nothing_says_so(tmp_path, capsys):
    noise = tmp_path / "random.bin"
    noise.write_bytes(random.Random(7).randbytes(3000))
    rc, out, err = replay(capsys, str(noise), "--protocol", "sgi")
    assert rc == 2 and out == []
    assert err[-1].endswith("nor as any other protocol (a leading banner? --skip-bytes N "
                            "drops it)")
    assert protocols_that_frame(noise.read_bytes()) == []


def test_a_noisy_line_still_frames(tmp_path, capsys):
    """Line noise (a third of the bytes garbage) is resynchronised past, not refused."""
    box = DialBoxSim(demo_script(seconds=10), enabled=True)
    rng = random.Random(3)
    noisy = bytearray()
    for _, make in box.frames():  # after each report, 0-4 bytes of 00-1F (never valid)
        noisy += make() + bytes(rng.randrange(0x20) for _ in range(rng.randrange(5)))
    capture = tmp_path / "noisy.bin"
    capture.write_bytes(bytes(noisy))
    assert check_framing("sgi", bytes(noisy)).frames
    rc, out, err = replay(capsys, str(capture), "--protocol", "sgi")
    assert rc == 0
    assert sum(json.loads(line)["kind"] != "status" for line in out) == 355


def _log(path, devices: dict[str, tuple[str, bytes]]) -> None:
    settings = [ReaderSettings("loop://", proto, name) for name, (proto, _) in devices.items()]
    with LogWriter(path, LogHeader(log_devices(settings), start_monotonic_ns=0)) as w:
        for name, (_, data) in devices.items():
            for k in range(0, len(data), 64):
                w.write(name, 1000 + k, data[k:k + 64])


def test_a_log_of_a_device_recorded_with_the_wrong_protocol_is_named(tmp_path, capsys):
    """A log replays what holo-devices saw, so it is not refused; but events from
    bytes that do not frame are not trusted: they are named and do not count."""
    log = tmp_path / "wrong.hlog"
    _log(log, {"dials": ("sgi", stream("hatire"))})
    rc, out, err = replay(capsys, str(log))
    assert rc == 1  # only untrusted events: nothing useful
    assert out  # the dump is still what the live run printed
    assert err[-1].startswith("holo-replay: dials: the recorded bytes do not frame as sgi "
                              "(4158 of 5400 bytes (77 %) rejected in 784 runs), so its 1044 "
                              "events are not trusted; the bytes frame as hatire: recorded "
                              "with the wrong protocol?")


def test_a_good_device_beside_a_misframed_one_still_counts(tmp_path, capsys):
    log = tmp_path / "mixed.hlog"
    _log(log, {"tracker": ("hatire", stream("hatire")), "dials": ("sgi", stream("native"))})
    rc, out, err = replay(capsys, str(log))
    assert rc == 0
    assert sum("do not frame" in line for line in err) == 1
    assert "holo-replay: dials: the recorded bytes do not frame as sgi" in err[-1]


def test_a_good_log_gets_no_framing_line(tmp_path, capsys):
    log = tmp_path / "good.hlog"
    data = stream("sgi") + sgi.encode_dial(1, 5)
    _log(log, {"dials": ("sgi", data), "tracker": ("hatire", hatire.encode_pose(0, 1.0, 0, 0))})
    rc, out, err = replay(capsys, str(log))
    assert rc == 0 and not any("frame" in line for line in err)


@pytest.mark.parametrize("chunk", ["64", "7", "1000"])
def test_a_raw_sgi_capture_loses_no_dial_packet_at_chunk_edges(tmp_path, capsys, chunk):
    """Raw chunks are stamped a chunk's line time apart (67 ms for 64 bytes at 9600
    baud); the 10 ms dial rule must not drop a packet split between two of them."""
    capture = tmp_path / "sgi.bin"
    capture.write_bytes(stream("sgi"))
    rc, out, _ = replay(capsys, str(capture), "--protocol", "sgi", "--chunk-size", chunk)
    records = [json.loads(line) for line in out]
    assert rc == 0 and [r for r in records if r["kind"] == "status"] == []
    assert len(records) == check_framing("sgi", capture.read_bytes()).events == 355


def test_hatire_in_the_wrong_byte_order_is_refused_both_ways(tmp_path, capsys):
    """The frames still have their AA AA / 55 55 ends, so no byte is rejected; but the
    swapped frame counter reads as a text or undefined code, so most frames give no
    pose (the fixture: 76 made-up poses of 4,765 frames, exit 0, before)."""
    if FIXTURE.is_file():
        rc, out, err = replay(capsys, str(FIXTURE), "--protocol", "hatire",
                              "--hatire-big-endian")
        assert rc == 2 and out == []
        assert err[-1] == (f"holo-replay: {FIXTURE}: does not frame as hatire "
                           "--hatire-big-endian: 2144 of its first 2180 frames gave no "
                           "pose, dial or button; it frames as hatire: leave out "
                           "--hatire-big-endian")
    big = tmp_path / "big.bin"
    big.write_bytes(b"".join(make() for _, make in
                             TrackerSim("hatire", byte_order="big").frames(3)))
    rc, out, err = replay(capsys, str(big), "--protocol", "hatire")
    assert rc == 2 and out == []
    assert err[-1].endswith("it frames as hatire --hatire-big-endian: pass --protocol "
                            "hatire --hatire-big-endian")
    rc, out, _ = replay(capsys, str(big), "--protocol", "hatire", "--hatire-big-endian")
    assert rc == 0 and len(out) == 180


@pytest.mark.skipif(not hasattr(__import__("os"), "openpty"), reason="pty pairs need POSIX")
def test_holo_devices_names_a_port_whose_bytes_do_not_frame(capsys):
    """A Hatire tracker on the dial box's port: the live run says so at its end."""
    import threading

    from drivers.commands import holo_devices as cli_devices
    from drivers.pty_link import PtyLink

    link, stop = PtyLink(), threading.Event()
    link.stop = stop
    frames = stream("hatire")

    def play() -> None:
        while not stop.is_set():
            link.read_available()  # the driver's init commands
            link.write(frames[:600])
            stop.wait(0.02)

    player = threading.Thread(target=play, daemon=True)
    player.start()
    try:
        rc = cli_devices.main(["--dials", link.path, "--seconds", "1.5"])
    finally:
        stop.set()
        player.join(10)
        link.close()
    err = capsys.readouterr().err.splitlines()
    assert rc == 0  # it ran; the line says what it read
    assert err[-1].startswith(f"holo-devices: dials ({link.path}): the bytes read do not "
                              "frame as sgi (")
    assert err[-1].endswith("; the wrong port or protocol?")


@pytest.mark.parametrize(("bytes_in", "discarded", "rejected"), [
    (100, 63, False), (100, 64, True),  # at least 64 bytes discarded ...
    (128, 64, False), (128, 65, True),  # ... and more than half of them
])
def test_rejected_needs_64_bytes_and_more_than_half_discarded(bytes_in, discarded, rejected):
    # mutants: MIN_REJECTED_BYTES 64 -> 65, `>=` as `>`, `> MAX_REJECTED_FRACTION` as `>=`
    check = FramingCheck("hatire", bytes_in, discarded)
    assert check.rejected == rejected and check.frames == (not rejected)


@pytest.mark.parametrize(("packets", "events", "eventless"), [
    (19, 0, False), (20, 9, True), (20, 10, False),
])
def test_eventless_needs_20_frames_and_fewer_than_half_with_events(packets, events, eventless):
    # mutants: MIN_FRAMES 20 -> 21, `>=` as `>`, `2 * events < packets` as `<=`
    check = FramingCheck("hatire", 1000, 0, 0, events, packets)
    assert check.eventless == eventless and check.frames == (not eventless)


def test_describe_names_bytes_when_rejected_and_frames_when_only_eventless():
    # mutants: describe's `eventless and not rejected` as `or`; the counts' default 0
    both = FramingCheck("sgi", 1000, 900, 3, 0, 30)
    assert both.describe() == "900 of 1000 bytes (90 %) rejected in 3 runs"
    assert FramingCheck("sgi", 1000, 0, 0, 5, 30).describe("its first ") \
        == "25 of its first 30 frames gave no pose, dial or button"
    assert FramingCheck("sgi") == FramingCheck("sgi", 0, 0, 0, 0, 0)
    assert FramingCheck("sgi").describe() == "0 of 0 bytes (0 %) rejected in 0 runs"
    assert FramingCheck("sgi", 200, 100, 1).describe() \
        == "100 of 200 bytes (50 %) rejected in 1 run"


def test_check_framing_reads_only_the_first_limit_bytes():
    # mutant: `limit is None` as `is not` (the limit ignored)
    data = b"".join(hatire.encode_pose(i, 0, 0, 0) for i in range(4))
    assert check_framing("hatire", data, limit=60).packets == 2
    assert check_framing("hatire", data, limit=None).packets == 4


def test_checks_of_two_parts_of_a_stream_add_up():
    # mutant: __add__'s packets sum changed
    a = FramingCheck("native", 10, 1, 2, 3, 4)
    assert a + FramingCheck("native", 20, 5, 6, 7, 8) == FramingCheck("native", 30, 6, 8, 10, 12)
