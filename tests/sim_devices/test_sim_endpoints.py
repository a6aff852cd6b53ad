"""Simulated devices through real links: loop://, pty pairs and TCP on 127.0.0.1."""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Callable

import pytest
import serial
from testkit import wait_for

from drivers.events import ButtonEvent, DialEvent, PoseEvent, StatusEvent
from drivers.protocols import make_decoder
from drivers.protocols import native as nat
from drivers.protocols import sgi_dialbox as sgi
from drivers.pty_link import PtyLink
from service.base.errors import DeviceError
from sim_devices.dialbox import DialBoxSim, Press, Turn
from sim_devices.endpoints import DeviceRunner, LoopLink, TcpLink
from sim_devices.faults import FaultSpec
from sim_devices.motion import make_motion
from sim_devices.tracker import TrackerSim

posix_only = pytest.mark.skipif(sys.platform == "win32", reason="pty pairs need POSIX")


def read_until(port, dec, done: Callable[[list], bool], timeout: float = 5.0,
               reopen: Callable[[], object] | None = None) -> tuple[list, int]:
    """Read and decode until ``done(events)``; reopen the port on errors if allowed."""
    events: list = []
    reopened = 0
    deadline = time.monotonic() + timeout
    while not done(events):
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out with {len(events)} events")
        try:
            # read only what is waiting: pyserial drops the bytes a read() already
            # collected when the port fails mid-call (socket closed, pty hung up)
            events += dec.feed(port.read(max(1, port.in_waiting)), time.monotonic_ns())
        except OSError:  # SerialException, or EIO from in_waiting's ioctl on a hung-up pty
            if reopen is None:
                raise
            port.close()
            port = reopen()
            reopened += 1
            dec.reset()
    port.close()
    return events, reopened


def seqs(events) -> list[int]:
    return [e.seq for e in events if isinstance(e, PoseEvent)]


def test_loop_link_with_faults_recovers_every_intact_frame():
    link = LoopLink()
    sim = TrackerSim("native", make_motion("sway"), rate_hz=100)
    runner = DeviceRunner(sim, link, FaultSpec(corrupt=0.05, burst=0.05, split=True, seed=4),
                          seconds=1.0, realtime=False, pace=False).start()
    dec = make_decoder("native")
    events, _ = read_until(link.port, dec,
                           lambda ev: runner.done.is_set() and link.port.in_waiting == 0
                           and dec.stats.bytes_in == runner.bytes_sent)
    assert seqs(events) == runner.ledger.intact
    assert runner.ledger.frames == 100 and runner.ledger.counts["corrupt"] > 0


class WaitLog(threading.Event):
    """A runner's stop event that notes every wait the runner makes (its pauses)."""

    def __init__(self) -> None:
        super().__init__()
        self.waits: list[float | None] = []

    def wait(self, timeout: float | None = None) -> bool:
        self.waits.append(timeout)
        return super().wait(timeout)


def test_runner_paces_writes_to_the_baud_rate():
    link = LoopLink()
    sim = TrackerSim("hatire", rate_hz=1000)
    # 30 bytes per frame, 10 bits each at 30000 baud -> 10 ms per frame
    sim_runner = DeviceRunner(sim, link, seconds=0.02, realtime=False, pace=True, baud=30_000)
    sim_runner.stop_event = paced = WaitLog()
    start = time.monotonic()
    sim_runner.run()
    elapsed = time.monotonic() - start
    assert sim_runner.ledger.frames == 20
    assert elapsed >= 20 * 0.01 * 0.9
    assert sum(paced.waits) == pytest.approx(10 * sim_runner.bytes_sent / 30_000)
    # unpaced: no pause at all (what it asks for, not how fast a loaded machine runs it)
    unpaced = DeviceRunner(TrackerSim("hatire", rate_hz=1000), LoopLink(), seconds=0.02,
                           realtime=False, pace=False)
    unpaced.stop_event = idle = WaitLog()
    unpaced.run()
    assert unpaced.ledger.frames == 20 and unpaced.bytes_sent == sim_runner.bytes_sent
    assert idle.waits == []
    link.close()


@posix_only
def test_pty_tracker_answers_host_commands():
    link = PtyLink()
    sim = TrackerSim("native", rate_hz=200, autostart=False)
    runner = DeviceRunner(sim, link, seconds=0.5, realtime=True, pace=True).start()
    try:
        port = serial.serial_for_url(link.path, timeout=0.02)
        port.write(nat.encode_command("reset") + nat.encode_command("start"))
        dec = make_decoder("native")
        events, _ = read_until(port, dec, lambda ev: len(seqs(ev)) >= 20)
        texts = [e.details["text"] for e in events if isinstance(e, StatusEvent)]
        assert texts[:2] == ["init", "start"]
        assert seqs(events)[:20] == list(range(20))
    finally:
        runner.stop()
        link.close()


