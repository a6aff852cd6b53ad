"""Device readers on real ports: loop://, pty pairs; faults, reconnects, the dial box."""

from __future__ import annotations

import os
import threading
import time

import pytest
from reader_helpers import Collector
from testkit import posix_only, wait_for

from drivers.dialbox_driver import DialBoxDriver
from drivers.events import ButtonEvent, DialEvent, PoseEvent
from drivers.protocols import hatire
from drivers.protocols import sgi_dialbox as sgi
from drivers.pty_link import PtyLink
from drivers.reader import (
    Chunk,
    Control,
    DeviceReader,
    DeviceStream,
    EventHub,
    ReaderSettings,
)
from service.base.errors import LogFileError, SettingsError
from sim_devices.dialbox import DialBoxSim, Press, Turn
from sim_devices.endpoints import DeviceRunner, LoopLink
from sim_devices.faults import FaultSpec
from sim_devices.motion import make_motion
from sim_devices.tracker import TrackerSim


def send_until_seen(link, sink: Collector, seq: int, timeout: float = 5.0) -> None:
    """Write a pose until the reader has it (a reopen in between flushes the input)."""
    deadline = time.monotonic() + timeout
    tick = threading.Event()
    while seq not in sink.seqs():
        assert time.monotonic() < deadline, f"pose {seq} never arrived"
        link.write(hatire.encode_pose(seq, 0, 0, 0))
        tick.wait(0.02)


def loop_reader(link: LoopLink, protocol: str, sink: Collector | None = None,
                **kw) -> DeviceReader:
    """A reader (not started yet) of ``link``'s loop:// port, polling every 10 ms."""
    return DeviceReader(ReaderSettings("loop://", protocol, poll_s=0.01),
                        Collector() if sink is None else sink,
                        opener=lambda url, **_: link.port, **kw)


@pytest.mark.parametrize("protocol", ["native", "hatire"])
def test_every_intact_frame_recovered_through_a_loop_reader(protocol):
    link = LoopLink()
    spec = FaultSpec(truncate=0.05, drop=0.05, burst=0.05, split=True, max_split=9, seed=21)
    runner = DeviceRunner(TrackerSim(protocol, make_motion("walk", seed=2), rate_hz=100),
                          link, spec, seconds=3.0, realtime=False, pace=False)
    sink = Collector()
    reader = loop_reader(link, protocol, sink)
    reader.start()
    try:
        runner.run()
        wait_for(lambda: reader.stream.decoder.stats.bytes_in == runner.bytes_sent,
                 what="all bytes read")
    finally:
        reader.stop()
    led = runner.ledger
    assert led.frames == 300 and led.counts["truncate"] and led.counts["burst"]
    assert sink.seqs() == led.intact  # every intact frame, none invented
    stats = reader.stats()
    assert stats["frames"] == len(led.intact)
    assert stats["resyncs"] == len(sink.status("resync")) > 0
    assert stats["bytes_discarded"] > led.burst_bytes
    assert stats["chunks"] == sum(isinstance(i, Chunk) for i in sink.items)
    assert b"".join(i.data for i in sink.items if isinstance(i, Chunk)) != b""
    assert stats["opens"] == 1 and stats["disconnects"] == 0 and not stats["connected"]


@posix_only
def test_every_intact_frame_recovered_through_a_pty_reader():
    link = PtyLink()
    spec = FaultSpec(corrupt=0.05, wrong_baud=0.03, burst=0.05, split=True, seed=22)
    runner = DeviceRunner(TrackerSim("native", make_motion("walk", seed=3), rate_hz=100),
                          link, spec, seconds=2.0, realtime=False, pace=False)
    sink = Collector()
    reader = DeviceReader(ReaderSettings(link.path, "native", poll_s=0.01), sink).start()
    try:
        wait_for(lambda: reader.connected)
        runner.run()
        wait_for(lambda: reader.stream.decoder.stats.bytes_in == runner.bytes_sent,
                 what=f"all bytes read ({runner.bytes_sent} sent; {reader.stats()}, "
                 f"crashed={reader.crashed!r}, errors={sink.status('error')})")
    finally:
        reader.stop()
        link.close()
    assert sink.seqs() == runner.ledger.intact and runner.ledger.counts["corrupt"]
    assert reader.stats()["crc_errors"] == len(sink.status("crc_error")) > 0


