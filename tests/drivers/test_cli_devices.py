"""holo-devices against simulated devices in subprocesses; live dump equals replay dump."""

from __future__ import annotations

import json
import os
import re
import select
import signal
import tty

import pytest
from drivers_fixtures import MISSING, hatire_capture
from testkit import posix_only

from drivers.commands import holo_devices as cli_devices
from drivers.pty_link import PtyLink
from drivers.recording import LogReader
from drivers.subscriber import DeviceSubscriber

FIXTURE = hatire_capture()
POSE_KEYS = {"t", "device", "kind", "yaw", "pitch", "roll", "x", "y", "z", "seq"}
KIND_KEYS = {"pose": POSE_KEYS,
             "dial": {"t", "device", "kind", "index", "delta", "value", "turns"},
             "button": {"t", "device", "kind", "index", "pressed"},
             "status": {"t", "device", "kind", "event", "details"}}


def kinds(lines: list[str]) -> list[str]:
    return [json.loads(line)["kind"] for line in lines]


@posix_only
def test_live_dump_equals_replay_dump_and_sigterm_closes_the_log(procs, tmp_path):
    # a faulty tracker that also drops off and comes back, and a dial box on a pty
    log = tmp_path / "session.hlog"
    # the tracker on TCP (socket:// URL; a reconnect cannot reach a recycled pty number)
    tracker = procs("sim_devices.commands.holo_sim", "tracker", "--tcp", "0", "--protocol",
                    "native",
                    "--rate", "200", "--faults",
                    "corrupt=0.03,burst=0.03,split,disconnect=0.01,reconnect_s=0.1,seed=5")
    dials = procs("sim_devices.commands.holo_sim", "dials", "--pty", "--seed", "3")
    tracker.wait_lines(lambda: tracker.out)
    dials.wait_lines(lambda: dials.out)
    live = procs("drivers.commands.holo_devices", "--tracker", tracker.out[0], "--tracker-protocol",
                 "native", "--dials", dials.out[0], "--record", str(log), "--dump",
                 "--pub", "tcp://127.0.0.1:0", "--reset-wait", "0.5")
    live.wait_lines(lambda: live.err)
    assert live.err[0].startswith("holo-devices: publishing on tcp://127.0.0.1:")
    address = live.err[0].split()[-1]
    with DeviceSubscriber(address) as sub:
        assert sub.wait_pose(10.0) is not None
        assert sub.wait_for(lambda s: s.state_known, 10.0)
    live.wait_lines(lambda: kinds(live.out).count("dial") >= 5
                    and kinds(live.out).count("pose") >= 100
                    and any('"event":"reconnect"' in line for line in live.out))
    live.p.send_signal(signal.SIGTERM)
    assert live.finish() == 143  # 128 + SIGTERM, after the clean stop
    stats = json.loads(live.err[-1])["stats"]
    assert stats["tracker"]["crc_errors"] > 0 and stats["dials"]["opens"] == 1
    assert stats["tracker"]["reconnects"] >= 1

    reader = LogReader(log, warn=False)
    assert len(list(reader)) > 0 and reader.stats.torn == 0 and reader.stats.corrupt == 0
    replay = procs("drivers.commands.holo_replay", str(log), "--as-fast-as-possible", "--dump")
    assert replay.finish(30) == 0
    assert replay.out == live.out  # line by line, same values and times

    records = [json.loads(line) for line in live.out]
    for rec in records:
        assert set(rec) >= KIND_KEYS[rec["kind"]] and rec["device"] in ("tracker", "dials")
    assert {r["kind"] for r in records} >= {"pose", "dial", "status"}
    events = {r["details"].get("message") for r in records if r["kind"] == "status"}
    assert {"opened", "init", "reset_ack", "closed"} <= events
    assert all(r["turns"] == r["value"] / 200 for r in records if r["kind"] == "dial")
    assert any(r["kind"] == "status" and r["event"] in ("crc_error", "resync")
               for r in records)


@posix_only
def test_clean_stop_reports_the_torn_last_frame_as_replay_does(procs, tmp_path):
    """The Hatire capture written into a pty: SIGTERM flushes the decoder (truncated)."""
    if not FIXTURE.is_file():
        pytest.skip(MISSING)
    capture = FIXTURE.read_bytes()
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        live = procs("drivers.commands.holo_devices", "--tracker", os.ttyname(slave), "--dump",
                     "--watchdog", "0", "--record", str(tmp_path / "s.hlog"))
        live.wait_lines(lambda: live.out)  # opened: from now on nothing written is lost
        view = memoryview(capture)
        while view:
            select.select([], [master], [], 1.0)
            view = view[os.write(master, view[:4096]):]
        live.wait_lines(lambda: kinds(live.out).count("pose") == 4765)
        live.p.send_signal(signal.SIGTERM)
        assert live.finish() == 143
    finally:
        os.close(master)
        os.close(slave)
    records = [json.loads(line) for line in live.out]
    assert records[-2]["event"] == "truncated" and records[-2]["details"] == {"bytes": 19}
    assert records[-1]["details"] == {"message": "closed"}
    stats = json.loads(live.err[-1])["stats"]["tracker"]
    assert (stats["frames"], stats["counter_gaps"], stats["truncated"]) == (4765, 2, 1)
    # what the replay of the raw capture reports, in the same order
    replay = procs("drivers.commands.holo_replay", str(FIXTURE), "--protocol", "hatire",
                   "--as-fast-as-possible", "--dump")
    assert replay.finish(60) == 0
    assert device_events(live.out) == device_events(replay.out)
    recorded = procs("drivers.commands.holo_replay", str(tmp_path / "s.hlog"),
                     "--as-fast-as-possible",
                     "--dump")
    assert recorded.finish(60) == 0 and recorded.out == live.out