@posix_only
def test_pty_disconnect_and_reconnect_through_symlink(tmp_path):
    link = PtyLink(symlink=str(tmp_path / "tracker"))
    sim = TrackerSim("hatire", rate_hz=400)
    spec = FaultSpec(disconnect=0.04, reconnect_s=0.05, seed=2)
    runner = DeviceRunner(sim, link, spec, seconds=0.4, realtime=True, pace=False)
    state = {"inode": os.lstat(link.path).st_ino}

    def inode(path):
        try:
            return os.lstat(path).st_ino
        except FileNotFoundError:  # the device is away: the link is removed meanwhile
            return None

    def reopen():
        # the device removes its link before it vanishes, so a link that exists
        # after the client saw the port fail is the new device
        wait_for(lambda: inode(link.path) is not None)
        state["inode"] = os.lstat(link.path).st_ino
        return serial.serial_for_url(link.path, timeout=0.02)

    port = serial.serial_for_url(link.path, timeout=0.02)
    runner.start()
    try:
        events, reopened = read_until(port, make_decoder("hatire"),
                                      lambda ev: 159 in seqs(ev), reopen=reopen)
    finally:
        runner.stop()
        link.close()
    assert runner.ledger.counts["disconnect"] >= 2
    # one reopen per disconnect the client noticed (two quick drops can look like one)
    assert 1 <= reopened <= runner.ledger.counts["disconnect"]
    assert seqs(events)[-1] == 159


def test_tcp_start_stop_and_reconnect():
    link = TcpLink(0)
    sim = TrackerSim("hatire", rate_hz=500, autostart=False)
    spec = FaultSpec(disconnect=0.02, reconnect_s=0.02, seed=5)
    runner = DeviceRunner(sim, link, spec, seconds=0.5, realtime=True, pace=True).start()

    def reopen():
        # a device plugged back in waits for the start command again, as at power-on
        port = serial.serial_for_url(link.name, timeout=0.02)
        port.write(b"S")
        return port

    try:
        port = reopen()
        events, reopened = read_until(port, make_decoder("hatire"),
                                      lambda ev: 249 in seqs(ev), reopen=reopen)
        assert reopened == runner.ledger.counts["disconnect"] >= 2
        assert seqs(events) == list(range(250))  # TCP delivers what was sent before a close
        assert events[0].details["meaning"] == "start"
        assert sim.received["start"] == reopened + 1
    finally:
        runner.stop()
        link.close()


def test_tcp_listens_on_loopback_only_and_reports_busy_port():
    link = TcpLink(0)
    try:
        assert link.name.startswith("socket://127.0.0.1:")
        with pytest.raises(DeviceError):
            TcpLink(link.port)
    finally:
        link.close()


@posix_only
def test_dial_box_handshake_script_and_lamps_over_pty():
    script = [Turn(0.0, 2, 40, steps=4, span_s=0.01), Press(0.02, 31, hold_s=0.01),
              Turn(0.05, 7, -70000, steps=7, span_s=0.01)]
    box = DialBoxSim(script)
    link = PtyLink()
    runner = DeviceRunner(box, link, seconds=1.0, realtime=True, pace=True).start()
    try:
        port = serial.serial_for_url(link.path, baudrate=9600, timeout=0.02)
        dec = make_decoder("sgi")
        port.write(b"".join(s.data for s in sgi.init_sequence()[:2]))
        acks, _ = read_until(port, dec, lambda ev: len(ev) >= 2)
        assert [e.details["message"] for e in acks] == ["reset_ack", "reset_ack"]
        port = serial.serial_for_url(link.path, baudrate=9600, timeout=0.02)
        port.write(b"".join(s.data for s in sgi.init_sequence()[2:]) + sgi.encode_lamps(0b101))
        events, _ = read_until(port, dec, lambda ev: len(ev) >= 13)
        wait_for(lambda: box.lamps == 0b101)
        assert box.lamp(0) and not box.lamp(1) and box.lamp(2)
    finally:
        runner.stop()
        link.close()
    dials = [e for e in events if isinstance(e, DialEvent)]
    assert [e.value for e in dials if e.index == 2] == [10, 20, 30, 40]
    assert [e.value for e in dials if e.index == 7][-1] == -70000  # unwrapped past 16 bits
    assert [(e.index, e.pressed) for e in events if isinstance(e, ButtonEvent)] == [
        (31, True), (31, False)]
    assert box.resets == 2