def test_receive_times_are_monotonic_clock_at_arrival():
    link = LoopLink()
    sink = Collector()
    reader = loop_reader(link, "hatire", sink).start()
    try:
        wait_for(lambda: reader.connected)
        before = time.monotonic_ns()
        link.write(hatire.encode_pose(0, 1.0, 2.0, 3.0))
        wait_for(lambda: len(sink.seqs()) == 1)
        after = time.monotonic_ns()
    finally:
        reader.stop()
    pose = [e for e in sink.snapshot() if isinstance(e, PoseEvent)][0]
    assert before <= pose.t_ns <= after
    assert (pose.yaw, pose.pitch, pose.roll) == (1.0, 2.0, 3.0)


class UnlinkingPtyLink(PtyLink):
    """A pty link whose symlink disappears while the device is unplugged.

    With the plain link the symlink keeps naming the closed /dev/pts/N during the
    outage, and a reader retrying it could open whatever pty another process gets
    with that recycled number.
    """

    def disconnect(self) -> None:
        if self.symlink and os.path.lexists(self.symlink):
            os.unlink(self.symlink)
        super().disconnect()


@posix_only
def test_pty_closed_and_reopened_resumes_without_restart(tmp_path):
    link = UnlinkingPtyLink(symlink=str(tmp_path / "tracker"))
    spec = FaultSpec(disconnect=0.03, reconnect_s=0.05, seed=2)
    runner = DeviceRunner(TrackerSim("hatire", rate_hz=400), link, spec, seconds=0.6,
                          realtime=True, pace=False)
    sink = Collector()
    settings = ReaderSettings(link.path, "hatire", poll_s=0.01, backoff_s=0.005,
                              backoff_max_s=0.02)
    reader = DeviceReader(settings, sink).start()
    try:
        wait_for(lambda: reader.connected)
        runner.start()
        wait_for(runner.done.is_set, what="simulator run")
        # frames sent while the port was closed are gone (opening flushes the input);
        # a frame written now must arrive through the reopened port
        drops = runner.ledger.counts["disconnect"]
        wait_for(lambda: reader.connected and reader.counters.reconnects >= 1)
        send_until_seen(link, sink, 999)
    finally:
        runner.stop()
        reader.stop()
        link.close()
    assert drops >= 2
    stats = reader.stats()
    assert 1 <= stats["reconnects"] <= drops and stats["disconnects"] == stats["reconnects"]
    assert len(sink.status("reconnect")) == stats["reconnects"]
    lost = [e for e in sink.status("error") if e.details["reason"] == "disconnected"]
    assert len(lost) == stats["disconnects"]
    assert all(e.details["decoder_reset"] for e in sink.status("reconnect"))
    # Frames are lost only across an outage: those sent while the port was closed
    # or not yet reopened (opening flushes the input).  How many depends on how soon
    # the reader reopens (later on a loaded machine), so count the gaps, not frames:
    # every gap in the frames received is an outage, none is a frame lost while the
    # port was open.
    seqs = [s for s in sink.seqs() if s != 999]
    assert len(seqs) == len(set(seqs)) and seqs == sorted(seqs)
    assert set(seqs) <= set(runner.ledger.intact)
    gaps = sum(b - a > 1 for a, b in zip(seqs, seqs[1:], strict=False))
    first_gap = seqs[0] > 0
    assert gaps + first_gap <= drops, (gaps, first_gap, drops)


