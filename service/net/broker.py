"""Least-recently-used broker between the service's render thread and render workers.

The ZeroMQ guide's load-balancing broker: a ROUTER frontend (the render thread's
DEALER, ``inproc://`` inside the service) and a ROUTER backend (workers' DEALERs,
``tcp://``, on this machine or others).  A worker announces itself with ``READY``;
each job goes to the worker idle the longest; its reply makes it ready again.
Idle workers repeat ``READY`` every heartbeat; one not heard from for three is
forgotten.  A worker that dies mid-job simply never answers: the requester's
deadline expires and it resends the job, which goes to another worker
(:class:`FramePipe` for whole-frame jobs, the default; :class:`BandClient` for
bands of one update).  ``ROUTER_MANDATORY`` makes a send to a vanished worker an
error, so the broker drops it and tries the next one.
"""

from __future__ import annotations

import json
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import zmq

from service.errors import MessageError
from service.net import protocol, wire
from service.net.worker import READY


class Broker:
    """The LRU broker (run it on a thread with :meth:`run`).

    Parameters
    ----------
    context : zmq.Context
    frontend, backend : str
        Bind addresses (requesters, workers).
    secure : callable, optional
        CurveZMQ server setup applied to the backend before binding.
    busy_limit_s : float
        A worker busy this long without answering is forgotten (it died mid-job; if
        it was only slow, its late reply makes it ready again).
    """

    def __init__(
        self,
        context: zmq.Context,
        frontend: str,
        backend: str,
        secure: Any = None,
        busy_limit_s: float = 10.0,
    ) -> None:
        self.busy_limit_s = busy_limit_s
        self.front = context.socket(zmq.ROUTER)
        self.back = context.socket(zmq.ROUTER)
        for s in (self.front, self.back):
            s.setsockopt(zmq.LINGER, 0)
            s.setsockopt(zmq.ROUTER_MANDATORY, 1)
            s.setsockopt(zmq.SNDTIMEO, 1000)
        self.back.setsockopt(zmq.HEARTBEAT_IVL, 1000)
        self.back.setsockopt(zmq.HEARTBEAT_TIMEOUT, 3000)
        if secure is not None:
            secure(self.back)
        self.front.bind(frontend)
        self.back.bind(backend)
        self.backend_address = self.back.getsockopt_string(zmq.LAST_ENDPOINT)
        self.ready: OrderedDict[bytes, float] = OrderedDict()  # worker -> last heard
        self.busy: dict[bytes, float] = {}
        self.pids: dict[bytes, int] = {}
        # ready, busy and pids change on the broker's thread and are read by info() on
        # the service's: a worker moved between them is never seen in neither or both
        self._books = threading.Lock()
        self.dispatched = 0
        self.dropped = 0
        self._stop = threading.Event()

    def stop(self) -> None:
        """Ask :meth:`run` to return."""
        self._stop.set()

    def info(self) -> dict[str, Any]:
        """Worker counts and pids (for the service's stats)."""
        with self._books:
            return {
                "ready": len(self.ready),
                "busy": len(self.busy),
                "dispatched": self.dispatched,
                "dropped": self.dropped,
                "workers": [{"pid": self.pids.get(w), "busy": w in self.busy}
                            for w in [*self.ready, *self.busy]],
            }

    def run(self) -> None:
        """Route until :meth:`stop`; closes both sockets on return."""
        poller = zmq.Poller()
        poller.register(self.back, zmq.POLLIN)
        poller.register(self.front, zmq.POLLIN)
        try:
            while not self._stop.is_set():
                events = dict(poller.poll(100))
                if self.back in events:
                    self._from_worker(self.back.recv_multipart(copy=False))
                if self.front in events and self.ready:
                    self._to_worker(self.front.recv_multipart(copy=False))
                self._expire()
        finally:
            self.front.close(0)
            self.back.close(0)

    def _from_worker(self, frames: list[zmq.Frame]) -> None:
        worker = bytes(frames[0].buffer)
        if len(frames) >= 3 and bytes(frames[2].buffer) == READY:
            with self._books:
                self.busy.pop(worker, None)
                self.ready[worker] = time.monotonic()
                self.ready.move_to_end(worker)
                self._note_pid(worker, frames[3:])
            return
        if len(frames) < 5:
            return
        with self._books:
            self.busy.pop(worker, None)
            self.ready[worker] = time.monotonic()
        try:
            self.front.send_multipart(frames[2:], copy=False)
        except zmq.ZMQError:
            self.dropped += 1  # the requester is gone; nothing to do

    def _note_pid(self, worker: bytes, rest: list[zmq.Frame]) -> None:
        try:
            self.pids[worker] = int(json.loads(bytes(rest[0].buffer))["pid"])
        except (IndexError, ValueError, KeyError, TypeError):
            pass

    def _to_worker(self, frames: list[zmq.Frame]) -> None:
        while True:
            with self._books:  # busy from the moment it is chosen
                if not self.ready:
                    break
                worker, _ = self.ready.popitem(last=False)
                self.busy[worker] = time.monotonic()
            try:
                self.back.send_multipart([worker, b"", *frames], copy=False)
            except zmq.ZMQError:
                with self._books:
                    self.busy.pop(worker, None)
                    self.pids.pop(worker, None)
                continue  # vanished: try the next one
            self.dispatched += 1
            return
        self.dropped += 1  # no worker took it: the requester's deadline resends

    def _expire(self) -> None:
        limit = protocol.HEARTBEAT_S * protocol.HEARTBEAT_LIVENESS
        now = time.monotonic()
        with self._books:
            for w in [w for w, t in self.ready.items() if now - t > limit]:
                del self.ready[w]
                self.pids.pop(w, None)
            for w in [w for w, t in self.busy.items() if now - t > self.busy_limit_s]:
                del self.busy[w]
                self.pids.pop(w, None)


