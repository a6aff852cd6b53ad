"""Session log format: round trip, torn tails, corruption, killed writers."""

import json
import signal
import subprocess
import sys
import textwrap
import warnings
import zlib
from pathlib import Path

import pytest
from drivers_fixtures import MISSING, hatire_capture
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.recording import (
    CRC,
    FILE_HEAD,
    MAGIC,
    REC_HEAD,
    SYNC,
    VERSION,
    DeviceInfo,
    LogHeader,
    LogReader,
    LogWarning,
    LogWriter,
    RawCaptureReader,
    Record,
    SerialSettings,
    encode_file_header,
    encode_record,
)
from service.base.errors import LogFileError, SettingsError

ROOT = Path(__file__).resolve().parents[2]
HATIRE = hatire_capture()


def header() -> LogHeader:
    return LogHeader(
        (
            DeviceInfo("tracker", "hatire", SerialSettings("loop://", 115200, 8, "N", 1)),
            DeviceInfo("dials", "dialbox", SerialSettings("/dev/ttyS1", 9600, 8, "E", 2)),
        ),
        start_wall_ns=1_700_000_000_000_000_000,
        start_monotonic_ns=5_000,
        extra={"note": "test"},
    )


def sample_records(n: int) -> list[Record]:
    devs = ("tracker", "dials")
    return [Record(devs[i % 2], 5_000 + i * 12_345, bytes([i % 256]) * (i % 37)) for i in range(n)]


def write_log(path: Path, records: list[Record]) -> list[int]:
    """Write records; return the file offset where each record starts."""
    offsets = []
    with LogWriter(path, header()) as w:
        for r in records:
            w._f.flush()
            offsets.append(path.stat().st_size)
            w.write(r.device, r.t_ns, r.data)
    return offsets


def read_all(path: Path) -> tuple[list[Record], LogReader]:
    reader = LogReader(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LogWarning)
        return list(reader), reader


def test_round_trip_keeps_bytes_times_devices_and_header(tmp_path):
    recs = sample_records(50)
    write_log(tmp_path / "a.hlog", recs)
    got, reader = read_all(tmp_path / "a.hlog")
    assert got == recs
    assert reader.header == header()
    assert (reader.stats.records, reader.stats.torn, reader.stats.corrupt) == (50, 0, 0)
    d = reader.header.devices[1]
    assert (d.protocol, d.serial.baudrate, d.serial.parity, d.serial.stopbits) == (
        "dialbox",
        9600,
        "E",
        2,
    )


def test_header_is_plain_json_after_magic(tmp_path):
    write_log(tmp_path / "a.hlog", [])
    raw = (tmp_path / "a.hlog").read_bytes()
    assert raw.startswith(MAGIC)
    js = json.loads(raw[18:-4])
    assert js["devices"][0]["serial"]["url"] == "loop://"
    assert js["start_wall_iso"].startswith("2023-11-14")


def test_torn_at_every_offset_of_last_record_keeps_all_complete_ones(tmp_path):
    recs = sample_records(6) + [Record("tracker", 99_999, b"\xaa\xaaSYNC?\xa7RC\x5d" * 3)]
    path = tmp_path / "full.hlog"
    offsets = write_log(path, recs)
    full = path.read_bytes()
    for cut in range(offsets[-1], len(full)):
        p = tmp_path / "cut.hlog"
        p.write_bytes(full[:cut])
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            reader = LogReader(p)
            got = list(reader)
        assert got == recs[:-1], cut
        torn_msgs = [w for w in caught if "torn last record" in str(w.message)]
        assert len(torn_msgs) == len(caught) == (cut > offsets[-1])
        assert reader.stats.torn == (cut > offsets[-1])
        assert reader.stats.skipped_bytes == cut - offsets[-1]
        assert reader.stats.corrupt == 0


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(victim=st.integers(0, 9), byte_in_record=st.integers(0, 10_000), xor=st.integers(1, 255))
def test_flipped_byte_is_reported_and_later_records_still_read(
    tmp_path, victim, byte_in_record, xor
):
    recs = sample_records(10)
    path = tmp_path / "f.hlog"
    path.unlink(missing_ok=True)
    offsets = write_log(path, recs)
    raw = bytearray(path.read_bytes())
    end = offsets[victim + 1] if victim + 1 < len(offsets) else len(raw)
    at = offsets[victim] + byte_in_record % (end - offsets[victim])
    raw[at] ^= xor
    path.write_bytes(bytes(raw))
    with pytest.warns(LogWarning, match="corrupt"):
        reader = LogReader(path)
        got = list(reader)
    assert got == recs[:victim] + recs[victim + 1 :]
    assert reader.stats.corrupt == 1 and reader.stats.torn == 0


