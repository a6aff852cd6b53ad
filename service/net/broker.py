"""Least-recently-used broker between the service's render thread and render workers.

The ZeroMQ guide's load-balancing broker: a ROUTER frontend (the render thread's
DEALER, ``inproc://`` inside the service) and a ROUTER backend (workers' DEALERs,
``tcp://``, on this machine or others).  A worker announces itself with ``READY``;
each job goes to the worker idle the longest; its reply makes it ready again.

The broker also tells the living from the dead (``docs/service.md``, "Supervised
workers").  Workers repeat ``READY`` every worker heartbeat while idle and ``BUSY``
while they render; one silent for three heartbeats, or holding a job past the job
timeout, is **dead at once**: it leaves the books, the job it held comes back to
its requester as a ``lost`` reply (``{"job", "band", "attempt", "ok": false,
"lost": true, "error"}``) so the requester resends it now rather than at its
deadline, and its pid and the reason go to :meth:`Broker.take_deaths` (the
:mod:`~service.net.supervisor` kills and replaces a local one).  A worker of an
older version (no ``heartbeat_s`` in its ``READY``) is judged by its idle ``READY``
every :data:`~service.net.protocol.HEARTBEAT_S` and by the job timeout only.
``ROUTER_MANDATORY`` makes a send to a vanished worker an error, so the broker
drops it and tries the next one.
"""

from __future__ import annotations

import json
import math
import queue
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import zmq

from service.base.errors import MessageError
from service.net import protocol, wire
from service.net.worker import BUSY, READY


@dataclass
class Book:
    """What the broker knows of one live worker."""

    pid: int | None
    #: when it was last heard from (any message), monotonic seconds
    seen: float
    #: its heartbeat while busy (``READY``'s ``heartbeat_s``); None: an older worker
    heartbeat_s: float | None = None
    #: when it was given the job it holds (None: idle)
    busy_since: float | None = None
    #: (requester identity, job header frame) of the job it holds
    holding: tuple[bytes, Any] | None = None
    #: jobs it answered
    jobs: int = 0

    def silent_limit_s(self) -> float | None:
        """How long it may be silent before it is dead (None: no limit while busy)."""
        if self.heartbeat_s is not None:
            return self.heartbeat_s * protocol.HEARTBEAT_LIVENESS
        if self.busy_since is None:
            return protocol.HEARTBEAT_S * protocol.HEARTBEAT_LIVENESS
        return None


