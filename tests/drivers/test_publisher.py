"""Publisher and subscriber over real ZeroMQ sockets on tcp://127.0.0.1."""

from __future__ import annotations

import json
import math
import threading
import time

import pytest
import zmq
from hypothesis import given
from hypothesis import strategies as st
from testkit import HANG_S

from drivers.events import ButtonEvent, DialEvent, PoseEvent, StatusEvent
from drivers.publisher import Publisher, _dumps, pose_json
from drivers.subscriber import DeviceSubscriber
from service.base.errors import DeviceError, SettingsError


def pose(n: int, t_ns: int = 1_000) -> PoseEvent:
    return PoseEvent(t_ns + n, float(n), 0.5, -0.5, 1.0, 2.0, 3.0, n % 1000)


def pump_until(pub: Publisher, sub: DeviceSubscriber, pred, timeout: float = HANG_S,
               send=None) -> None:
    """Service the publisher (and optionally send) until ``pred(sub)``; fail on timeout."""
    deadline = time.monotonic() + timeout
    while not pred(sub):
        if time.monotonic() > deadline:
            raise AssertionError("subscriber condition not met in time")
        if send is not None:
            send()
        pub.service()
        sub.poll(0.01)


@pytest.fixture
def pub():
    p = Publisher("tcp://127.0.0.1:0", t0_ns=1_000)
    try:
        yield p
    finally:
        p.close()


def test_poses_dials_buttons_and_status_reach_a_subscriber(pub):
    assert pub.address.startswith("tcp://127.0.0.1:") and not pub.address.endswith(":0")
    with DeviceSubscriber(pub.address) as sub:
        pump_until(pub, sub, lambda s: s.pose is not None, send=lambda: pub.publish(pose(1)))
        pub.publish_all([pose(2), DialEvent(5_000, 3, 7, 7), ButtonEvent(6_000, 4, True),
                         StatusEvent(7_000, "tracker", "resync", {"discarded": 3})])
        got: list = []
        pump_until(pub, sub, lambda s: got.extend(s.take_events()) or len(got) >= 3)
        assert sub.pose.yaw == 2.0 and sub.pose.t_ns == 1_002 and sub.pose.seq == 2
        assert sub.dials[3] == 7 and sub.buttons[4] and sub.seq == 2
        assert [type(e) for e in got] == [DialEvent, ButtonEvent, StatusEvent]
        assert got[0] == DialEvent(5_000, 3, 7, 7)
        assert got[2].details == {"discarded": 3}
        assert sub.stats.gaps == 0 and sub.stats.malformed == 0


def test_dial_messages_carry_turns_per_the_configured_counts_per_turn():
    p = Publisher("tcp://127.0.0.1:0", counts_per_turn=50)
    raw = zmq.Context.instance().socket(zmq.SUB)
    raw.setsockopt(zmq.LINGER, 0)
    raw.setsockopt(zmq.SUBSCRIBE, b"dials")
    raw.connect(p.address)
    try:
        body: dict = {}
        deadline = time.monotonic() + HANG_S
        while body.get("kind") != "dial":  # snapshots first, then the turn
            assert time.monotonic() < deadline, "no dial message"
            p.publish(DialEvent(5_000, 1, -75, -75))
            p.service()
            if raw.poll(10):
                body = json.loads(raw.recv_multipart()[1])
        assert (body["value"], body["turns"]) == (-75, -1.5)
        assert {"index", "delta", "value", "turns", "seq", "dials", "buttons"} <= set(body)
    finally:
        raw.close()
        p.close()
    with pytest.raises(SettingsError):
        Publisher("tcp://127.0.0.1:0", counts_per_turn=0)


