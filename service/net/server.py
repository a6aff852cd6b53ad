"""The render service: sockets, threads and shutdown (``docs/service.md``).

Three loops share one :class:`~service.net.state.ServiceState`:

* the **control loop** (the caller's thread, :meth:`Service.run`) answers requests
  on the ROUTER socket with a handler per message type (:mod:`.handlers`,
  ``docs/protocol.md``);
* the **render thread** (:mod:`.scheduler`) renders the scene as fast as it can (or
  at most ``max_update_hz``) for a rendezvous a little in the future, in process or
  through the LRU broker to worker processes (whole frames, one in flight per worker,
  each for its own rendezvous; or bands of hololines), and builds the galpixmap; with
  a broker but no worker connected to it, it renders in process;
* the **refresh thread** (:mod:`.refresh`) ticks at the refresh rate on an absolute
  schedule, hands finished updates to the Galilean stage, takes the viewer's pose from
  the devices' stream, refreshes and publishes the frame.  It never waits for a
  render; a render that misses its rendezvous is counted (``incomplete_updates``).
"""

from __future__ import annotations

import os
import queue
import sys
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import zmq

from service.base.errors import MessageError, SettingsError
from service.engine.engine import Engine
from service.net import protocol, wire
from service.net.broker import Broker
from service.net.curve_keys import curve_server, is_local, start_authenticator
from service.net.forkserver import ForkServer
from service.net.frame_stream import FrameStream
from service.net.handlers import HANDLERS, error_code, load_builtin
from service.net.refresh import ServiceRefresh
from service.net.scheduler import WorkerScheduler
from service.net.state import (
    DEFAULT_WORKER_ADDRESS,
    WHILE_WARMING,
    ReplyCache,
    ServiceConfig,
    service_state,
)
from service.net.supervisor import Supervisor

if TYPE_CHECKING:  # handed in by the command; the server never imports the warm-up
    from service.readiness import Warmup


