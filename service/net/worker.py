"""Render workers: one update (a whole frame, or a band of its hololines), in its own process.

A worker connects a DEALER to the broker's backend (``service/net/broker.py``), says
``READY`` (and again every worker heartbeat while idle, ``BUSY`` every heartbeat
while it renders, so the broker tells a dead or stopped worker from a busy one
within three heartbeats), and answers each job with the arrays of its rows (all of them for a
whole-frame job, the default) and the render's stats.  A job is a JSON header plus
the scene's buffers (``docs/protocol.md`` array rules: JSON and raw buffers only)::

    {"job": 12, "band": 1, "attempt": 0, "rows": [60, 120], "t": 0.25,
     "refresh_hz": 60, "display": {...}, "render": {...}, "viewer": {...} | null,
     "scene": {...inline scene with $array references...}}

Bands: rows ``r0:r1`` of a display render as a display ``r1 - r0`` rows high with
the scene moved up by ``r0 * s + (h' - h) / 2`` (``s`` the pixel size, ``h`` and
``h'`` the heights), which puts exactly those hololines on it: the projection is
parallel, so a translation moves the picture without changing it.  With a viewer
pose the viewer is moved down instead (exact unless the viewer rotates between
the difference steps).

Run: ``python -m service.net.worker --connect tcp://HOST:5557 [--curve-keys DIR]``.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import zmq

from service.engine.jobs import StatsRenderer, render_job
from service.net import protocol, wire
from service.net.client import _curve_client
from service.numba_patches import locked_cache_saves
from service.process import setup_frame_process
from service.render.pipeline import Renderer, warm_up

#: an idle worker's message to the broker (with ``{"pid", "jobs", "heartbeat_s"}``).
READY = b"READY"
#: a rendering worker's heartbeat to the broker (it is alive, its job still running).
BUSY = b"BUSY"


def handle_job(renderer: Renderer, body: list[Any]) -> list[Any]:
    """Job frames (header, buffers) -> reply frames (header, buffers)."""
    try:
        job = protocol.parse_reply(body)
        arrays = job.pop("arrays", [])
        spec = wire.resolve(job.pop("scene"), arrays if isinstance(arrays, list) else [])
        out, stats = render_job(renderer, job, wire.scene_from_wire(spec))
        names = list(out)
        head = {
            "job": job["job"],
            "band": job.get("band", 0),
            "attempt": job.get("attempt", 0),
            "ok": True,
            "pid": os.getpid(),
            "stats": {**stats, "pid": os.getpid()},
        }
        return wire.encode(head, [out[n] for n in names], names)
    except Exception as exc:  # noqa: BLE001 - a bad job must not kill the worker
        head = {"job": None, "ok": False, "error": f"{type(exc).__name__}: {exc}"}
        try:
            head["job"], head["band"] = json.loads(bytes(body[0]))["job"], None
        except (ValueError, KeyError, IndexError, TypeError):
            pass
        return wire.encode(head, [])


class Worker:
    """The worker loop: READY, then jobs, until stopped or the deadline.

    A job renders on a thread of its own while the loop sends ``BUSY`` every
    :data:`~service.net.protocol.WORKER_HEARTBEAT_S` (the socket stays on the loop's
    thread), so a long render is told from a stopped process.

    Parameters
    ----------
    address : str
        The broker's backend address.
    curve_keys : str, optional
        ``holo-service-keys`` directory (CurveZMQ client).
    """

    def __init__(self, address: str, curve_keys: str | None = None) -> None:

        self.ctx = zmq.Context()
        self.sock = self.ctx.socket(zmq.DEALER)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.setsockopt(zmq.HEARTBEAT_IVL, 1000)
        self.sock.setsockopt(zmq.HEARTBEAT_TIMEOUT, 3000)
        _curve_client(self.sock, curve_keys)
        self.sock.connect(address)
        self.renderer = StatsRenderer()
        self.jobs = 0
        self._render = ThreadPoolExecutor(1, thread_name_prefix="render")

    def _ready(self) -> None:
        info = {"pid": os.getpid(), "jobs": self.jobs, "heartbeat_s": protocol.WORKER_HEARTBEAT_S}
        wire.send(self.sock, [b"", READY, json.dumps(info).encode()], 1000)

    def _answer(self, body: list[Any]) -> list[Any]:
        """Render a job on the render thread, sending ``BUSY`` every heartbeat meanwhile."""
        job = self._render.submit(handle_job, self.renderer, body)
        while True:
            try:
                return job.result(protocol.WORKER_HEARTBEAT_S)
            except TimeoutError:
                wire.send(self.sock, [b"", BUSY], 1000)

    def run(self, stop_after_s: float | None = None, parent: int | None = None) -> None:
        """Serve jobs; sends READY every worker heartbeat while idle.

        Stops after ``stop_after_s`` or when process ``parent`` is no longer its parent.
        """
        end = None if stop_after_s is None else time.monotonic() + stop_after_s
        beat = protocol.WORKER_HEARTBEAT_S
        self._ready()
        last = time.monotonic()
        while (end is None or time.monotonic() < end) and (
            parent is None or os.getppid() == parent
        ):
            if not self.sock.poll(int(beat * 1000)):
                if time.monotonic() - last >= beat:
                    self._ready()
                    last = time.monotonic()
                continue
            frames = self.sock.recv_multipart(copy=False)
            envelope, body = split_job(frames)
            if body is None:
                continue
            reply = self._answer(body)
            self.jobs += 1
            wire.send(self.sock, [b"", *envelope, *reply], 5000)
            last = time.monotonic()

    def close(self) -> None:
        """Stop the render thread; close the socket and the context."""
        self._render.shutdown(wait=False)
        self.sock.close(0)
        self.ctx.term()


def split_job(frames: list[Any]) -> tuple[list[bytes], list[Any] | None]:
    """``[b"", client, b"", header, *buffers]`` -> (``[client, b""]``, body)."""
    if len(frames) < 4 or len(frames[0]) or len(frames[2]):
        return [], None
    return [bytes(frames[1]), b""], [f.buffer for f in frames[3:]]


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m service.net.worker``."""
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # see service.commands.holo_service.main
    setup_frame_process()  # heap reuse and one BLAS thread (service.process)
    ap = argparse.ArgumentParser(prog="holo-service-worker")
    ap.add_argument("--connect", default="tcp://127.0.0.1:5557")
    ap.add_argument("--curve-keys", default=None)
    ap.add_argument("--warm-up", action="store_true", help="compile the kernels before READY")
    ap.add_argument("--parent", type=int, default=None, help="exit when this process is gone")
    ap.add_argument(
        "--nice",
        type=int,
        default=5,
        help="lower the worker's CPU priority: renders are elastic, refreshes are "
        "not (the service's refresh thread and the device drivers come first)",
    )
    args = ap.parse_args(argv)
    if args.nice > 0:
        os.nice(args.nice)
    worker = Worker(args.connect, args.curve_keys)

    locked_cache_saves()  # a service's background compile may write the same cache
    if args.warm_up:

        warm_up()
    try:
        worker.run(parent=args.parent)
    except KeyboardInterrupt:
        pass
    finally:
        worker.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
