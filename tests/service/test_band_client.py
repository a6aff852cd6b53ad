"""BandClient: a worker's reply that names no band of the job counts as no reply."""

from __future__ import annotations

import json
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import zmq

from service.net import wire
from service.net.broker import BandClient

HANG_S = 60


def _serve(router: zmq.Socket, replies: list[tuple[dict, list]]) -> list[dict]:
    """Take the client's band requests, then send ``replies`` (header, arrays) in order."""
    asked = []
    while len(asked) < 2:
        assert router.poll(HANG_S * 1000)
        ident, _, head, *_ = router.recv_multipart()
        asked.append((ident, json.loads(head)))
    ident = asked[0][0]
    for head, arrays in replies:
        wire.send(router, [ident, b"", *wire.encode(head, arrays, [f"a{i}" for i in
                                                                 range(len(arrays))])], 1000)
    return [h for _, h in asked]


def test_replies_naming_no_band_of_the_job_are_dropped_and_the_bands_come_back_in_order():
    ctx = zmq.Context()
    router = ctx.socket(zmq.ROUTER)
    router.setsockopt(zmq.LINGER, 0)
    router.bind("inproc://bands")
    client = BandClient(ctx, "inproc://bands", timeout_s=HANG_S)
    job = {"job": 7, "kind": "render"}
    band = {b: np.full(3, b, np.int32) for b in (0, 1)}
    bad = [{"ok": True, "job": 7}, {"ok": True, "job": 7, "band": 2},
           {"ok": True, "job": 7, "band": -1}, {"ok": True, "job": 7, "band": True},
           {"ok": True, "job": 7, "band": "1"}, {"ok": False, "job": 7, "band": 1},
           {"ok": True, "job": 6, "band": 1}]
    replies = [(h, [band[1]]) for h in bad]
    # a band 0 and one stray band: a count of replies alone would end the job here
    replies += [({"ok": True, "job": 7, "band": 0}, [band[0]]),
                ({"ok": True, "job": 7, "band": 0}, [band[1]]),  # a second reply: ignored
                ({"ok": True, "job": 7, "band": 1}, [band[1]])]
    try:
        with ThreadPoolExecutor(1) as pool:
            result = pool.submit(client.run, job, [], [(0, 2), (2, 4)])
            asked = _serve(router, replies)
            got = result.result(timeout=HANG_S)
        assert sorted(h["band"] for h in asked) == [0, 1]
        assert got is not None and [g["a0"].tolist() for g in got] == [[0, 0, 0], [1, 1, 1]]
        assert client.resent == 0
    finally:
        client.close()
        router.close(0)
        ctx.term()