class Service:
    """The render service; see the module notes.

    Parameters
    ----------
    config : ServiceConfig
    log : callable, optional
        Called with one line of text per warm-up step (the CLI prints them).
    warmup : service.readiness.Warmup, optional
        The readiness to serve under: the command hands it in (``holo-service``
        warms up unless ``--no-warmup``); None (library use, tests): ready at once,
        kernels compile when first used.  The server never imports the warm-up.

    Raises
    ------
    SettingsError
        A bad setting (:func:`~service.net.state.check_config`), before any socket is bound.
    """

    def __init__(self, config: ServiceConfig, log: Callable[[str], None] | None = None,
                 warmup: Warmup | None = None) -> None:
        self.st = service_state(config)
        self.config = config
        self.log = log or (lambda line: None)
        # two I/O threads: the frame PUB gets one of its own (FrameStream sets the
        # affinity), so a worker's multi-MB reply never queues a frame behind it
        self.ctx = self.st.ctx = zmq.Context(io_threads=max(1, config.io_threads))
        self._waiting: list[tuple[list[bytes], Any, float, tuple]] = []
        self.replies = ReplyCache()
        self._threads: list[threading.Thread] = []
        #: the render and refresh threads (started once the warm-up is over)
        self.engine: Engine | None = None
        self._auth = None
        self._open_sockets()
        self.st.warmup = warmup
        if self.st.warmup is None:
            self._prepare()

    @property
    def session(self) -> str:
        """The session id of this run (in ``hello`` and every frame)."""
        return self.st.session

    @property
    def stream(self) -> FrameStream:
        """The frame stream (PUB)."""
        return self.st.stream

    # ---------------------------------------------------------------- set-up
    def _secure(self, address: str) -> Callable[[zmq.Socket], None] | None:
        keys = self.config.curve_keys
        if keys is None:
            if not is_local(address):
                raise SettingsError(
                    f"binding {address} (not loopback) needs --curve-keys DIR "
                    "(make them with holo-service-keys DIR)"
                )
            return None
        if self._auth is None:
            self._auth = start_authenticator(self.ctx, keys)
        return curve_server(keys)

    def _open_sockets(self) -> None:
        c = self.config
        self.router = self.ctx.socket(zmq.ROUTER)
        self.router.setsockopt(zmq.LINGER, 0)
        self.router.setsockopt(zmq.MAXMSGSIZE, self.st.limits.max_message_bytes)
        self.router.setsockopt(zmq.ROUTER_MANDATORY, 1)
        self.router.setsockopt(zmq.SNDTIMEO, 1000)
        self.router.setsockopt(zmq.HEARTBEAT_IVL, int(protocol.HEARTBEAT_S * 1000))
        self.router.setsockopt(
            zmq.HEARTBEAT_TIMEOUT, int(protocol.HEARTBEAT_S * protocol.HEARTBEAT_LIVENESS * 1000)
        )
        secure = self._secure(c.control)
        if secure:
            secure(self.router)
        try:
            self.router.bind(c.control)
            self.control_address = self.router.getsockopt_string(zmq.LAST_ENDPOINT)
            self.st.stream = FrameStream(self.ctx, c.frames, self.session, self._secure(c.frames))
            if c.workers > 0 or c.worker_address is not None:
                self._start_broker()
        except (zmq.ZMQError, SettingsError):
            self.close()
            raise

    def _start_broker(self) -> None:
        """Bind the broker's backend; start it and the workers' supervisor (no worker yet)."""
        c = self.config
        address = c.worker_address or DEFAULT_WORKER_ADDRESS
        self.st.broker = Broker(
            self.ctx,
            "inproc://holo-broker",
            address,
            self._secure(address),
            job_timeout_s=c.render_timeout_s,
        )
        env = _worker_env(c.workers)
        forks = ForkServer(env, self.log) if c.workers > 0 else None
        if forks is not None:
            forks.start()  # imports the worker's modules during the warm-up
        self.st.supervisor = Supervisor(
            self.st.broker, self._worker_command(), env, self.log, forks=forks
        )
        for name, target in (("broker", self.st.broker.run), ("supervisor",
                                                                self.st.supervisor.run)):
            t = threading.Thread(target=target, name=name, daemon=True)
            t.start()
            self._threads.append(t)

    def _worker_command(self) -> list[str]:
        """A local worker's command line (it connects to the broker's backend)."""
        cmd = [
            sys.executable,
            "-m",
            "service.net.worker",
            "--connect",
            self.st.broker.backend_address,
            "--warm-up",
            "--parent",
            str(_pid()),
        ]
        if self.config.curve_keys:
            cmd += ["--curve-keys", str(self.config.curve_keys)]
        return cmd

    def _start_workers(self) -> None:
        """Start ``config.workers`` local workers (after the warm-up: they load its cache)."""
        sup = self.st.supervisor
        if sup is None or self.config.workers <= 0 or sup.slots:
            return
        sup.start(self.config.workers)

    def _prepare(self) -> None:
        """What needs the kernels: the ``--scene`` and the local workers."""
        if self.config.scene:
            self.st.state.scene = load_builtin(self.config.scene)
            self.st.state.scene_t = time.monotonic()
            self.st.state.scene_load += 1
        self._start_workers()

    # ------------------------------------------------------------- control
    @property
    def ready(self) -> bool:
        """Whether the warm-up is over (always, without one)."""
        return self.st.ready

    def status(self) -> dict[str, Any]:
        """``status`` and, while warming up, ``warmup`` (``docs/protocol.md`` 1.8)."""
        return self.st.status()

    def run(self, deadline_s: float | None = None) -> None:
        """Serve until ``shutdown`` (or ``deadline_s``); starts and joins the threads.

        With a warm-up the control loop first answers "warming up" and sends the
        heartbeats itself until the kernels are ready, then starts the workers, the
        render and the refresh threads.
        """
        end = None if deadline_s is None else time.monotonic() + deadline_s
        try:
            if self.st.warmup is not None:
                self._warm(end)
            if self.st.stop.is_set() or (end is not None and time.monotonic() >= end):
                return
            self.engine = Engine(self.st, WorkerScheduler(self.st, self.log),
                                 ServiceRefresh(self.st))
            self.engine.start()
            self.stream.extra = {"status": "ready"}
            self._serve(end)
        finally:
            self.close()

    def _warm(self, end: float | None) -> None:
        """Answer requests and send heartbeats until the warm-up is over, then prepare."""
        self.st.warmup.start()
        while not self.st.stop.is_set() and (end is None or time.monotonic() < end):
            if self.st.warmup.ready.wait(0):
                break
            self.stream.extra = self.status()
            self.stream.heartbeat()
            if self.st.warmup.phase == "loading":
                self._start_workers()  # the cache is full: they load it while this does
            if self.router.poll(20):
                self._serve_one(self.router.recv_multipart(copy=False))
            self._forget_clients()
        if self.st.warmup.ready.is_set() and not self.st.stop.is_set():
            self.log(f"ready after {self.st.warmup.summary()}")
            self._prepare()

    def _serve(self, end: float | None) -> None:
        """The control loop of a ready service."""
        while not self.st.stop.is_set() and (end is None or time.monotonic() < end):
            if self.router.poll(5):
                self._serve_one(self.router.recv_multipart(copy=False))
            self._answer_renders()
            self._forget_clients()

    def _serve_one(self, frames: list[zmq.Frame]) -> None:
        envelope, body = protocol.split_envelope([f.buffer for f in frames])
        self.st.counters.n["requests"] += 1
        self.st.clients[envelope[0]] = time.monotonic()
        rid = mtype = None
        key = None
        try:
            req = protocol.parse_request(body, self.st.limits)
            rid, mtype = req.get("id"), req["type"]
            if not self.ready and mtype not in WHILE_WARMING:  # never cached: retry later
                self._send(self._warming_reply(envelope, rid, mtype))
                return
            key = self.replies.key(envelope, req)
            cached = self.replies.get(key)
            if cached is not None:  # a resend (Lazy Pirate): the same answer, not applied twice
                self.st.counters.n["resends_answered"] += 1
                self._send([*envelope, *cached])
                return
            out = HANDLERS[mtype](self.st, req)
            if out is None:  # answered later (render)
                self._waiting.append(
                    (envelope, rid, time.monotonic(), (time.monotonic_ns(), self.st.scene_mark()))
                )
                return
            frames_out = protocol.reply(envelope, rid, mtype, *out)
        except MessageError as exc:
            partial = getattr(exc, "partial", {"id": rid, "type": mtype})
            frames_out = self._error(
                envelope, partial["id"], partial["type"], exc.code, exc.message
            )
        except Exception as exc:  # noqa: BLE001 - every request gets a reply
            code = error_code(exc)
            frames_out = self._error(envelope, rid, mtype, code, f"{type(exc).__name__}: {exc}")
        if key is not None:
            self.replies.put(key, frames_out[len(envelope) :])
        self._send(frames_out)

    def _warming_reply(self, envelope: list[bytes], rid: Any, mtype: str) -> list[Any]:
        """The ``warming_up`` error reply, with the progress (``docs/protocol.md`` 1.8)."""
        self.st.counters.n["errors"] += 1
        w = self.st.warmup.as_dict()
        message = (
            f"warming up: {w['phase']} {w['done']}/{w['total']}; "
            "retry when hello, ping or a heartbeat says status ready"
        )
        return protocol.error_reply(envelope, rid, mtype, "warming_up", message, self.status())

    def _error(
        self, envelope: list[bytes], rid: Any, mtype: str | None, code: str, message: str
    ) -> list[Any]:
        self.st.counters.n["errors"] += 1
        return protocol.error_reply(envelope, rid, mtype, code, message)

    def _send(self, frames: list[Any]) -> None:
        try:
            wire.send(self.router, frames, 1000)
        except zmq.ZMQError:
            pass  # the client is gone (ROUTER_MANDATORY); nothing to answer

    def _forget_clients(self) -> None:
        limit = protocol.HEARTBEAT_S * protocol.HEARTBEAT_LIVENESS
        now = time.monotonic()
        for ident in [i for i, t in self.st.clients.items() if now - t > limit]:
            del self.st.clients[ident]

    # ------------------------------------------------------- render replies
    def _answer_renders(self) -> None:
        """Answer waiting ``render`` requests with the newest finished render."""
        done = None
        while True:
            try:
                done = self.st.render_results.get_nowait()
            except queue.Empty:
                break
            # a render started after the request, with its settings and scene, answers it
            fresh = [w for w in self._waiting if done[1] >= w[3][0] and done[3] >= w[3][1]]
            self._waiting = [w for w in self._waiting if w not in fresh]
            for envelope, rid, _t, _mark in fresh:
                self._send(_render_reply(envelope, rid, done))
        limit = self.config.render_timeout_s * 4 + 5
        now = time.monotonic()
        for item in [w for w in self._waiting if now - w[2] > limit]:
            self._waiting.remove(item)
            self._send(
                self._error(
                    item[0], item[1], "render", "render_failed", "no render finished in time"
                )
            )

    # ------------------------------------------------------------- closing
    @property
    def stop_event(self) -> threading.Event:
        """Set it (from any thread) to make :meth:`run` return and close the service."""
        return self.st.stop

    def close(self) -> None:
        """Stop the threads and workers; close every socket (LINGER 0).

        Threads get 5 s each to finish; the context is then destroyed (every socket
        still open closed with LINGER 0), so closing never waits forever.
        """
        self.st.stop.set()
        if self.st.warmup is not None:
            self.st.warmup.stop()
        if self.st.broker is not None:
            self.st.broker.stop()
        if self.st.supervisor is not None:
            self.st.supervisor.stop()
        if self.engine is not None:
            self.engine.stop()
        self.st.chains.close()  # a build the load started (the engine's stop ends it too)
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(5.0)
        if self.st.supervisor is not None:
            self.st.supervisor.close()
        for sock in (
            getattr(self, "router", None),
            getattr(getattr(self, "stream", None), "sock", None),
        ):
            if sock is not None:
                sock.close(0)
        if self._auth is not None:
            self._auth.stop()
        self.ctx.destroy(linger=0)


# ------------------------------------------------------------------ helpers
def _pid() -> int:

    return os.getpid()


def _worker_env(workers: int) -> dict[str, str]:
    """Environment of local workers: their numba thread pools share the cores.

    Each worker renders whole frames with parallel kernels; N workers with a pool
    of every core each would oversubscribe the machine N times, so each gets
    ``cores // N`` threads (at least one) unless ``NUMBA_NUM_THREADS`` is set.
    """
    env = dict(os.environ)
    if "NUMBA_NUM_THREADS" not in env and workers > 0:
        env["NUMBA_NUM_THREADS"] = str(max(1, (os.cpu_count() or 1) // workers))
    return env


def _render_reply(envelope: list[bytes], rid: Any, done: tuple) -> list[Any]:
    render_id, t0, frame, _mark, stats = done
    return protocol.reply(
        envelope,
        rid,
        "render",
        {"render_id": render_id, "t_ns": t0, "stats": stats},
        [frame.colour, frame.depth],
        ["colour", "depth"],
    )
