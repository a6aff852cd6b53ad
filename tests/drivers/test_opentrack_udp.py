"""opentrack-udp:// trackers over real UDP on 127.0.0.1: reader, holo-devices, holo-sim, replay."""

from __future__ import annotations

import json
import signal
import socket

import pytest
from reader_helpers import Collector
from testkit import HANG_S, posix_only, wait_for

from drivers.commands import holo_devices as cli_devices
from drivers.events import PoseEvent
from drivers.protocols.opentrack import encode_pose
from drivers.reader import Chunk, DeviceReader, ReaderSettings
from drivers.udp_port import UdpPort


def free_udp_port() -> int:
    """A UDP port nobody has bound right now (racy, as testkit.free_port)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def sender():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        yield s


def listen(port: int, sink, watchdog_s: float | None = 2.0) -> DeviceReader:
    url = f"opentrack-udp://127.0.0.1:{port}"
    return DeviceReader(ReaderSettings(url, "opentrack", watchdog_s=watchdog_s,
                                       backoff_s=0.02, backoff_max_s=0.1), sink)


def opened(c: Collector) -> bool:
    return any(e.details.get("message") == "opened" for e in c.status("info"))


def test_the_reader_takes_one_chunk_per_datagram(sender):
    port, c = free_udp_port(), Collector()
    with listen(port, c) as reader:
        wait_for(lambda: opened(c), HANG_S, "the listener opened")
        sent = [encode_pose(k, 0, 0, 0, 0, 0) for k in range(40)]
        sent[10], sent[20] = sent[10][:30], sent[20] + b"\0"  # two of the wrong size
        for data in sent:  # back to back: queued datagrams must not run together
            sender.sendto(data, ("127.0.0.1", port))
        wait_for(lambda: reader.stats()["chunks"] == 40, HANG_S, "40 datagrams read")
    chunks = [i.data for i in c.items if isinstance(i, Chunk)]
    assert chunks == sent
    poses = [e for e in c.snapshot() if isinstance(e, PoseEvent)]
    assert [p.x for p in poses] == [float(k) for k in range(40) if k not in (10, 20)]
    st = reader.stats()
    assert (st["frames"], st["bad_size"], st["bytes_discarded"]) == (38, 2, 30 + 49)
    assert [e.details["reason"] for e in c.status("error")] == ["wrong_size", "wrong_size"]


def test_a_sender_that_stops_is_reported_like_a_quiet_serial_device(sender):
    port, c = free_udp_port(), Collector()
    with listen(port, c, watchdog_s=0.3):
        wait_for(lambda: opened(c), HANG_S, "the listener opened")
        sender.sendto(encode_pose(1, 0, 0, 0, 0, 0), ("127.0.0.1", port))
        wait_for(lambda: c.seqs(), HANG_S, "a pose")
        # the sender stops: the watchdog says so, rebinds the port, and poses resume
        wait_for(lambda: c.status("reconnect"), HANG_S, "the watchdog's reopen")
        (quiet,) = [e for e in c.status("error") if e.details["reason"] == "watchdog"][:1]
        assert quiet.details["decoder_reset"] and "no valid frame" in quiet.details["message"]

        def resumed() -> list:
            sender.sendto(encode_pose(2, 0, 0, 0, 0, 0), ("127.0.0.1", port))
            return c.poses_after(lambda e: e.event == "reconnect")

        wait_for(resumed, HANG_S, "poses after the reopen")


def test_a_port_in_use_is_an_open_failure_retried_until_free(sender):
    blocker = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    blocker.bind(("127.0.0.1", 0))
    port, c = blocker.getsockname()[1], Collector()
    with listen(port, c):
        wait_for(lambda: c.status("error"), HANG_S, "the open failure")
        (failed,) = c.status("error")
        assert failed.details["reason"] == "open_failed"
        assert f"UDP 127.0.0.1:{port}" in failed.details["message"]
        blocker.close()
        wait_for(lambda: opened(c), HANG_S, "the open once the port is free")


def test_udp_port_is_receive_only_and_reports_its_address():
    port = UdpPort(f"opentrack-udp://127.0.0.1:{free_udp_port()}")
    try:
        assert port.address[0] == "127.0.0.1" and port.read_datagram(0.0) == b""
        with pytest.raises(Exception, match="takes no host commands"):
            port.write(b"S")
    finally:
        port.close()


@pytest.mark.parametrize(("argv", "message"), [
    (["--tracker", "opentrack-udp://127.0.0.1:70000"], "a port in 1-65535"),
    (["--tracker", "opentrack-udp://127.0.0.1:4242", "--tracker-protocol", "hatire"],
     "does not fit"),
    (["--tracker", "loop://", "--tracker-protocol", "opentrack"], "come over UDP"),
])
def test_holo_devices_refuses_urls_that_do_not_fit(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        cli_devices.main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert message in err


@posix_only
def test_holo_sim_over_udp_into_holo_devices_recorded_and_replayed(procs, tmp_path, sender):
    """Poses with faults (short datagrams, random ones, a sender that stops) end to end."""
    port, log = free_udp_port(), tmp_path / "ot.hlog"
    live = procs("drivers.commands.holo_devices", "--tracker", f"opentrack-udp://127.0.0.1:{port}",
                 "--dump", "--record", str(log), "--watchdog", "0.4")
    live.wait_lines(lambda: any('"opened"' in line for line in live.out))
    sim = procs("sim_devices.commands.holo_sim", "tracker", "--udp", f"127.0.0.1:{port}", "--rate",
                "200",
                "--seconds", "3", "--faults",
                "truncate=0.03,drop=0.02,burst=0.02,disconnect=0.004,reconnect_s=0.6,seed=4")
    sim.wait_lines(lambda: sim.out)
    assert sim.out[0] == f"opentrack-udp://127.0.0.1:{port}"
    assert sim.finish(HANG_S) == 0
    summary = json.loads(sim.out[-1])
    assert summary["faults"]["truncate"] and summary["faults"]["disconnect"]

    def last_seen() -> bool:  # a last pose of our own, after all of the simulator's
        sender.sendto(encode_pose(4000.0, 0, 0, 0, 0, 0), ("127.0.0.1", port))
        return any('"x":4000.0' in line for line in live.out)

    wait_for(last_seen, HANG_S, "the last pose dumped")
    live.p.send_signal(signal.SIGTERM)
    assert live.finish() == 143
    records = [json.loads(line) for line in live.out]
    reasons = {r["details"].get("reason") for r in records if r["kind"] == "status"}
    assert "wrong_size" in reasons
    stats = json.loads(live.err[-1])["stats"]["tracker"]
    assert stats["bad_size"] >= summary["faults"].get("truncate", 0)
    poses = [r for r in records if r["kind"] == "pose"]
    assert len(poses) == stats["frames"] - stats["out_of_range"]
    replay = procs("drivers.commands.holo_replay", str(log), "--as-fast-as-possible", "--dump")
    assert replay.finish(HANG_S) == 0
    assert replay.out == live.out  # datagram by datagram, the same lines

    # and back onto UDP, at the recorded timing, into a listener of our own
    port2, c = free_udp_port(), Collector()
    with listen(port2, c, watchdog_s=None) as reader:
        wait_for(lambda: opened(c), HANG_S, "the second listener opened")
        again = procs("drivers.commands.holo_replay", str(log), "--to-port",
                      f"opentrack-udp://127.0.0.1:{port2}", "--speed", "4")
        assert again.finish(HANG_S) == 0
        wait_for(lambda: reader.stats()["chunks"] == stats["chunks"], HANG_S,
                 "every recorded datagram sent again")
    assert [e.x for e in c.snapshot() if isinstance(e, PoseEvent)] == [p["x"] for p in poses]
