"""--forward-opentrack: a tracker's filtered poses out as opentrack datagrams over real UDP."""

from __future__ import annotations

import json
import signal
import socket

import pytest
from testkit import HANG_S, posix_only

from drivers.commands import holo_devices as cli_devices
from drivers.events import PoseEvent, StatusEvent
from drivers.opentrack_forward import ForwardSettings, OpentrackForwarder
from drivers.protocols.opentrack import OpentrackDecoder
from service.base.errors import SettingsError


@pytest.fixture
def listener():
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.settimeout(HANG_S)
    yield s
    s.close()


def received(sock: socket.socket, n: int) -> list[PoseEvent]:
    dec = OpentrackDecoder()
    out = []
    for _ in range(n):
        out += dec.feed(sock.recv(100), 0)
    assert all(isinstance(e, PoseEvent) for e in out)
    return out


def pose(t_ms: float, x: float, yaw: float = 0.0) -> PoseEvent:
    return PoseEvent(int(t_ms * 1e6), yaw, 2.0, -3.0, x, 5.0, 6.0, 0)


def test_raw_poses_round_trip_through_opentracks_axes(listener):
    fwd = OpentrackForwarder(ForwardSettings(*listener.getsockname(), filter="raw"))
    try:
        sent = [pose(10 * k, 10.0 * k, yaw=170.0 + 5 * k) for k in range(4)]
        for ev in sent:
            fwd.forward([ev])
        got = received(listener, 4)
    finally:
        fwd.close()
    for ev, back in zip(sent, got, strict=True):
        wrapped = (ev.yaw + 180) % 360 - 180  # 185 degrees goes out as -175
        assert (back.x, back.y, back.z) == pytest.approx((ev.x, ev.y, ev.z), abs=1e-9)
        assert (back.yaw, back.pitch, back.roll) == pytest.approx((wrapped, 2.0, -3.0))
    assert fwd.stats() == {"sent": 4, "skipped": 0, "send_errors": 0}


def test_filtered_and_predicted_poses_and_a_reset_on_reconnect(listener):
    fwd = OpentrackForwarder(ForwardSettings(*listener.getsockname(), "alpha-beta", 100.0))
    try:
        # x moves at 1 mm/ms: the filter's prediction leads the newest sample
        fwd.forward([pose(0, 99.0), pose(0, 0.0)])  # one read: only its newest pose
        fwd.forward([pose(10, 10.0)])
        fwd.forward([pose(20, 20.0)])
        fwd.forward([PoseEvent(21_000_000, 0, 0, 0, float("nan"), 0, 0, 1)])  # refused
        fwd.forward([StatusEvent(30_000_000, "tracker", "reconnect", {"decoder_reset": True}),
                     pose(40, 500.0)])
        got = received(listener, 4)
    finally:
        fwd.close()
    assert got[0].x == pytest.approx(0.0)  # the first sample: at rest, at the sample
    assert got[1].x > 10.0 and got[2].x > got[1].x > 10.0  # ahead of the samples
    assert got[3].x == pytest.approx(500.0)  # a reset: no velocity from before the outage
    assert fwd.stats() == {"sent": 4, "skipped": 1, "send_errors": 0}


def test_bad_forward_settings_are_refused(capsys):
    with pytest.raises(SettingsError):
        ForwardSettings("127.0.0.1", 4242, filter="kalman")
    with pytest.raises(SystemExit) as exc:
        cli_devices.main(["--tracker", "loop://", "--forward-opentrack", "127.0.0.1"])
    assert exc.value.code == 2
    assert "give HOST:PORT" in capsys.readouterr().err.splitlines()[-1]


@posix_only
def test_holo_devices_forwards_a_hatire_trackers_poses(procs, listener):
    sim = procs("sim_devices.commands.holo_sim", "tracker", "--pty", "--rate", "100", "--motion",
                "turn")
    sim.wait_lines(lambda: sim.out)
    host, port = listener.getsockname()
    live = procs("drivers.commands.holo_devices", "--tracker", sim.out[0], "--dump",
                 "--forward-opentrack", f"{host}:{port}", "--forward-filter", "raw")
    got = received(listener, 20)
    live.wait_lines(lambda: len(live.out) > 25)
    live.p.send_signal(signal.SIGTERM)
    assert live.finish() == 143
    dumped = [json.loads(line) for line in live.out]
    dumped = {(round(d["x"], 6), round(d["yaw"], 6)) for d in dumped if d["kind"] == "pose"}
    assert all((round(e.x, 6), round(e.yaw, 6)) in dumped for e in got)  # the same poses
    assert live.err[0].startswith(f"holo-devices: forwarding poses to opentrack at {host}:")
    assert live.err[-2].startswith("holo-devices: forwarded ")
