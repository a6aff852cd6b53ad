"""A stand-in render service whose ``stats`` replies come late (run as a script).

It speaks protocol version 1 (``service.net.protocol``) on 127.0.0.1 ports of its
own choosing and prints ``control ADDR frames ADDR`` once bound.  Every request is
answered at once except ``stats``: the first reply comes after ``first_delay``
seconds, later ones after ``delay`` (each with a new level-of-detail note, so a
client can tell which replies it took).  Frames (black, of the display
``set_display`` asked for) go out at 30 Hz.  It has no renderer, so it starts in a
fraction of a second; the tests use it where only the timing of replies matters.

Usage: ``python slow_stats_service.py FIRST_DELAY DELAY``; it stops on ``shutdown``
or a signal.
"""

from __future__ import annotations

import sys
import time
from typing import Any

import numpy as np
import zmq

from service.base.errors import MessageError
from service.net import protocol, wire

SESSION = "5a0c0001"


def answer(req: dict[str, Any], state: dict[str, Any]) -> dict[str, Any]:
    """The reply fields of every request but ``stats``."""
    kind = req["type"]
    if kind == "hello":
        return {"version": 1, "versions": [1], "service": "holo-service", "session": SESSION,
                "heartbeat_s": 1.0, "frames": state["frames"],
                "limits": protocol.DEFAULT_LIMITS.as_dict(), "status": "ready"}
    if kind == "set_display":
        for key in ("zones", "rows", "cols"):
            state[key] = int(req.get(key, state[key]))
        return {"display": {k: state[k] for k in ("zones", "rows", "cols")}}
    if kind == "load_scene":
        state["scene"] += 1
        return {"objects": [], "polygons": 0, "scene": state["scene"]}
    if kind == "update_objects":
        return {"updated": len(req.get("objects", []))}
    return {"status": "ready"} if kind == "ping" else {}


def main(first_delay: float, delay: float) -> None:
    ctx = zmq.Context.instance()
    router, pub = ctx.socket(zmq.ROUTER), ctx.socket(zmq.PUB)
    for s in (router, pub):
        s.setsockopt(zmq.LINGER, 0)
    router.bind("tcp://127.0.0.1:*")
    pub.bind("tcp://127.0.0.1:*")
    state = {"frames": pub.getsockopt_string(zmq.LAST_ENDPOINT), "zones": 3, "rows": 24,
             "cols": 32, "scene": 0}
    print(f"control {router.getsockopt_string(zmq.LAST_ENDPOINT)} frames {state['frames']}",
          flush=True)
    late: list[tuple[float, list[Any]]] = []  # (when, reply frames)
    asked, seq, next_frame = 0, 0, time.monotonic()
    while True:
        if router.poll(5):
            envelope, body = protocol.split_envelope(router.recv_multipart())
            try:
                req = protocol.parse_request(body)
            except MessageError as exc:
                part = getattr(exc, "partial", {})
                router.send_multipart(protocol.error_reply(
                    envelope, part.get("id"), part.get("type"), exc.code, exc.message))
                continue
            if req["type"] == "shutdown":
                break
            if req["type"] == "stats":
                asked += 1
                stats = {"lod": {"chains": {"notes": [f"slow note {asked}"]}}}
                wait = first_delay if asked == 1 else delay
                late.append((time.monotonic() + wait,
                             protocol.reply(envelope, req["id"], "stats", {"stats": stats})))
            else:
                router.send_multipart(
                    protocol.reply(envelope, req["id"], req["type"], answer(req, state)))
        now = time.monotonic()
        for item in [x for x in late if x[0] <= now]:
            late.remove(item)
            router.send_multipart(item[1])
        if now >= next_frame:
            seq += 1
            next_frame = now + 1 / 30
            colour = np.zeros((state["zones"], state["rows"], state["cols"], 3), np.uint8)
            head = {"v": 1, "kind": "frame", "session": SESSION, "seq": seq, "render_id": 0,
                    "since_render": seq, "t_ns": time.monotonic_ns(), "scene": state["scene"]}
            wire.send(pub, [b"frame", *wire.encode(head, [colour], ["colour"])], timeout_ms=0)


if __name__ == "__main__":
    main(float(sys.argv[1]), float(sys.argv[2]))