def device_events(lines: list[str]) -> list[tuple]:
    """Decoder events without times, the readers' own statuses left out."""
    out = []
    for rec in map(json.loads, lines):
        if rec["kind"] == "status" and "message" in rec["details"]:
            continue
        out.append((rec["kind"], rec.get("seq"), rec.get("event"),
                    json.dumps(rec.get("details"), sort_keys=True)))
    return out


def test_seconds_limit_and_dump_of_a_quiet_loop_port(capsys):
    assert cli_devices.main(["--tracker", "loop://", "--dump", "--seconds", "0.2"]) == 0
    out = capsys.readouterr()
    first = json.loads(out.out.splitlines()[0])
    assert first["kind"] == "status" and first["details"]["message"] == "opened"
    assert json.loads(out.err.splitlines()[-1])["stats"]["tracker"]["opens"] == 1


def test_bad_settings_exit_2(tmp_path, capsys):
    existing = tmp_path / "x.hlog"
    existing.write_bytes(b"")
    assert cli_devices.main(["--tracker", "loop://", "--record", str(existing)]) == 2
    assert "holo-devices:" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        cli_devices.main(["--dump"])
    assert exc.value.code == 2


RETRY = re.compile(r"holo-devices: tracker \((?P<url>[^)]*)\): open failed \(try (?P<n>\d+)"
                   r"(?P<same>, same error)?\)(?P<msg>: .*)?; (?P<then>.*)$")


def retries(lines: list[str]) -> list[re.Match]:
    return [m for m in map(RETRY.match, lines) if m]


@posix_only
def test_a_missing_port_says_each_retry_with_its_back_off_until_it_appears(procs, tmp_path):
    path = str(tmp_path / "ttyUSB9")  # no such port yet
    live = procs("drivers.commands.holo_devices", "--tracker", path, "--dump")
    live.wait_lines(lambda: len(retries(live.err)) >= 4)
    first, *later = retries(live.err)[:4]
    assert first["url"] == path and first["n"] == "1" and "No such file" in first["msg"]
    assert first["then"] == "next try in 0.05 s"
    assert [m["n"] for m in later] == ["2", "3", "4"]
    assert all(m["same"] and not m["msg"] for m in later)  # the error is not repeated
    assert [m["then"] for m in later] == [f"next try in {w} s" for w in ("0.10", "0.20", "0.40")]
    assert not any("open_failed" in line for line in live.err)  # no second, raw report
    link = PtyLink(symlink=path)  # the device is plugged in: read, and no more retry lines
    try:
        live.wait_lines(lambda: any('"message":"opened"' in line for line in live.out))
        tries = len(retries(live.err))
        live.p.send_signal(signal.SIGINT)
        assert live.finish() == 130
    finally:
        link.close()
    assert len(retries(live.err)) == tries
    assert json.loads(live.err[-1])["stats"]["tracker"]["opens"] == 1


def test_no_retry_tries_each_port_once_and_exits_1(procs, tmp_path):
    path = str(tmp_path / "ttyUSB9")
    live = procs("drivers.commands.holo_devices", "--tracker", path, "--no-retry")
    assert live.finish() == 1
    (only,) = retries(live.err)
    assert only["n"] == "1" and only["then"] == "not retrying (--no-retry)"
    assert json.loads(live.err[-3])["stats"]["tracker"]["open_failures"] == 1
    assert live.err[-2].startswith(f"holo-devices: never opened tracker ({path}): ")
    assert live.err[-1] == "holo-devices: no device could be opened; nothing was read"
    # one device read, the other missing: still status 1, the run ends at once
    both = procs("drivers.commands.holo_devices", "--tracker", "loop://", "--dials", path,
                 "--no-retry")
    assert both.finish() == 1
    assert both.err[-1] == f"holo-devices: stopped: dials ({path}) did not open (--no-retry)"


@posix_only
def test_no_retry_ends_the_run_when_a_lost_device_does_not_reopen(procs, tmp_path):
    path = str(tmp_path / "tracker")
    link = PtyLink(symlink=path)
    live = procs("drivers.commands.holo_devices", "--tracker", path, "--dump", "--no-retry")
    try:
        live.wait_lines(lambda: any('"message":"opened"' in line for line in live.out))
    finally:
        link.close()  # unplugged: the port and its name are gone
    assert live.finish() == 1
    assert live.err[-1] == f"holo-devices: stopped: tracker ({path}) was lost and did not " \
        "reopen (--no-retry)"
