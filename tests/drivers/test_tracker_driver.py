"""The tracker's start / stop / reset commands: sent on every open and on a clean stop."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from reader_helpers import Collector
from testkit import posix_only, wait_for

from drivers.commands import holo_devices as cli_devices
from drivers.events import PoseEvent, StatusEvent
from drivers.protocols import native
from drivers.protocols.hatire import HatireCommands
from drivers.pty_link import PtyLink
from drivers.reader import DeviceReader, ReaderSettings
from drivers.tracker_driver import TrackerDriver, command_byte
from service.base.errors import SettingsError
from sim_devices.endpoints import DeviceRunner
from sim_devices.faults import FaultSpec
from sim_devices.tracker import TrackerSim

ROOT = Path(__file__).resolve().parents[2]
def is_reconnect(e: StatusEvent) -> bool:
    return e.event == "reconnect"


def is_watchdog(e: StatusEvent) -> bool:
    return e.event == "error" and e.details.get("reason") == "watchdog"


def test_command_bytes_and_their_parsing():
    assert TrackerDriver("hatire").command("start") == b"S"
    custom = TrackerDriver("hatire", HatireCommands(b"G", b"H", b"J"))
    assert [custom.command(n) for n in ("start", "stop", "reset")] == [b"G", b"H", b"J"]
    assert TrackerDriver("native").command("stop") == native.encode_command("stop")
    assert command_byte("G") == b"G" and command_byte("0x47") == b"G"
    for bad in ("", "GH", "0x4", "0xZZ"):
        with pytest.raises(SettingsError):
            command_byte(bad)
    with pytest.raises(SettingsError):
        TrackerDriver("sgi")
    with pytest.raises(SystemExit) as exc:
        cli_devices.build_parser().parse_args(["--tracker", "x", "--hatire-start", "GH"])
    assert exc.value.code == 2


@posix_only
def test_start_is_sent_again_after_the_device_is_unplugged_and_plugged_back(tmp_path):
    # a device that waits for its start character, and waits again after each unplug
    cmds = HatireCommands(start=b"G", stop=b"H", reset=b"J")
    sim = TrackerSim("hatire", rate_hz=200, commands=cmds, autostart=False)
    link = PtyLink(symlink=str(tmp_path / "tracker"))
    runner = DeviceRunner(sim, link, FaultSpec(disconnect=0.01, reconnect_s=0.05, seed=4),
                          realtime=True, pace=False)
    driver = TrackerDriver("hatire", cmds)
    sink = Collector()
    settings = ReaderSettings(link.path, "hatire", poll_s=0.01, backoff_s=0.005,
                              backoff_max_s=0.02)
    reader = DeviceReader(settings, sink, hooks=driver).start()
    try:
        wait_for(lambda: reader.connected, what="first open")
        runner.start()
        wait_for(lambda: len(sink.poses_after(is_reconnect)) >= 20,
                 what="poses after a reconnect")
    finally:
        runner.stop()
        reader.stop()
        link.close()
    assert runner.ledger.counts["disconnect"] >= 1 and reader.counters.reconnects >= 1
    assert driver.sent["start"] == reader.counters.opens >= 2
    assert sim.received["start"] >= 2  # the device heard the start again after the unplug
    seqs = [e.seq for e in sink.snapshot() if isinstance(e, PoseEvent)]
    assert seqs == sorted(seqs)


@posix_only
@pytest.mark.parametrize("protocol, reset_on_open", [("hatire", False), ("native", True)])
def test_start_after_a_watchdog_reopen_and_stop_on_a_clean_stop(protocol, reset_on_open):
    sim = TrackerSim(protocol, rate_hz=200, autostart=False)
    link = PtyLink()
    runner = DeviceRunner(sim, link, realtime=True, pace=False)
    driver = TrackerDriver(protocol, reset_on_open=reset_on_open)
    sink = Collector()
    settings = ReaderSettings(link.path, protocol, poll_s=0.01, watchdog_s=0.3,
                              backoff_s=0.01, backoff_max_s=0.02)
    reader = DeviceReader(settings, sink, hooks=driver).start()
    try:
        wait_for(lambda: reader.connected, what="first open")
        runner.start()
        wait_for(lambda: len(sink.poses_after(lambda e: True)) >= 10, what="first poses")
        sim.power_cycle()  # the device falls silent until it hears a start again
        wait_for(lambda: len(sink.poses_after(is_watchdog)) >= 10,
                 what="poses after the watchdog reopen")
        reader.stop()
        wait_for(lambda: sim.received["stop"] == 1 and not sim.streaming,
                 what="the stop command heard")
    finally:
        runner.stop()
        reader.stop()
        link.close()
    assert reader.counters.watchdog_trips >= 1 and reader.counters.opens >= 2
    assert driver.sent["start"] == sim.received["start"] == reader.counters.opens
    assert driver.sent["reset"] == sim.received["reset"] == (
        reader.counters.opens if reset_on_open else 0)
    if reset_on_open:  # the counter restarts at each open
        assert [p.seq for p in sink.poses_after(is_watchdog)][:3] == [0, 1, 2]
    last = sink.snapshot()[-1]
    assert last.event == "info" and last.details == {"message": "closed"}


@posix_only
def test_holo_devices_starts_a_tracker_that_waits_for_its_start_character(tmp_path):
    """The audit's case: holo-sim --wait-start read by holo-devices (big-endian, own chars)."""
    sim = subprocess.Popen(
        [sys.executable, "-m", "sim_devices.commands.holo_sim", "tracker", "--pty", "--wait-start",
         "--rate", "100", "--byte-order", "big", "--hatire-start", "G", "--hatire-stop", "H"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    log = tmp_path / "s.hlog"
    try:
        path = sim.stdout.readline().strip()
        assert path.startswith("/dev/"), sim.stderr.read()
        live = subprocess.run(
            [sys.executable, "-m", "drivers.commands.holo_devices", "--tracker", path, "--dump",
             "--seconds", "1.5", "--hatire-start", "G", "--hatire-stop", "0x48",
             "--hatire-big-endian", "--record", str(log)],
            cwd=ROOT, capture_output=True, text=True, timeout=60)
        sim.send_signal(signal.SIGTERM)
        out, err = sim.communicate(timeout=20)
    finally:
        if sim.poll() is None:
            sim.kill()
            sim.wait(10)
    assert live.returncode == 0, live.stderr
    records = [json.loads(line) for line in live.stdout.splitlines()]
    poses = [r for r in records if r["kind"] == "pose"]
    assert len(poses) >= 30  # ~1.5 s at 100 Hz; none at all without the start character
    assert [p["seq"] for p in poses] == list(range(len(poses)))  # big-endian honoured
    assert all(abs(p["yaw"]) < 90 for p in poses)
    assert not any(r.get("event") in ("counter_gap", "error") for r in records)
    assert records[-1]["details"] == {"message": "closed"}
    stats = json.loads(live.stderr.splitlines()[-1])["stats"]["tracker"]
    assert stats["watchdog_trips"] == 0 and stats["opens"] == 1
    assert json.loads(out.splitlines()[-1])["commands"] == {"start": 1, "stop": 1, "reset": 0}
    # the log header keeps the byte order: the replay prints the same lines
    replay = subprocess.run([sys.executable, "-m", "drivers.commands.holo_replay", str(log),
                             "--as-fast-as-possible", "--dump"],
                            cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert replay.returncode == 0, replay.stderr
    assert replay.stdout == live.stdout