class BandClient:
    """Sends one update's bands through the broker and gathers them, resending on timeout.

    Parameters
    ----------
    context : zmq.Context
    address : str
        The broker's frontend.
    timeout_s : float
        Deadline per attempt of each band.
    retries : int
        Resends per band before the update fails.
    stop : threading.Event, optional
        Set: :meth:`run` gives up at once.
    has_workers : callable, optional
        Whether the broker knows a worker; a band past its deadline when it knows
        none fails the update instead of being resent to nobody.
    """

    def __init__(
        self,
        context: zmq.Context,
        address: str,
        timeout_s: float = 5.0,
        retries: int = 3,
        stop: threading.Event | None = None,
        has_workers: Callable[[], bool] | None = None,
    ) -> None:
        self.stop = stop or threading.Event()
        self.has_workers = has_workers or (lambda: True)
        self.sock = context.socket(zmq.DEALER)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.connect(address)
        self.timeout_s = timeout_s
        self.retries = retries
        self.resent = 0

    def run(
        self, job: dict[str, Any], scene_arrays: list[np.ndarray], bands: list[tuple[int, int]]
    ) -> list[dict[str, np.ndarray]] | None:
        """Render every band; their arrays in band order, or None when one failed."""
        got: dict[int, dict[str, np.ndarray]] = {}
        attempts = dict.fromkeys(range(len(bands)), 0)
        sent_at: dict[int, float] = {}
        for b in range(len(bands)):
            sent_at[b] = self._send(job, scene_arrays, bands, b, 0)
        while len(got) < len(bands):
            if self.stop.is_set():
                return None
            now = time.monotonic()
            for b in [b for b in range(len(bands)) if b not in got]:
                if now - sent_at[b] > self.timeout_s:
                    if attempts[b] >= self.retries or not self.has_workers():
                        return None
                    attempts[b] += 1
                    self.resent += 1
                    sent_at[b] = self._send(job, scene_arrays, bands, b, attempts[b])
            if self.sock.poll(50):
                self._take(self.sock.recv_multipart(copy=False), job["job"], len(bands), got)
        return [got[b] for b in range(len(bands))]

    def _send(
        self,
        job: dict[str, Any],
        arrays: list[np.ndarray],
        bands: list[tuple[int, int]],
        band: int,
        attempt: int,
    ) -> float:
        head = {**job, "band": band, "attempt": attempt, "rows": list(bands[band])}
        wire.send(self.sock, [b"", *wire.encode(head, arrays)], 1000)
        return time.monotonic()

    @staticmethod
    def _take(frames: list[zmq.Frame], job_id: int, bands: int, got: dict) -> None:
        """Keep a worker's reply for one of the ``bands`` bands of job ``job_id``.

        A reply that is garbled, failed, for another job, or names no band of this
        one (a remote worker of another version, say) counts as no reply: its band
        is resent when its deadline passes.  The first good reply of a band wins.
        """
        try:
            head = protocol.parse_reply([f.buffer for f in frames])
        except MessageError:
            return
        band = head.get("band")
        if (head.get("ok") and head.get("job") == job_id
                and isinstance(head.get("arrays"), dict)
                and isinstance(band, int) and not isinstance(band, bool) and 0 <= band < bands):
            stats = head.get("stats")
            got.setdefault(band, {**head["arrays"], "_stats": stats if isinstance(stats, dict)
                                  else {}})

    def close(self) -> None:
        """Close the socket (LINGER 0)."""
        self.sock.close(0)