class Broker:
    """The LRU broker (run it on a thread with :meth:`run`).

    Parameters
    ----------
    context : zmq.Context
    frontend, backend : str
        Bind addresses (requesters, workers).
    secure : callable, optional
        CurveZMQ server setup applied to the backend before binding.
    job_timeout_s : float
        A worker holding a job this long is dead (stuck), whatever its heartbeats say.
    """

    def __init__(
        self,
        context: zmq.Context,
        frontend: str,
        backend: str,
        secure: Any = None,
        job_timeout_s: float = 5.0,
    ) -> None:
        self.job_timeout_s = job_timeout_s
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
        self.ready: OrderedDict[bytes, None] = OrderedDict()  # idle workers, LRU first
        self.books: dict[bytes, Book] = {}  # every live worker
        # ready and books change on the broker's thread and are read by info() on the
        # service's: a worker moved between states is never seen in neither or both
        self._books = threading.Lock()
        self._forget: queue.SimpleQueue[int] = queue.SimpleQueue()
        self._deaths: queue.SimpleQueue[tuple[int | None, str]] = queue.SimpleQueue()
        self.dispatched = 0  # jobs sent to a worker
        self.answered = 0  # replies passed on to their requester
        self.lost = 0  # jobs held by a worker found dead (handed back, or dropped: no requester)
        self.refused = 0  # jobs handed back at once: no live worker
        self.dropped = 0  # messages whose requester was gone
        #: silences forgiven: a local worker past its silence limit still using the CPU
        self.starved = 0
        #: ``mark(pid)`` / ``working(pid)`` (:class:`service.net.supervisor.CpuWatch`), or
        #: None: every silence past the limit is a death
        self.watch: Any = None
        self._stop = threading.Event()

    def stop(self) -> None:
        """Ask :meth:`run` to return."""
        self._stop.set()

    def live(self) -> int:
        """Live workers (idle or busy)."""
        return len(self.books)

    def idle(self) -> int:
        """Live workers holding no job (one could take a job at once); any thread."""
        with self._books:
            return sum(b.busy_since is None for b in self.books.values())

    def forget(self, pid: int) -> None:
        """Drop the worker of process ``pid`` (it exited); any thread.  Not a death report."""
        self._forget.put(pid)

    def take_deaths(self) -> list[tuple[int | None, str]]:
        """Workers found dead since the last call: (pid, why), oldest first; any thread."""
        out = []
        while True:
            try:
                out.append(self._deaths.get_nowait())
            except queue.Empty:
                return out

    def info(self) -> dict[str, Any]:
        """Worker counts and each live worker (for the service's stats)."""
        now = time.monotonic()
        with self._books:  # one snapshot: dispatched = answered + lost + busy in it
            workers = [
                {"pid": b.pid, "alive": True, "busy": b.busy_since is not None, "jobs": b.jobs,
                 "last_seen_s": round(now - b.seen, 3)}
                for b in self.books.values()
            ]
            counts = {"dispatched": self.dispatched, "answered": self.answered,
                      "lost": self.lost, "refused": self.refused, "dropped": self.dropped}
        return {
            "ready": sum(not w["busy"] for w in workers),
            "busy": sum(w["busy"] for w in workers),
            **counts,
            "starved": self.starved,
            "workers": workers,
        }

    def run(self) -> None:
        """Route until :meth:`stop`; closes both sockets on return."""
        poller = zmq.Poller()
        poller.register(self.back, zmq.POLLIN)
        poller.register(self.front, zmq.POLLIN)
        try:
            while not self._stop.is_set():
                events = dict(poller.poll(20))
                if self.back in events:
                    self._from_worker(self.back.recv_multipart(copy=False))
                if self.front in events and (self.ready or not self.books):
                    self._to_worker(self.front.recv_multipart(copy=False))
                self._expire()
        finally:
            self.front.close(0)
            self.back.close(0)

    def _from_worker(self, frames: list[zmq.Frame]) -> None:
        worker = bytes(frames[0].buffer)
        kind = bytes(frames[2].buffer) if len(frames) >= 3 else b""
        now = time.monotonic()
        with self._books:
            book = self.books.get(worker)
            if book is not None:
                book.seen = now
                if self.watch is not None and book.pid is not None:
                    self.watch.mark(book.pid)
            if kind == BUSY or (book is None and kind != READY):
                return  # a heartbeat; or a late reply of a worker already dropped
            if kind == READY and book is not None and book.busy_since is not None:
                return  # sent before the job reached it: a heartbeat, the job is still held
            if kind == READY:
                book = book or self._admit(worker, frames[3:], now)
            if book.busy_since is not None and kind != READY:
                book.jobs += 1
            book.busy_since, book.holding = None, None
            self.ready[worker] = None
            self.ready.move_to_end(worker)
            # counted with the busy flag, under one lock: info() never sees it in neither
            passing = kind != READY and len(frames) >= 5
            self.answered += passing
        if passing:
            try:
                self.front.send_multipart(frames[2:], copy=False)
            except zmq.ZMQError:
                with self._books:  # the requester is gone; nothing to do
                    self.answered -= 1
                    self.dropped += 1

    def _admit(self, worker: bytes, rest: list[zmq.Frame], now: float) -> Book:
        """A new worker's book from its ``READY`` info (``{"pid", "heartbeat_s"}``)."""
        try:
            info = json.loads(bytes(rest[0].buffer))
        except (IndexError, ValueError):
            info = {}
        info = info if isinstance(info, dict) else {}
        pid, beat = info.get("pid"), info.get("heartbeat_s")
        book = Book(
            pid if isinstance(pid, int) and not isinstance(pid, bool) else None,
            now,
            float(beat) if isinstance(beat, int | float) and 0 < beat <= 60 else None,
        )
        self.books[worker] = book
        if self.watch is not None and book.pid is not None:
            self.watch.mark(book.pid)
        return book

    def _to_worker(self, frames: list[zmq.Frame]) -> None:
        while True:
            with self._books:  # busy from the moment it is chosen
                if not self.ready:
                    break
                worker, _ = self.ready.popitem(last=False)
                book = self.books[worker]
                book.busy_since = time.monotonic()
                book.holding = (bytes(frames[0].buffer), frames[2] if len(frames) > 2 else None)
                self.dispatched += 1
            try:
                self.back.send_multipart([worker, b"", *frames], copy=False)
            except zmq.ZMQError:  # not sent: the next worker gets it
                self._dead(worker, "gone (its connection closed)", unsent=True)
                continue  # vanished: try the next one
            return
        # no live worker took it: lost now, so the requester renders it in process
        holding = (bytes(frames[0].buffer), frames[2] if len(frames) > 2 else None)
        self.refused += self._lost(Book(None, 0.0, holding=holding), "no live worker")

    def _expire(self) -> None:
        """Drop workers forgotten, silent past their limit, or past the job timeout."""
        gone: set[int] = set()
        while True:
            try:
                gone.add(self._forget.get_nowait())
            except queue.Empty:
                break
        now = time.monotonic()
        dead: list[tuple[bytes, str, bool]] = []
        silent: list[tuple[bytes, Book]] = []
        with self._books:
            for w, b in self.books.items():
                limit = b.silent_limit_s()
                if b.pid in gone:
                    dead.append((w, "its process ended", False))
                elif b.busy_since is not None and now - b.busy_since > self.job_timeout_s:
                    dead.append((w, f"a job past its {self.job_timeout_s:g} s timeout", True))
                elif limit is not None and now - b.seen > limit:
                    silent.append((w, b))
        for w, b in silent:  # the watch asks the supervisor: never under self._books
            if self._starved(b):
                b.seen = now  # at work, only starved of the CPU: another window
            else:
                dead.append((w, f"silent for {now - b.seen:.1f} s", True))
        for w, why, report in dead:
            self._dead(w, why, report)

    def _starved(self, book: Book) -> bool:
        """Whether a silent worker is a local process still at work (not stopped or hung).

        On a machine busy with other programs a worker's heartbeat waits behind its
        render (a compiled kernel holds the GIL) and behind the CPU; its process still
        uses the CPU, where a stopped or hung one does not.  A worker found working is
        given another silence window; one past the job timeout is dead all the same.
        """
        if self.watch is None or book.pid is None or not self.watch.working(book.pid):
            return False
        self.starved += 1
        return True

    def _dead(self, worker: bytes, why: str, report: bool = True, unsent: bool = False) -> None:
        """Drop a worker; its job back to its requester as ``lost``; report it (pid, why).

        ``unsent``: its job never reached it (not dispatched after all; the caller
        offers it to the next worker).  Counts change with the books, under one lock.
        """
        with self._books:
            book = self.books.pop(worker, None)
            self.ready.pop(worker, None)
            if book is not None and unsent:
                book.holding = None
                self.dispatched -= 1
            held = book is not None and book.holding is not None
            self.lost += held
        if book is None:
            return
        if report:
            self._deaths.put((book.pid, why))
        if held:
            self._lost(book, why)

    def _lost(self, book: Book, why: str) -> bool:
        """Tell the requester of the job ``book`` held that it is lost (resend it now).

        Returns whether the notice went out (False: a garbled job, or its requester gone).
        """
        requester, header = book.holding
        try:
            job = json.loads(bytes(header.buffer)) if header is not None else {}
        except ValueError:
            return False
        if not isinstance(job, dict):
            return False
        who = "" if book.pid is None else f"worker {book.pid}: "
        head = {"job": job.get("job"), "band": job.get("band"), "attempt": job.get("attempt"),
                "ok": False, "lost": True, "error": who + why}
        try:
            self.front.send_multipart([requester, b"", *wire.encode(head, [])])
        except zmq.ZMQError:
            self.dropped += 1  # the requester is gone
            return False
        return True


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
                lost = self._take(self.sock.recv_multipart(copy=False), job["job"], len(bands),
                                  got)
                if lost is not None and lost not in got:
                    sent_at[lost] = -math.inf  # its worker died: resend it now
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
    def _take(frames: list[zmq.Frame], job_id: int, bands: int, got: dict) -> int | None:
        """Keep a worker's reply for one of the ``bands`` bands of job ``job_id``.

        A reply that is garbled, failed, for another job, or names no band of this
        one (a remote worker of another version, say) counts as no reply: its band
        is resent when its deadline passes.  The first good reply of a band wins.

        Returns
        -------
        int or None
            The band of a ``lost`` notice (its worker died: resend it now), else None.
        """
        try:
            head = protocol.parse_reply([f.buffer for f in frames])
        except MessageError:
            return None
        band = head.get("band")
        if (head.get("job") != job_id or not isinstance(band, int) or isinstance(band, bool)
                or not 0 <= band < bands):
            return None
        if head.get("lost") is True:
            return band
        if head.get("ok") and isinstance(head.get("arrays"), dict):
            stats = head.get("stats")
            got.setdefault(band, {**head["arrays"], "_stats": stats if isinstance(stats, dict)
                                  else {}})
        return None

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
            if head.get("lost") is True:  # its worker died: resend it now
                flight.sent_at = -math.inf
                continue
            del self.flights[head["job"]]
            done.append((flight, head))
        return done

    def expired(self) -> list[Flight]:
        """Jobs past their deadline or lost with their worker (removed: resend or give up)."""
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