def test_late_joiner_sees_the_absolute_dial_and_button_state(pub):
    for k in range(10):
        pub.publish(DialEvent(k, k % 8, 5, 5 * (k // 8 + 1)))
    pub.publish(ButtonEvent(20, 31, True))
    with DeviceSubscriber(pub.address, topics=(b"dials",)) as late:
        # no new dial event: the snapshot sent on its subscription carries the state
        pump_until(pub, late, lambda s: s.state_known)
        assert late.dials == (10, 10, 5, 5, 5, 5, 5, 5)
        assert late.buttons[31] and not any(late.buttons[:31])
        assert late.seq == 11 and late.stats.gaps == 0
        pub.publish(DialEvent(30, 0, -3, 7))
        pump_until(pub, late, lambda s: s.seq == 12)
        assert late.dials[0] == 7 and late.stats.gaps == 0


def test_periodic_snapshot_and_reset_keep_the_sequence_consistent():
    clock = [0]
    p = Publisher("tcp://127.0.0.1:0", snapshot_s=1.0, clock_ns=lambda: clock[0])
    try:
        with DeviceSubscriber(p.address) as sub:
            pump_until(p, sub, lambda s: s.state_known)
            p.publish(DialEvent(1, 2, 9, 9))
            p.publish(StatusEvent(2, "dials", "reconnect", {"decoder_reset": True}))
            pump_until(p, sub, lambda s: s.seq == 2)
            assert sub.dials == (0,) * 8 and sub.stats.gaps == 0
            clock[0] = 2_000_000_000  # one snapshot period later
            before = sub.stats.messages
            pump_until(p, sub, lambda s: s.stats.messages > before)
            assert sub.seq == 2 and sub.stats.gaps == 0 and sub.stats.stale == 0
    finally:
        p.close()


def test_subscriber_counts_gaps_skips_malformed_and_follows_a_new_session():
    ctx = zmq.Context.instance()
    raw = ctx.socket(zmq.PUB)
    raw.setsockopt(zmq.LINGER, 0)
    port = raw.bind_to_random_port("tcp://127.0.0.1")

    def dials(seq: int, session: str = "a", value: int = 0) -> list[bytes]:
        body = {"t": 0.0, "t_ns": seq, "device": "dials", "kind": "dial", "index": 0,
                "delta": 1, "value": value, "seq": seq, "session": session,
                "dials": [value] + [0] * 7, "buttons": [False] * 32}
        return [b"dials", json.dumps(body).encode()]

    try:
        with DeviceSubscriber(f"tcp://127.0.0.1:{port}") as sub:
            deadline = time.monotonic() + HANG_S
            while not sub.state_known and time.monotonic() < deadline:
                raw.send_multipart(dials(1, value=1))
                sub.poll(0.01)
            start = sub.seq
            huge_t = dials(start + 1, value=7)  # a number JSON reads as inf
            huge_t[1] = huge_t[1].replace(b'"t": 0.0', b'"t": 1e400')
            huge_seq = dials(2**70, value=8)
            for msg in ([b"dials", b"{oops"], [b"dials"], [b"pose", b"[1, 2]"], huge_t,
                        huge_seq, dials(start + 1, value=2), dials(start + 5, value=3),
                        dials(start + 2, value=99), dials(1, session="b", value=4)):
                raw.send_multipart(msg)
            assert sub.wait_for(lambda s: s.session == "b", HANG_S)
    finally:
        raw.close()
    assert sub.stats.malformed == 5
    assert sub.stats.gaps == 1 and sub.stats.missing == 3 and sub.stats.stale == 1
    assert sub.dials[0] == 4 and sub.seq == 1 and sub.stats.sessions == 2


def test_pose_only_endpoint_conflates_to_the_latest_pose():
    p = Publisher("tcp://127.0.0.1:0", pose_address="tcp://127.0.0.1:0")
    sock = zmq.Context.instance().socket(zmq.SUB)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.CONFLATE, 1)
    sock.setsockopt(zmq.SUBSCRIBE, b"")
    sock.connect(p.pose_address)
    try:
        deadline = time.monotonic() + HANG_S
        while not sock.poll(10):
            assert time.monotonic() < deadline
            p.publish(pose(0))
        sock.recv()
        for n in range(1, 201):
            p.publish(pose(n))
        received = []
        while not received or received[-1]["n"] < p.counts["pose"]:
            assert sock.poll(max(0, int((deadline - time.monotonic()) * 1000))), "no newer pose"
            received.append(json.loads(sock.recv()))
        assert received[-1]["yaw"] == 200.0
        assert len(received) < 200  # older poses were dropped, only the newest kept
    finally:
        sock.close()
        p.close()


def test_subscriber_takes_poses_from_the_conflating_endpoint():
    p = Publisher("tcp://127.0.0.1:0", pose_address="tcp://127.0.0.1:0")
    try:
        with DeviceSubscriber(p.address, pose_address=p.pose_address) as sub:
            pump_until(p, sub, lambda s: s.pose is not None and s.state_known,
                       send=lambda: p.publish(pose(0)))
            before = sub.stats.messages
            for n in range(1, 301):
                p.publish(pose(n))
            p.publish(DialEvent(9, 1, 4, 4))
            pump_until(p, sub, lambda s: s.pose.yaw == 300.0 and s.dials[1] == 4)
            assert sub.stats.messages - before < 300  # old poses were conflated away
            assert sub.stats.malformed == 0 and sub.stats.gaps == 0
    finally:
        p.close()


def test_waits_time_out_without_a_publisher():
    ctx = zmq.Context.instance()
    probe = ctx.socket(zmq.PUB)
    port = probe.bind_to_random_port("tcp://127.0.0.1")
    probe.close(0)
    with DeviceSubscriber(f"tcp://127.0.0.1:{port}") as sub:
        start = time.monotonic()
        assert sub.wait_pose(0.1) is None
        assert not sub.wait_for(lambda s: s.state_known, 0.05)
        assert sub.poll(0.02) == 0
        assert time.monotonic() - start < 2.0


def test_bind_error_is_a_device_error(pub):
    with pytest.raises(DeviceError):
        Publisher(pub.address)
    with pytest.raises(DeviceError):
        Publisher("tcp://127.0.0.1:0", pose_address=pub.address)


def test_messages_are_topic_plus_json_with_the_dump_fields(pub):
    sock = zmq.Context.instance().socket(zmq.SUB)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.SUBSCRIBE, b"")
    sock.connect(pub.address)
    try:
        deadline = time.monotonic() + HANG_S
        frames: list[bytes] = []
        while not frames or frames[0] != b"pose":
            assert time.monotonic() < deadline
            pub.publish(pose(7))
            pub.service()
            frames = sock.recv_multipart() if sock.poll(10) else []
    finally:
        sock.close()
    assert len(frames) == 2
    body = json.loads(frames[1])
    extra = {k: body.pop(k) for k in ("t_ns", "session", "n")}
    assert body == pose(7).to_dict(1_000) and extra["t_ns"] == 1_007


finite = st.floats(allow_nan=False, allow_infinity=False)


@given(t_ns=st.integers(0, 2**63), t0_ns=st.integers(0, 2**40),
       vals=st.tuples(*[finite] * 6), seq=st.integers(0, 2**32 - 1),
       quat=st.none() | st.tuples(*[finite] * 4),
       device_t_us=st.none() | st.integers(0, 2**63), n=st.integers(1, 2**40))
def test_pose_body_is_byte_for_byte_what_json_writes(t_ns, t0_ns, vals, seq, quat,
                                                     device_t_us, n):
    ev = PoseEvent(t_ns, *vals, seq, quat, device_t_us)
    envelope = {**ev.to_dict(t0_ns), "t_ns": t_ns, "session": "0a1b2c3d", "n": n}
    assert pose_json(ev, t0_ns, "0a1b2c3d", n) == _dumps(envelope)


def test_pose_body_falls_back_to_json_for_what_it_cannot_format(pub):
    nan_pose = PoseEvent(1_500, math.nan, 0.0, 0.0, 0.0, 0.0, 0.0, 1)
    assert pose_json(nan_pose, 0, "0a1b2c3d", 1) is None
    assert pose_json(pose(1), 0, 'a"b', 1) is None
    with DeviceSubscriber(pub.address) as sub:
        pump_until(pub, sub, lambda s: s.pose is not None and s.pose.seq == 1,
                   send=lambda: pub.publish(nan_pose))
        assert math.isnan(sub.pose.yaw)


def test_sink_publishes_the_events_then_passes_the_item_on(pub):
    passed: list = []
    sink = pub.sink(lambda item, events: passed.append((item, events)))
    with DeviceSubscriber(pub.address) as sub:
        pump_until(pub, sub, lambda s: s.pose is not None,
                   send=lambda: sink("chunk", [pose(1)]))
        sink("quiet", [])
        sink("turn", [DialEvent(5_000, 2, 3, 3)])
        got: list = []
        pump_until(pub, sub, lambda s: got.extend(s.take_events()) or got)
    assert got == [DialEvent(5_000, 2, 3, 3)] and sub.dials[2] == 3
    assert passed[-2:] == [("quiet", []), ("turn", [DialEvent(5_000, 2, 3, 3)])]
    assert pub.sink()("no next sink", []) is None


def test_threads_publishing_at_once_keep_the_dial_stream_whole(pub):
    per_thread = 300
    with DeviceSubscriber(pub.address) as sub:
        pump_until(pub, sub, lambda s: s.state_known)
        start = threading.Barrier(3)

        def turn(index: int) -> None:
            start.wait(HANG_S)
            for k in range(per_thread):
                pub.publish_all([DialEvent(k, index, 1, k + 1), pose(k)])

        threads = [threading.Thread(target=turn, args=(i,)) for i in (0, 1)]
        for t in threads:
            t.start()
        start.wait(HANG_S)
        while any(t.is_alive() for t in threads):
            pub.service()  # the consumer thread's part, at the same time
            sub.poll(0.001)
        for t in threads:
            t.join(HANG_S)
        got: list = []
        pump_until(pub, sub, lambda s: got.extend(s.take_events())
                   or sum(isinstance(e, DialEvent) for e in got) == 2 * per_thread)
    assert sub.stats.gaps == 0 and sub.stats.malformed == 0 and sub.stats.stale == 0
    assert tuple(sub.dials[:2]) == (per_thread, per_thread) and sub.seq == 2 * per_thread
    assert pub.counts["pose"] == 2 * per_thread