def test_garbage_between_records_is_skipped(tmp_path):
    recs = sample_records(4)
    path = tmp_path / "g.hlog"
    offsets = write_log(path, recs)
    raw = path.read_bytes()
    junk = b"\xa7RC\x5d" + b"\x00" * 40 + b"\xa7R"
    path.write_bytes(raw[: offsets[2]] + junk + raw[offsets[2] :])
    got, reader = read_all(path)
    assert got == recs
    assert reader.stats.corrupt == 1
    assert reader.stats.skipped_bytes == len(junk)


@pytest.mark.parametrize(
    ("content", "match"),
    [
        (b"", "too short"),
        (b"NOTALOG!" * 4, "magic"),
        (MAGIC + b"\x09\x00" + b"\x00" * 8, "version"),
    ],
)
def test_unreadable_file_header_raises(tmp_path, content, match):
    p = tmp_path / "bad.hlog"
    p.write_bytes(content)
    with pytest.raises(LogFileError, match=match):
        LogReader(p)


def test_torn_or_corrupt_file_header_raises(tmp_path):
    p = tmp_path / "h.hlog"
    write_log(p, [])
    raw = p.read_bytes()
    (tmp_path / "t.hlog").write_bytes(raw[:-3])
    with pytest.raises(LogFileError, match="torn"):
        LogReader(tmp_path / "t.hlog")
    bad = bytearray(raw)
    bad[30] ^= 1
    (tmp_path / "c.hlog").write_bytes(bytes(bad))
    with pytest.raises(LogFileError, match="CRC"):
        LogReader(tmp_path / "c.hlog")
    with pytest.raises(LogFileError):
        LogReader(tmp_path / "missing.hlog")


@pytest.mark.parametrize(("change", "words"), [
    (lambda h: h.update(start_wall_ns=float("inf")), "OverflowError"),  # written as 1e400
    (lambda h: h["devices"][0].update(name=None), "device name must be a string"),
    (lambda h: h["devices"][1].update(protocol=7), "device protocol must be a string"),
    (lambda h: h.update(devices=[3]), "TypeError"),
])
def test_a_crafted_header_with_a_valid_crc_is_a_log_file_error(tmp_path, change, words):
    js = header().to_json()
    change(js)
    body = json.dumps(js).replace("Infinity", "1e400").encode()
    p = tmp_path / "x.hlog"
    p.write_bytes(FILE_HEAD.pack(MAGIC, VERSION, len(body)) + body
                  + CRC.pack(zlib.crc32(body)))
    with pytest.raises(LogFileError, match=f"bad log header: .*{words}"):
        LogReader(p)


def test_writer_rejects_unknown_device_existing_file_and_closed_use(tmp_path):
    p = tmp_path / "w.hlog"
    with LogWriter(p, header()) as w, pytest.raises(SettingsError):
        w.write("mouse", 1, b"x")
    with pytest.raises(LogFileError):
        LogWriter(p, header())
    w = LogWriter(p, header(), overwrite=True)
    w.close()
    with pytest.raises(LogFileError):
        w.write("tracker", 1, b"x")
    with pytest.raises(SettingsError):
        LogHeader((DeviceInfo("a", "x"), DeviceInfo("a", "y")))


WRITER = textwrap.dedent(
    """
    import sys
    from drivers.recording import DeviceInfo, LogHeader, LogWriter
    h = LogHeader((DeviceInfo("tracker", "hatire"),))
    with LogWriter(sys.argv[1], h, flush_every=int(sys.argv[2])) as w:
        i = 0
        while True:
            w.write("tracker", i, i.to_bytes(4, "little") * (1 + i % 50))
            i += 1
            if i == 300:
                print("ready", flush=True)
    """
)