@posix_only
def test_watchdog_reopens_a_silent_port_and_waits_for_a_missing_one(tmp_path):
    path = str(tmp_path / "later")
    sink = Collector()
    settings = ReaderSettings(path, "hatire", poll_s=0.01, watchdog_s=0.15, backoff_s=0.01,
                              backoff_max_s=0.04)
    reader = DeviceReader(settings, sink).start()
    link = None
    try:
        wait_for(lambda: reader.counters.open_failures >= 3, what="open retries")
        assert len(sink.status("error")) == 1  # one report per outage, not per attempt
        assert sink.status("error")[0].details["reason"] == "open_failed"
        link = PtyLink(symlink=path)  # the device appears
        wait_for(lambda: reader.connected, what="first open")
        send_until_seen(link, sink, 1)
        wait_for(lambda: reader.counters.watchdog_trips >= 1, what="watchdog")
        wait_for(lambda: reader.counters.opens >= 2 and reader.connected, what="reopen")
        send_until_seen(link, sink, 2)
    finally:
        reader.stop()
        if link is not None:
            link.close()
    opened = [e for e in sink.status("info") if e.details.get("message") == "opened"]
    assert len(opened) == 1 and opened[0].details["attempts"] >= 4
    trips = [e for e in sink.status("error") if e.details["reason"] == "watchdog"]
    assert len(trips) == reader.counters.watchdog_trips


def test_reader_thread_is_joined_and_port_closed_on_stop():
    link = LoopLink()
    reader = loop_reader(link, "native").start()
    wait_for(lambda: reader.connected)
    start = time.monotonic()
    reader.stop()
    assert time.monotonic() - start < 1.0
    assert not reader._thread.is_alive() and not link.port.is_open
    assert not reader.write(b"x") and reader.counters.write_errors == 1


@posix_only
def test_dial_box_handshake_events_reinit_and_lamps():
    # the last step keeps the runner (which answers host commands) playing until the
    # test stops it: one due after 0.5 s of streaming could end it before the re-init
    # and the lamp command reach the box on a loaded machine
    script = [Turn(0.0, 2, 40, steps=4, span_s=0.01), Press(0.02, 31, hold_s=0.01),
              Turn(0.05, 7, -70000, steps=7, span_s=0.01), Turn(3600.0, 0, 5, steps=1)]
    box = DialBoxSim(script)
    link = PtyLink()
    runner = DeviceRunner(box, link, realtime=True, pace=True).start()
    driver = DialBoxDriver(reset_wait_s=1.0, lamps=0b101)
    sink = Collector()
    reader = DeviceReader(ReaderSettings(link.path, "sgi", baudrate=9600, poll_s=0.01,
                                         watchdog_s=None), sink, hooks=driver).start()
    try:
        wait_for(lambda: driver.inits == 1, what="handshake")
        wait_for(lambda: box.lamps == 0b101, what="initial lamps")  # sent last
        assert box.resets == 2 and box.dial_mask == 0xFF and box.auto_mask == 0xFFFFFFFF
        wait_for(lambda: any(isinstance(e, DialEvent) and e.index == 7 and e.value == -70000
                             for e in sink.snapshot()), what="dial 7 report")
        link.write(b"\x00" * 16)  # garbage: the decoder asks for a re-init
        wait_for(lambda: driver.inits == 2, what="re-init")
        wait_for(lambda: box.resets == 4, what="box saw the second handshake")
        assert driver.set_lamp(1, True) and driver.lamps == 0b111
        wait_for(lambda: box.lamps == 0b111, what="lamp 1")
    finally:
        runner.stop()
        reader.stop()
        link.close()
    events = sink.snapshot()
    dials = [e for e in events if isinstance(e, DialEvent)]
    assert [e.value for e in dials if e.index == 2] == [10, 20, 30, 40]
    assert [(e.index, e.pressed) for e in events if isinstance(e, ButtonEvent)] == [
        (31, True), (31, False)]
    inits = [e for e in sink.status("info") if e.details.get("message") == "init"]
    assert [e.details["reset_ack"] for e in inits] == [True, True]
    reinit = [e for e in sink.status("info") if e.details.get("message") == "reinit"]
    assert len(reinit) == 1 and reinit[0].details["decoder_reset"]