@dataclass
class Flight:
    """A whole-frame job sent through the broker and not answered yet."""

    job: dict[str, Any]
    arrays: list[np.ndarray]
    meta: Any
    sent_at: float
    attempt: int = 0


class FramePipe:
    """Whole-frame jobs through the broker, several in flight (pipelining).

    Each job renders one update (all hololines) for its own rendezvous; with N
    workers the render thread keeps up to N in flight, so N renders overlap instead
    of N bands of one render each repeating the whole-scene work.  Replies are
    matched on ``(job, attempt)``; a reply to an attempt that was given up on is
    dropped (its rendezvous was re-aimed, so the late render is never grafted).

    Parameters
    ----------
    context : zmq.Context
    address : str
        The broker's frontend.
    timeout_s : float
        Deadline of one attempt; past it the job is handed back by :meth:`expired`.
    """

    def __init__(self, context: zmq.Context, address: str, timeout_s: float = 5.0) -> None:
        self.sock = context.socket(zmq.DEALER)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.connect(address)
        self.timeout_s = timeout_s
        self.flights: dict[int, Flight] = {}
        self.max_in_flight = 0

    def send(
        self, job: dict[str, Any], arrays: list[np.ndarray], meta: Any, attempt: int = 0
    ) -> None:
        """Send one job (``job["job"]`` is its id) for all rows; ``meta`` comes back with it."""
        head = {**job, "band": 0, "attempt": attempt}
        wire.send(self.sock, [b"", *wire.encode(head, arrays)], 1000)
        self.flights[int(job["job"])] = Flight(job, arrays, meta, time.monotonic(), attempt)
        self.max_in_flight = max(self.max_in_flight, len(self.flights))

    def poll(self, timeout_ms: int) -> list[tuple[Flight, dict[str, Any]]]:
        """Replies that arrived within ``timeout_ms``: (its flight, reply header with arrays)."""
        done = []
        wait = timeout_ms
        while self.sock.poll(wait):
            wait = 0
            frames = self.sock.recv_multipart(copy=False)
            try:
                head = protocol.parse_reply([f.buffer for f in frames])
            except MessageError:  # a garbled reply counts as no reply
                continue
            flight = self.flights.get(head.get("job")) if isinstance(head.get("job"), int) else None
            if flight is None or head.get("attempt") != flight.attempt:
                continue  # a reply to an attempt already given up on
            del self.flights[head["job"]]
            done.append((flight, head))
        return done

    def expired(self) -> list[Flight]:
        """Jobs past their deadline (removed: the caller resends or gives up)."""
        now = time.monotonic()
        late = [f for f in self.flights.values() if now - f.sent_at > self.timeout_s]
        for f in late:
            del self.flights[int(f.job["job"])]
        return late

    def close(self) -> None:
        """Close the socket (LINGER 0)."""
        self.sock.close(0)


def split_rows(rows: int, n: int) -> list[tuple[int, int]]:
    """``n`` bands of hololines covering ``rows`` (nearly equal, none empty)."""
    n = max(1, min(n, rows))
    edges = np.linspace(0, rows, n + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]