@pytest.mark.parametrize("flush_every", [1, 7])
def test_killed_writer_process_leaves_readable_file(tmp_path, flush_every):
    path = tmp_path / "killed.hlog"
    proc = subprocess.Popen(
        [sys.executable, "-c", WRITER, str(path), str(flush_every)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
    )
    try:
        assert proc.stdout.readline() == b"ready\n"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    assert proc.returncode == -signal.SIGKILL
    got, reader = read_all(path)
    assert len(got) >= 300 - flush_every
    assert reader.stats.corrupt == 0 and reader.stats.torn <= 1
    for i, r in enumerate(got):
        assert (r.device, r.t_ns, r.data) == ("tracker", i, i.to_bytes(4, "little") * (1 + i % 50))


def test_raw_capture_reader_chunks_with_line_rate_times(tmp_path):
    p = tmp_path / "raw.bin"
    p.write_bytes(bytes(range(256)) * 4)
    r = RawCaptureReader(p, protocol="hatire", baudrate=9600, chunk_size=100, skip_bytes=24)
    recs = list(r)
    assert b"".join(x.data for x in recs) == (bytes(range(256)) * 4)[24:]
    assert [len(x.data) for x in recs] == [100] * 10
    assert recs[0].t_ns == round(100 * 10 / 9600 * 1e9)
    assert recs[-1].t_ns == round(1000 * 10 / 9600 * 1e9)
    assert r.stats.records == 10
    assert r.header.devices[0].protocol == "hatire"
    assert r.header.devices[0].serial.baudrate == 9600


@pytest.mark.skipif(not HATIRE.is_file(), reason=MISSING)
def test_raw_capture_reader_on_hatire_fixture():
    recs = list(RawCaptureReader(HATIRE, protocol="hatire", chunk_size=30, skip_bytes=79))
    data = b"".join(r.data for r in recs)
    assert data == HATIRE.read_bytes()[79:]
    assert data[:2] == b"\xaa\xaa"
    assert recs[-1].t_ns == pytest.approx(len(data) * 10 / 115200 * 1e9, abs=1)


@pytest.mark.skipif(not HATIRE.is_file(), reason=MISSING)
def test_raw_capture_replays_through_the_hatire_decoder():
    hatire = pytest.importorskip("drivers.protocols.hatire")
    dec = hatire.HatireDecoder(angle_limit=360.0)
    poses = []
    for rec in RawCaptureReader(HATIRE, protocol="hatire", chunk_size=17):
        poses += [e for e in dec.feed(rec.data, rec.t_ns) if hasattr(e, "yaw")]
    assert len(poses) == 4765
    assert all(b.t_ns >= a.t_ns for a, b in zip(poses, poses[1:], strict=False))


def test_log_round_trip_of_a_hatire_stream_feeds_the_decoder_identically(tmp_path):
    hatire = pytest.importorskip("drivers.protocols.hatire")
    stream = b"".join(hatire.encode_pose(k, k * 0.5, -k, 1.0) for k in range(100))
    path = tmp_path / "h.hlog"
    with LogWriter(path, LogHeader((DeviceInfo("tracker", "hatire"),))) as w:
        for k in range(0, len(stream), 23):
            w.write("tracker", k * 1000, stream[k : k + 23])
    dec = hatire.HatireDecoder()
    poses = [e for r in LogReader(path) for e in dec.feed(r.data, r.t_ns) if hasattr(e, "yaw")]
    assert [p.seq for p in poses] == list(range(100))
    assert poses[10].yaw == 5.0


def test_record_and_file_header_bytes_are_the_documented_layout():
    # docs/recording-format.md pins the bytes; mutants: VERSION 1 -> 2, flags 0 -> 1
    data = b"ab"
    head = b"\xa7RC\x5d" + (1).to_bytes(2, "little") + b"\x00\x00" \
        + (-5).to_bytes(8, "little", signed=True) + (2).to_bytes(4, "little")
    want = head + zlib.crc32(head[4:]).to_bytes(4, "little") + data \
        + zlib.crc32(data).to_bytes(4, "little")
    assert encode_record(1, -5, data) == want
    assert encode_file_header(header())[:14] == b"HOLOLOG\x00\r\n\x1a\n\x01\x00"


def test_records_up_to_16_mib_and_not_one_byte_more():
    # the documented bound (16 MiB); mutants: the check or its raise deleted, 1 << 24 changed
    assert len(encode_record(0, 0, bytes(16 << 20))) == 16 << 20 | 28
    with pytest.raises(SettingsError, match="exceeds"):
        encode_record(0, 0, bytes((16 << 20) + 1))


def _crafted(dev: int, n: int, data: bytes) -> bytes:
    """A record whose CRCs are right whatever its fields say."""
    head = REC_HEAD.pack(SYNC, dev, 0, 9, n)
    return head + CRC.pack(zlib.crc32(head[4:])) + data + CRC.pack(zlib.crc32(data))


@pytest.mark.parametrize("junk", [
    _crafted(2, 3, b"xyz"),  # a device the header does not have (2 devices)
    _crafted(0, (16 << 20) + 1, b""),  # longer than any record may be
])
def test_a_record_with_good_crcs_but_impossible_fields_is_skipped_as_corrupt(tmp_path, junk):
    # mutants: `dev >= n_devices or n > MAX_RECORD` as `and`, its ("bad", 0) return
    # replaced (an IndexError, or a record of a device that does not exist)
    recs = sample_records(4)
    path = tmp_path / "f.hlog"
    offsets = write_log(path, recs)
    raw = path.read_bytes()
    path.write_bytes(raw[: offsets[2]] + junk + raw[offsets[2]:])
    got, reader = read_all(path)
    assert got == recs
    assert (reader.stats.corrupt, reader.stats.skipped_bytes) == (1, len(junk))


def test_device_index_names_a_device_missing_from_the_header():
    # mutant: the raise deleted (None returned)
    assert header().device_index("dials") == 1
    with pytest.raises(SettingsError, match="'mouse' is not in the log header"):
        header().device_index("mouse")


def test_each_record_is_on_disk_after_write_by_default_and_after_flush_every_otherwise(
        tmp_path):
    # a killed writer loses at most the unflushed records; mutants: flush_every's
    # default 1 -> 2, the pending count starting at 1, the flush_every < 1 raise deleted
    rec = 28 + 3
    with LogWriter(tmp_path / "a.hlog", header()) as w:
        start = (tmp_path / "a.hlog").stat().st_size
        w.write("tracker", 1, b"abc")
        assert (tmp_path / "a.hlog").stat().st_size == start + rec
        assert w.records == 1
    with LogWriter(tmp_path / "b.hlog", header(), flush_every=3) as w:
        sizes = []
        for i in range(3):
            w.write("dials", i, b"xyz")
            sizes.append((tmp_path / "b.hlog").stat().st_size - start)
        assert sizes == [0, 0, 3 * rec]
    with pytest.raises(SettingsError, match="flush_every must be >= 1"):
        LogWriter(tmp_path / "c.hlog", header(), flush_every=0)
    assert not (tmp_path / "c.hlog").exists()


def test_a_header_that_is_not_json_but_has_a_valid_crc_is_a_log_file_error(tmp_path):
    # mutant: the "header is not JSON" raise deleted (a TypeError unpacking None)
    body = b"{not json"
    p = tmp_path / "j.hlog"
    p.write_bytes(FILE_HEAD.pack(MAGIC, VERSION, len(body)) + body + CRC.pack(zlib.crc32(body)))
    with pytest.raises(LogFileError, match="header is not JSON"):
        LogReader(p)


def test_a_16_mib_record_reads_back_whole(tmp_path):
    # mutant: the reader's `n > MAX_RECORD` as `>=` (a maximal record skipped as corrupt)
    data = bytes(range(256)) * (1 << 16)
    path = tmp_path / "big.hlog"
    with LogWriter(path, header()) as w:
        w.write("dials", 3, data)
    got, reader = read_all(path)
    assert got == [Record("dials", 3, data)] and reader.stats.corrupt == 0


@pytest.mark.parametrize("bad", [dict(baudrate=0), dict(chunk_size=0), dict(skip_bytes=-1),
                                 dict(bits_per_byte=0)])
def test_raw_capture_reader_refuses_each_impossible_setting(tmp_path, bad):
    # mutant: the settings check's `or`s as `and` (one bad setting alone accepted)
    (tmp_path / "c.bin").write_bytes(b"x")
    with pytest.raises(SettingsError):
        RawCaptureReader(tmp_path / "c.bin", protocol="hatire", **bad)


def test_raw_capture_reader_defaults_to_64_byte_chunks_from_the_first_byte(tmp_path):
    # mutants: chunk_size default 64 -> 65, skip_bytes default 0 -> 1
    (tmp_path / "c.bin").write_bytes(bytes(range(100)))
    got = list(RawCaptureReader(tmp_path / "c.bin", protocol="hatire"))
    assert [r.data for r in got] == [bytes(range(64)), bytes(range(64, 100))]
    assert RawCaptureReader(tmp_path / "c.bin", protocol="x").header.extra["synthetic_times"]


def test_raw_capture_reader_of_a_missing_file_is_a_log_file_error(tmp_path):
    # mutant: the "no such capture file" raise deleted
    with pytest.raises(LogFileError, match="no such capture file"):
        RawCaptureReader(tmp_path / "none.bin", protocol="hatire")


def test_a_header_holds_1_to_65535_devices():
    # device ids are uint16; mutants: `0 < len(names) < 65536` with < as <=
    names = [f"d{i}" for i in range(65536)]
    assert len(LogHeader(tuple(DeviceInfo(n, "x") for n in names[:1])).devices) == 1
    assert len(LogHeader(tuple(DeviceInfo(n, "x") for n in names[1:])).devices) == 65535
    for bad in ((), tuple(DeviceInfo(n, "x") for n in names)):
        with pytest.raises(SettingsError, match="1..65535"):
            LogHeader(bad)


@pytest.mark.parametrize("tail", [b"\x00" * 10, b"\x00" * 40, b"\xa7R", b"\xa7RC\x5d\x00"])
def test_junk_after_the_last_record_is_corrupt_unless_it_begins_a_record(tmp_path, tail):
    # short junk that cannot begin a record is corrupt, not a torn record; junk with
    # no sync after it is skipped to the end.  Mutants: the torn check's tail
    # buf[pos:pos + len(SYNC)] as pos - len(SYNC), the resync's `pos == -1` as -2
    recs = sample_records(3)
    path = tmp_path / "t.hlog"
    write_log(path, recs)
    path.write_bytes(path.read_bytes() + tail)
    got, reader = read_all(path)
    assert got == recs
    torn = tail.startswith(b"\xa7")
    assert (reader.stats.torn, reader.stats.corrupt) == (int(torn), int(not torn))
    assert reader.stats.skipped_bytes == len(tail)


def test_a_damaged_region_with_false_sync_markers_in_it_is_one_corrupt_region(tmp_path):
    # mutant: the resync's check of each sync found (`[0] == "bad"` as `[1]`) ignored
    recs = sample_records(4)
    path = tmp_path / "s.hlog"
    offsets = write_log(path, recs)
    raw = path.read_bytes()
    junk = b"\x00" + (SYNC + b"\x00" * 30) * 3
    path.write_bytes(raw[: offsets[2]] + junk + raw[offsets[2]:])
    got, reader = read_all(path)
    assert got == recs
    assert (reader.stats.corrupt, reader.stats.skipped_bytes) == (1, len(junk))


def test_raw_capture_reader_takes_one_byte_chunks_at_one_baud(tmp_path):
    # the smallest settings are valid; mutants: `chunk_size <= 0` / `baudrate <= 0` as <= 1
    (tmp_path / "c.bin").write_bytes(b"ab")
    got = list(RawCaptureReader(tmp_path / "c.bin", protocol="x", chunk_size=1, baudrate=1))
    assert [(r.data, r.t_ns) for r in got] == [(b"a", 10 * 10**9), (b"b", 20 * 10**9)]
