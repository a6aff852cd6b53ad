"""holo-view against a real publisher: JSON snapshots, text lines, a live panel in a pty."""

from __future__ import annotations

import json
import os
import select
import signal
import threading
import time
import tty

import pytest
from testkit import SIGNALS, STATUS, catches, linux_only, posix_only, wait_for

from drivers.commands import holo_view as cli_view
from drivers.events import ButtonEvent, DialEvent, PoseEvent
from drivers.publisher import Publisher


class Stream:
    """A publisher in a thread: a pose every 10 ms (yaw = its number); once ``go`` is
    set, dial 2 turned to 40 and button 3 pressed (once)."""

    def __init__(self, go: threading.Event | None = None) -> None:
        self.pub = Publisher("tcp://127.0.0.1:0", 0)
        self.stop = threading.Event()
        self.go = go if go is not None else threading.Event()
        if go is None:
            self.go.set()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        k, sent = 0, False
        while not self.stop.wait(0.01):
            k += 1
            t = time.monotonic_ns()
            self.pub.publish(PoseEvent(t, float(k), -2.25, 0.75, 1.0, 2.0, 3.0, k))
            if self.go.is_set() and not sent:
                sent = True
                self.pub.publish(DialEvent(t, 2, 40, 40))
                self.pub.publish(ButtonEvent(t, 3, True))
            self.pub.service()

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5)
        self.pub.close()


@pytest.fixture
def stream():
    s = Stream()
    try:
        yield s
    finally:
        s.close()


def test_json_snapshots_hold_the_latest_state(procs, stream):
    view = procs("drivers.commands.holo_view", stream.pub.address, "--json", "--count", "40",
                 "--rate", "100")
    assert view.finish() == 0
    snaps = [json.loads(ln) for ln in view.out]
    assert len(snaps) == 40
    last = snaps[-1]
    assert last["address"] == stream.pub.address and last["session"] == stream.pub.session
    assert last["pose"]["pitch"] == -2.25 and last["pose"]["yaw"] == last["pose"]["seq"]
    assert [p["pose"]["seq"] for p in snaps if p["pose"]] == sorted(
        p["pose"]["seq"] for p in snaps if p["pose"])
    assert last["dials"] == [0, 0, 40, 0, 0, 0, 0, 0] and last["buttons"] == [3]
    assert last["malformed"] == 0 and last["messages"] >= 40


def test_each_event_comes_once_in_the_snapshot_after_it(procs):
    go = threading.Event()
    stream = Stream(go)
    try:
        view = procs("drivers.commands.holo_view", stream.pub.address, "--json", "--count", "60",
                     "--rate", "100")
        view.wait_lines(lambda: len(view.out) >= 3)  # subscribed and showing poses
        go.set()
        assert view.finish() == 0
    finally:
        stream.close()
    snaps = [json.loads(ln) for ln in view.out]
    events = [e for s in snaps for e in s["events"]]
    assert events == [{"device": "dials", "kind": "dial", "index": 2, "delta": 40, "value": 40},
                      {"device": "dials", "kind": "button", "index": 3, "pressed": True}]
    # the two events are published back to back but may cross the socket in two reads
    # (a fresh clone's make test once split them), so each is checked where it came
    dial = next(i for i, s in enumerate(snaps) if any(e["kind"] == "dial" for e in s["events"]))
    press = next(i for i, s in enumerate(snaps) if any(e["kind"] == "button" for e in s["events"]))
    assert snaps[dial - 1]["dials"][2] == 0 and snaps[dial]["dials"][2] == 40
    assert snaps[press - 1]["buttons"] == [] and snaps[press]["buttons"] == [3]
    assert snaps[-1]["buttons"] == [3] and press >= dial


def test_once_and_plain_lines(procs, stream):
    view = procs("drivers.commands.holo_view", stream.pub.address, "--once")
    assert view.finish() == 0 and len(view.out) == 1
    line = view.out[0]
    assert line.startswith("t ") and ("pose yaw" in line or "pose no pose yet" in line)
    assert "dials " in line and "buttons " in line


def test_nothing_arrives_exit_1(capsys):
    # port 1 on loopback: nobody publishes there
    assert cli_view.main(["tcp://127.0.0.1:1", "--once", "--timeout", "0.3"]) == 1
    assert "nothing from tcp://127.0.0.1:1 within 0.3 s" in capsys.readouterr().err


def test_bad_address_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exc:
        cli_view.main(["tcp://127.0.0.1:0"])  # nothing to connect to
    assert exc.value.code == 2 and "1-65535" in capsys.readouterr().err


def _read_pty(master: int, text: list[str]) -> None:
    while select.select([master], [], [], 0)[0]:
        try:
            text.append(os.read(master, 65536).decode(errors="replace"))
        except OSError:
            return


@posix_only
@SIGNALS
def test_live_panel_in_a_terminal_redraws_in_place_and_stops_cleanly(procs, stream, signum):
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        view = procs("drivers.commands.holo_view", stream.pub.address, "--rate", "50", stdout=slave)
        text: list[str] = []

        def panel_shows_state() -> bool:
            _read_pty(master, text)
            screen = "".join(text)
            return "held: 3" in screen and "2:   +40" in screen and "pose     yaw" in screen

        wait_for(panel_shows_state, what="the panel with the stream's state")
        view.signal(signum)
        assert view.finish() == STATUS[signum]
        _read_pty(master, text)
    finally:
        os.close(master)
        os.close(slave)
    screen = "".join(text)
    assert screen.startswith(cli_view.HIDE + cli_view.HOME)  # cursor hidden, drawn at home
    assert screen.count(cli_view.HOME) > 2  # redrawn in place, not scrolled
    assert screen.endswith(cli_view.SHOW)  # the cursor is back after the stop
    assert "Traceback" not in screen and not view.err


@linux_only
def test_sigint_while_waiting_for_a_publisher(procs):
    view = procs("drivers.commands.holo_view", "tcp://127.0.0.1:1", "--json")
    view.wait_lines(lambda: catches(view.p.pid, signal.SIGTERM))
    view.signal(signal.SIGINT)
    assert view.finish() == 130 and view.out == []


def test_poses_from_the_pose_only_endpoint(procs):
    pub = Publisher("tcp://127.0.0.1:0", 0, pose_address="tcp://127.0.0.1:0")
    stop = threading.Event()

    def run() -> None:
        k = 0
        while not stop.wait(0.01):
            k += 1
            pub.publish(PoseEvent(time.monotonic_ns(), float(k), 0.0, 0.0, 0.0, 0.0, 0.0, k))
            pub.service()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    try:
        view = procs("drivers.commands.holo_view", pub.address, "--pose", pub.pose_address,
                     "--json",
                     "--count", "20", "--rate", "100")
        assert view.finish() == 0
    finally:
        stop.set()
        thread.join(5)
        pub.close()
    snaps = [json.loads(ln) for ln in view.out]
    with_pose = [s for s in snaps if s["pose"]]
    assert with_pose and all(s["pose"]["yaw"] == s["pose"]["seq"] for s in with_pose)
    # each pose counted once (not also taken from the main socket): no more poses came
    # in than the publisher sent meanwhile
    first, last = with_pose[0], with_pose[-1]
    assert 0 < last["poses"] - first["poses"] <= last["pose"]["seq"] - first["pose"]["seq"]