def test_stream_applies_control_items_like_the_live_reader():
    stream = DeviceStream("tracker", "hatire")
    frame = hatire.encode_pose(5, 1, 2, 3)
    assert stream.process(Chunk("tracker", 10, frame[:20])) == []
    events = stream.process(Control("tracker", 20, "error", {"reason": "x"}, flush=True,
                                    reset=True))
    assert [e.event for e in events] == ["truncated", "error"]
    assert events[1].details == {"reason": "x", "decoder_reset": True}
    ctl = Control("dials", 7, "info", {"message": "init"}, reset=False)
    assert Control.from_bytes("dials", 7, ctl.to_bytes()) == ctl
    with pytest.raises(LogFileError):
        Control.from_bytes("dials", 7, b"{not json")
    assert DeviceStream("d", "sgi_dialbox").protocol == "sgi"
    with pytest.raises(SettingsError):
        ReaderSettings("loop://", "morse")


def test_hub_dispatches_in_order_and_times_out():
    hub = EventHub()
    seen: list = []
    assert hub.dispatch([lambda i, e: seen.append(i)], timeout_s=0.01) == 0
    for k in range(5):
        hub.put(Chunk("tracker", k, bytes([k])), [])
    assert hub.dispatch([lambda i, e: seen.append(i.t_ns)], timeout_s=0.01) == 5
    assert seen == [0, 1, 2, 3, 4] and hub.empty()


def test_sgi_init_sequence_order_is_what_the_driver_sends():
    # reset twice, wait, dials before buttons, button commands twice (VRPN)
    steps = sgi.init_sequence(0.5)
    assert [s.data[0] for s in steps] == [0x20, 0x20, 0x50, 0x71, 0x71]
    assert steps[1].wait_s == 0.5 and os.name  # the driver waits on step 2


def test_an_unexpected_exception_is_reported_and_ends_the_thread():
    class Broken:
        def on_open(self, reader):
            pass

        def on_events(self, reader, events):
            raise RuntimeError("bug")

    link = LoopLink()
    sink = Collector()
    reader = loop_reader(link, "hatire", sink, hooks=Broken()).start()
    try:
        link.write(hatire.encode_pose(0, 0, 0, 0))
        wait_for(lambda: reader.crashed is not None, what="crash report")
        reader._thread.join(2.0)
        assert not reader._thread.is_alive() and not reader.connected
    finally:
        reader.stop()
    crash = [e for e in sink.status("error") if e.details["reason"] == "reader_crashed"]
    assert len(crash) == 1 and "bug" in crash[0].details["message"]


@posix_only
def test_a_pty_is_read_through_its_descriptor_and_a_frame_may_span_two_reads():
    link = PtyLink()
    sink = Collector()
    reader = DeviceReader(ReaderSettings(link.path, "hatire", poll_s=0.01), sink).start()
    frame = hatire.encode_pose(5, 1.0, 2.0, 3.0)
    try:
        wait_for(lambda: reader.connected)
        assert reader._fd is not None  # select + os.read, not pyserial's read(1)
        link.write(frame[:7])
        wait_for(lambda: reader.counters.chunks == 1, what="first half read")
        assert sink.seqs() == []
        before = time.monotonic_ns()
        link.write(frame[7:])
        wait_for(lambda: sink.seqs() == [5], what="pose from the second half")
    finally:
        reader.stop()
        link.close()
    assert reader._fd is None and not reader.connected
    pose = [e for e in sink.snapshot() if isinstance(e, PoseEvent)][0]
    assert pose.t_ns >= before  # stamped when the bytes that completed it came
    assert b"".join(i.data for i in sink.items if isinstance(i, Chunk)) == frame


def test_a_loop_port_has_no_descriptor_and_is_read_through_pyserial():
    link = LoopLink()
    sink = Collector()
    reader = loop_reader(link, "hatire", sink).start()
    try:
        wait_for(lambda: reader.connected)
        assert reader._fd is None
        link.write(hatire.encode_pose(3, 0.0, 0.0, 0.0))
        wait_for(lambda: sink.seqs() == [3])
    finally:
        reader.stop()
