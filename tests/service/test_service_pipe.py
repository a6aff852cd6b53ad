"""FramePipe: a reply counts only for the attempt in flight; a given-up one's is dropped."""

from __future__ import annotations

import json

import zmq

from service.net import wire
from service.net.broker import FramePipe


def _serve_one(router: zmq.Socket) -> tuple[list[bytes], dict]:
    assert router.poll(5000), "the job never arrived"
    frames = router.recv_multipart()
    return frames[:2], json.loads(frames[2])


def _answer(router: zmq.Socket, envelope: list[bytes], job: dict) -> None:
    head = {"job": job["job"], "band": 0, "attempt": job["attempt"], "ok": True}
    router.send_multipart([*envelope, *wire.encode(head, [])])


def test_a_late_reply_to_a_resent_job_is_dropped():
    ctx = zmq.Context()
    router = ctx.socket(zmq.ROUTER)
    router.setsockopt(zmq.LINGER, 0)
    port = router.bind_to_random_port("tcp://127.0.0.1")
    pipe = FramePipe(ctx, f"tcp://127.0.0.1:{port}", timeout_s=0.0)
    try:
        pipe.send({"job": 5, "t": 0.0}, [], meta="first aim")
        env, job = _serve_one(router)
        late = pipe.expired()  # deadline 0: given up at once
        assert [f.meta for f in late] == ["first aim"] and not pipe.flights
        pipe.send({"job": 5, "t": 0.1}, [], meta="re-aimed", attempt=1)
        env1, job1 = _serve_one(router)
        _answer(router, env, job)  # the old attempt answers late: never handed on
        _answer(router, env1, job1)
        got = []
        for _ in range(5):
            got += pipe.poll(2000)
            if got:
                break
        assert [(f.meta, h["attempt"]) for f, h in got] == [("re-aimed", 1)]
        assert pipe.poll(200) == [] and pipe.max_in_flight == 1
    finally:
        pipe.close()
        router.close(0)
        ctx.term()
