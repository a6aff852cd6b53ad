"""holo-replay: the Hatire fixture, timing, skip, loop, torn logs, writing into a pty."""

from __future__ import annotations

import fcntl
import json
import os
import select
import signal
import struct
import subprocess
import sys
import termios
import threading
import time
import tty
from pathlib import Path

import pytest
from drivers_fixtures import MISSING, hatire_capture
from testkit import HANG_S, wait_for

from drivers.commands import holo_replay as cli_replay
from drivers.commands.holo_devices import header_extra, log_devices
from drivers.events import PoseEvent
from drivers.protocols import hatire, make_decoder
from drivers.protocols import sgi_dialbox as sgi
from drivers.reader import Control, DeviceReader, ReaderSettings
from drivers.recording import LogHeader, LogWriter
from drivers.subscriber import DeviceSubscriber

ROOT = Path(__file__).resolve().parents[2]
FIXTURE = hatire_capture()
posix_only = pytest.mark.skipif(sys.platform == "win32", reason="pty pairs need POSIX")
T0 = 5_000_000_000


def make_log(path: Path, n: int = 20, period_s: float = 0.01) -> list[bytes]:
    """A tracker log: an 'opened' control record, then one Hatire frame per record."""
    header = LogHeader(log_devices([ReaderSettings("loop://", "hatire", "tracker")]),
                       start_monotonic_ns=T0)
    frames = [hatire.encode_pose(k, float(k), 0.0, 0.0) for k in range(n)]
    with LogWriter(path, header) as w:
        opened = Control("tracker", T0 + 1000, "info", {"message": "opened"}, reset=True)
        w.write("tracker:control", opened.t_ns, opened.to_bytes())
        for k, frame in enumerate(frames):
            w.write("tracker", T0 + round((k + 1) * period_s * 1e9), frame)
    return frames


def dump(capsys, *argv: str) -> list[dict]:
    assert cli_replay.main([*argv, "--dump"]) == 0
    return [json.loads(line) for line in capsys.readouterr().out.splitlines()]


