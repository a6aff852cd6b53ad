"""Heartbeats: the frame stream's ``hb`` messages while no frame is published, and
``ServiceClient.heartbeat()`` pinging only when idle."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
import zmq
from testkit import TINY_DISPLAY, wait_until

from service.net import protocol
from service.net.client import ServiceClient


@pytest.mark.parametrize("refresh_hz", [30, 1])
def test_frame_stream_sends_heartbeats_without_frames(service_factory, refresh_hz):
    # no scene: nothing is rendered, so no frame is ever published
    svc = service_factory(*TINY_DISPLAY, "--refresh", str(refresh_hz))
    with ServiceClient(svc.control) as c:
        hello = c.hello()
    sub = zmq.Context.instance().socket(zmq.SUB)
    sub.setsockopt(zmq.LINGER, 0)
    sub.setsockopt(zmq.SUBSCRIBE, b"")
    sub.connect(svc.frames)
    got = []
    try:
        deadline = time.monotonic() + 8.0
        while len(got) < 4 and time.monotonic() < deadline:
            if sub.poll(200):
                topic, head = sub.recv_multipart()[:2]
                got.append((time.monotonic(), topic, json.loads(head)))
    finally:
        sub.close(0)
    assert len(got) >= 4, f"{len(got)} messages in 8 s"
    assert {t for _, t, _ in got} == {b"hb"}, "no frame without a scene"
    for _, _, h in got:
        assert h["kind"] == "hb" and h["v"] == 1 and h["session"] == hello["session"]
        assert h["seq"] == 0 and "arrays" not in h
    beat, tick = hello["heartbeat_s"] * 1e3, 1e3 / refresh_hz
    sent = np.diff([h["t_ns"] / 1e6 for _, _, h in got])
    # docs/protocol.md 1.7: a message at least every heartbeat_s (the refresh loop
    # checks once a tick, so within a tick of jitter), and not a flood either
    assert np.all(sent <= beat + 150), sent
    assert np.all(sent >= min(beat / 2, tick) - 50), sent
    received = np.diff([t for t, _, _ in got])
    assert received.max() < 3 * hello["heartbeat_s"]


def test_client_heartbeat_pings_only_when_idle(small_service):
    with ServiceClient(small_service.control) as c:
        before = c.stats()["requests"]  # this stats request counts itself
        assert c.heartbeat()  # just heard from the service: nothing sent
        assert c.stats()["requests"] == before + 1
        assert wait_until(
            lambda: time.monotonic() - c.last_reply_t >= protocol.HEARTBEAT_S, 3, 0.05
        )
        assert c.heartbeat()  # idle for a heartbeat: a ping
        assert time.monotonic() - c.last_reply_t < protocol.HEARTBEAT_S
        s = c.stats()
        assert s["requests"] == before + 3 and s["clients"] >= 1
        assert s["errors"] == 0
    small_service.stop()
    with ServiceClient(small_service.control, timeout_s=0.3, retries=0) as gone:
        assert gone.heartbeat() is False
