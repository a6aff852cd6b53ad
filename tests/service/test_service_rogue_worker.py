"""A worker whose replies parse but do not make a render fails that render, not the service.

A remote ``holo-service-worker`` may be of another version: its replies can name the
job right and still carry arrays that do not stitch or stats of other types.  The
render thread must count each such render as failed, say why, and go on rendering.
"""

from __future__ import annotations

import json
import threading

import numpy as np
import pytest
import zmq
from testkit import HANG_S, free_port, wait_until

from service.engine.jobs import StatsRenderer
from service.net import protocol, wire
from service.net.client import ServiceClient
from service.net.worker import READY, handle_job, split_job

#: Malformed replies, each with the job's id, band and attempt filled in.
REPLIES = {
    "arrays that do not stitch": ({"stats": {}}, {"colour": np.zeros(3, np.float32)}),
    "stats of another type": ({"stats": [1, 2]}, {"colour": np.zeros(3, np.float32)}),
    "no arrays at all": ({"stats": {"lod": 3, "bands": 4}}, {}),
}


def _reply(kind: str, body: list) -> list:
    """Reply frames to a job: ``REPLIES[kind]``, or a real render of the job at 16 columns."""
    job = protocol.parse_reply(body)
    if kind == "a real render of another size":
        head = json.loads(bytes(body[0]))
        head["display"]["cols"] = 16
        return handle_job(StatsRenderer(), [json.dumps(head).encode(), *body[1:]])
    extra, arrays = REPLIES[kind]
    head = {"ok": True, "job": job["job"], "band": job.get("band", 0),
            "attempt": job.get("attempt", 0), **extra}
    return wire.encode(head, list(arrays.values()), list(arrays))


def _rogue(backend: str, stop: threading.Event, kind: str, answered: list) -> None:
    """A worker in this process: READY, then every job answered as ``kind`` says."""
    ctx = zmq.Context()
    sock = ctx.socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(backend)
    try:
        wire.send(sock, [b"", READY, json.dumps({"pid": 999_999, "jobs": 0}).encode()], 1000)
        while not stop.is_set():
            if not sock.poll(200):
                wire.send(sock, [b"", READY, b'{"pid": 999999, "jobs": 0}'], 1000)
                continue
            envelope, body = split_job(sock.recv_multipart(copy=False))
            if body is None:
                continue
            wire.send(sock, [b"", *envelope, *_reply(kind, body)], 1000)
            answered.append(kind)
    finally:
        sock.close(0)
        ctx.term()


@pytest.mark.parametrize("split", ["frames", "bands"])
@pytest.mark.parametrize("kind", [*REPLIES, "a real render of another size"])
def test_a_worker_with_malformed_replies_fails_renders_and_the_service_goes_on(
        service_factory, split, kind):
    backend = f"tcp://127.0.0.1:{free_port()}"
    svc = service_factory(
        "--scene", "game", "--zones", "1", "--size", "32x24", "--split", split,
        "--workers", "0", "--worker-address", backend, "--refresh", "30",
        "--render-timeout", "0.5",  # a band with no usable reply fails after 4 x 0.5 s
    )  # fmt: skip
    stop, answered = threading.Event(), []
    rogue = threading.Thread(target=_rogue, args=(backend, stop, kind, answered), daemon=True)
    rogue.start()
    try:
        with ServiceClient(svc.control, timeout_s=30) as c:
            assert wait_until(lambda: c.stats()["split"] == split, HANG_S), "worker never joined"
            assert wait_until(lambda: c.stats()["render_failures"] >= 2, HANG_S)
            st = c.stats()
            assert answered and st["last_render_error"], st
            stop.set()
            rogue.join(HANG_S)
            # the rogue gone, renders run in process again: the render thread lived
            assert wait_until(lambda: c.stats()["split"] == "in_process", HANG_S)
            before = c.stats()["renders"]
            header, _ = c.render_once()
            assert header["stats"]["mode"] == "in_process"
            assert c.stats()["renders"] > before
    finally:
        stop.set()
        rogue.join(HANG_S)