def test_hatire_fixture_as_fast_as_possible_gives_4765_pose_lines():
    if not FIXTURE.is_file():
        pytest.skip(MISSING)
    out = subprocess.run([sys.executable, "-m", "drivers.commands.holo_replay", str(FIXTURE),
                          "--protocol", "hatire", "--as-fast-as-possible", "--dump"],
                         cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    records = [json.loads(line) for line in out.stdout.splitlines()]
    poses = [r for r in records if r["kind"] == "pose"]
    assert len(poses) == 4765
    assert sum(r.get("event") == "counter_gap" for r in records) == 2
    assert poses[0]["t"] > 0 and all(r["device"] == "tracker" for r in records)
    # the end of the replay flushes the decoder: the torn last frame is reported
    truncated = [r for r in records if r.get("event") == "truncated"]
    assert truncated == [records[-1]] and truncated[0]["details"] == {"bytes": 19}
    assert truncated[0]["t"] == records[-2]["t"]  # at the time of the last chunk


def test_log_replay_times_and_values(tmp_path, capsys):
    log = tmp_path / "s.hlog"
    make_log(log)
    records = dump(capsys, str(log), "--as-fast-as-possible")
    assert records[0]["kind"] == "status" and records[0]["t"] == 1e-6
    poses = records[1:]
    assert [p["seq"] for p in poses] == list(range(20))
    assert [p["t"] for p in poses] == [(k + 1) * 0.01 for k in range(20)]
    assert poses[3]["yaw"] == 3.0


def test_recorded_timing_and_speed(tmp_path, capsys):
    log = tmp_path / "s.hlog"
    make_log(log, n=21, period_s=0.02)  # 0.4 s between first and last frame
    start = time.monotonic()
    assert len(dump(capsys, str(log), "--speed", "2")) == 22
    elapsed = time.monotonic() - start
    assert elapsed >= 0.4 / 2 * 0.95


def test_skip_keeps_decoder_state_and_loop_repeats(tmp_path, capsys):
    log = tmp_path / "s.hlog"
    make_log(log)
    skipped = dump(capsys, str(log), "--as-fast-as-possible", "--skip", "0.1")
    assert [r["seq"] for r in skipped] == list(range(10, 20))  # from 0.1 s after the first
    assert all(r["kind"] == "pose" for r in skipped)  # no false counter gap at the cut
    looped = dump(capsys, str(log), "--as-fast-as-possible", "--loop", "--passes", "2")
    assert [r.get("seq") for r in looped] == 2 * ([None] + list(range(20)))


def test_each_pass_ends_with_a_flush_of_a_torn_frame(tmp_path, capsys):
    log = tmp_path / "s.hlog"
    header = LogHeader(log_devices([ReaderSettings("loop://", "hatire", "tracker")]),
                       start_monotonic_ns=T0)
    with LogWriter(log, header) as w:
        w.write("tracker", T0 + 10, hatire.encode_pose(0, 1.0, 0.0, 0.0))
        w.write("tracker", T0 + 20, hatire.encode_pose(1, 2.0, 0.0, 0.0)[:12])  # torn
    looped = dump(capsys, str(log), "--as-fast-as-possible", "--loop", "--passes", "2")
    assert [(r["kind"], r.get("event")) for r in looped] == 2 * [("pose", None),
                                                                  ("status", "truncated")]
    assert looped[1]["details"] == {"bytes": 12} and looped[1]["t"] == 20 / 1e9


def test_dial_turns_follow_the_logged_or_given_counts_per_turn(tmp_path, capsys):
    log = tmp_path / "dials.hlog"
    settings = [ReaderSettings("loop://", "sgi", "dials", 9600)]
    header = LogHeader(log_devices(settings), start_monotonic_ns=T0,
                       extra=header_extra(settings, 50))
    with LogWriter(log, header) as w:
        w.write("dials", T0 + 10, sgi.encode_dial(2, 25) + sgi.encode_dial(2, -75))
    dials = dump(capsys, str(log), "--as-fast-as-possible")
    assert [(d["value"], d["turns"]) for d in dials] == [(25, 0.5), (-75, -1.5)]
    assert set(dials[0]) == {"t", "device", "kind", "index", "delta", "value", "turns"}
    given = dump(capsys, str(log), "--as-fast-as-possible", "--dial-counts-per-turn", "100")
    assert [d["turns"] for d in given] == [0.25, -0.75]
    with pytest.raises(SystemExit) as exc:
        cli_replay.main([str(log), "--dial-counts-per-turn", "0"])
    assert exc.value.code == 2


@posix_only
def test_replay_publishes_on_the_address_it_prints(tmp_path):
    log = tmp_path / "s.hlog"
    make_log(log)
    proc = subprocess.Popen([sys.executable, "-m", "drivers.commands.holo_replay", str(log),
                             "--loop",
                             "--pub", "tcp://127.0.0.1:0"],
                            cwd=ROOT, stderr=subprocess.PIPE, text=True)
    try:
        assert select.select([proc.stderr], [], [], 20)[0], "no output from holo-replay"
        line = proc.stderr.readline()
        assert line.startswith("holo-replay: publishing on tcp://127.0.0.1:"), line
        address = line.split()[-1]
        assert not address.endswith(":0")
        with DeviceSubscriber(address) as sub:
            got = sub.wait_pose(20.0)
            assert got is not None, "no pose from holo-replay"
            assert sub.wait_for(lambda s: s.pose_count >= 25, 20.0)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(20) == 143  # 128 + SIGTERM, after the clean stop
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
        proc.stderr.close()
    assert 0 <= got.seq < 20 and got.yaw == float(got.seq)  # the log's frames
    assert sub.stats.malformed == 0


def test_torn_log_replays_what_is_complete(tmp_path, capsys):
    log = tmp_path / "s.hlog"
    make_log(log)
    raw = log.read_bytes()
    log.write_bytes(raw[:-10])
    assert cli_replay.main([str(log), "--as-fast-as-possible", "--dump"]) == 0
    out = capsys.readouterr()
    assert len(out.out.splitlines()) == 20 and "1 torn" in out.err


def test_bad_inputs_exit_2(tmp_path, capsys):
    text = tmp_path / "notes.txt"
    text.write_text("hello")
    assert cli_replay.main([str(text), "--dump"]) == 2
    assert "--protocol" in capsys.readouterr().err
    assert cli_replay.main([str(tmp_path / "missing.hlog")]) == 2
    log = tmp_path / "s.hlog"
    make_log(log)
    assert cli_replay.main([str(log), "--to-port", "loop://", "--device", "nope"]) == 2


@posix_only
def test_to_port_writes_the_recorded_bytes_into_a_pty(tmp_path):
    log = tmp_path / "s.hlog"
    frames = make_log(log)
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    try:
        proc = subprocess.Popen([sys.executable, "-m", "drivers.commands.holo_replay", str(log),
                                 "--speed", "4", "--to-port", os.ttyname(slave)], cwd=ROOT)
        try:
            got = bytearray()
            deadline = time.monotonic() + 20
            while len(got) < sum(map(len, frames)) and time.monotonic() < deadline:
                if select.select([master], [], [], 0.05)[0]:
                    got += os.read(master, 4096)
            assert proc.wait(20) == 0
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(10)
    finally:
        os.close(master)
        os.close(slave)
    dec = make_decoder("hatire")
    poses = [e for e in dec.feed(bytes(got), 0) if isinstance(e, PoseEvent)]
    assert bytes(got) == b"".join(frames) and [p.seq for p in poses] == list(range(20))


@posix_only
def test_to_pty_waits_for_its_reader_before_closing(tmp_path):
    # closing a pty throws away what its client has not read: a replay that ends by
    # itself must wait for a reader that is behind (a loaded machine), as holo-sim does
    log = tmp_path / "s.hlog"
    sent = b"".join(make_log(log))
    proc = subprocess.Popen([sys.executable, "-m", "drivers.commands.holo_replay", str(log),
                             "--to-pty"],
                            cwd=ROOT, stderr=subprocess.PIPE, text=True)
    client = -1
    try:
        line = proc.stderr.readline()  # the first stderr line names the pty
        assert line.startswith("holo-replay: device on /dev/"), line
        client = os.open(line.split()[-1], os.O_RDONLY | os.O_NOCTTY)

        def waiting() -> int:  # bytes in the pty for us (poll first: it moves them in)
            select.select([client], [], [], 0)
            return struct.unpack("i", fcntl.ioctl(client, termios.FIONREAD, b"\0" * 4))[0]

        # the replay has written everything; nobody has read it: it must stay open
        wait_for(lambda: waiting() >= len(sent), HANG_S, "every frame in the pty")
        with pytest.raises(subprocess.TimeoutExpired):
            proc.wait(timeout=1.0)
        got = b""
        while len(got) < len(sent):
            got += os.read(client, 4096)
        assert got == sent
        assert proc.wait(HANG_S) == 0
    finally:
        if client >= 0:
            os.close(client)
        if proc.poll() is None:
            proc.kill()
            proc.wait(HANG_S)
        proc.stderr.close()


@posix_only
def test_to_pty_plays_a_live_device_for_a_reader(tmp_path):
    log = tmp_path / "s.hlog"
    make_log(log)
    proc = subprocess.Popen([sys.executable, "-m", "drivers.commands.holo_replay", str(log),
                             "--to-pty",
                             "--loop"], cwd=ROOT, stderr=subprocess.PIPE, text=True)
    seqs: list[int] = []
    reader = None
    try:
        assert select.select([proc.stderr], [], [], 20)[0], "no output from holo-replay"
        line = proc.stderr.readline()  # the first stderr line names the pty (one write)
        assert line.startswith("holo-replay: device on /dev/"), line
        settings = ReaderSettings(line.split()[-1], "hatire", poll_s=0.01)
        reader = DeviceReader(settings, lambda item, events: seqs.extend(
            e.seq for e in events if isinstance(e, PoseEvent))).start()
        deadline = time.monotonic() + 20
        while len(seqs) < 30:
            assert time.monotonic() < deadline and proc.poll() is None
            threading.Event().wait(0.01)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(20) == 143  # 128 + SIGTERM, after the clean stop
    finally:
        if reader is not None:
            reader.stop()
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
        proc.stderr.close()
    # the log's 20 frames in order, pass after pass (the first ones may predate the open)
    assert all(b == (a + 1) % 20 for a, b in zip(seqs, seqs[1:], strict=False))
    assert 0 in seqs[1:]
