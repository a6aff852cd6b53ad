"""Supervised render workers: a dead or stuck worker is replaced (``docs/service.md``).

The service's local workers run in slots, one process each, every one the leader
of its own process group.  A thread (:meth:`Supervisor.run`) looks every
:data:`TICK_S` at two things:

* the **broker's death reports** (:meth:`~service.net.broker.Broker.take_deaths`: a
  worker silent for three worker heartbeats, or holding a job past the job
  timeout).  A local one is **killed with its process group** (it may be stopped or
  hung: SIGKILL, which also ends its level-of-detail builds), then replaced; a
  remote one is only counted (the broker has dropped it; it comes back by saying
  ``READY`` again).
* **each slot's process**: one that exited is dropped from the broker at once
  (:meth:`~service.net.broker.Broker.forget`: its job comes back ``lost`` and is
  resent) and started again.

A worker that had said ``READY`` is restarted at once, unless it died within
:data:`QUICK_S` of saying it twice in a row or more (a worker that crashes on every
job): then after a back-off (0.5, 1, 2 ... s, at most :data:`MAX_BACKOFF_S`), never
given up (renders go on in process meanwhile).  One that dies before it ever said
``READY`` failed to start, and so did one that has not said it :data:`STARTUP_S`
after it started (hung: it is killed with its process group): it is restarted after
a back-off (0.5, 1, 2, 4 s), and after :data:`MAX_FAILED_STARTS` failures in a row
the slot is given up with one line in ``stats`` (``worker_error``) and on stderr.
A worker killed before ``READY`` by a signal from outside (:data:`OUTSIDE_SIGNALS`:
an operator, the OOM killer, the chaos benchmark) did not fail to start: it is
restarted as one that died soon after ``READY`` (back-off only if it keeps happening,
never given up).
Every death counts in ``worker_deaths``, every start after the first in
``worker_restarts``.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from service.net.broker import Broker
from service.net.forkserver import ForkedProc, ForkServer

#: seconds between looks at the processes and the broker's reports
TICK_S = 0.05
#: failed starts in a row (deaths before ``READY``) after which a slot is given up
MAX_FAILED_STARTS = 5
#: the back-off after the first failed start, doubled after each further one
BACKOFF_S = 0.5
#: seconds a started worker has to say ``READY`` (its kernels load or compile first:
#: a cold cache on a busy 2-core machine took 100 s) before it is killed as hung
STARTUP_S = 300.0
#: a worker that dies this soon after ``READY`` counts as a quick death
QUICK_S = 10.0
#: the longest back-off between restarts of a worker that keeps dying quickly
MAX_BACKOFF_S = 30.0
#: seconds a worker gets to end after SIGTERM when the service closes
CLOSE_S = 3.0
#: signals a worker does not send itself (a crash raises SIGSEGV, SIGABRT, SIGBUS ...):
#: a death by one of them before ``READY`` is not a failed start
OUTSIDE_SIGNALS = frozenset({signal.SIGKILL, signal.SIGTERM, signal.SIGINT, signal.SIGHUP})


@dataclass
class Slot:
    """One local worker: its process now, and its history."""

    index: int
    proc: subprocess.Popen | ForkedProc | None = None
    #: processes started
    starts: int = 0
    #: deaths before ``READY`` in a row
    failed_starts: int = 0
    #: the process said ``READY`` (the broker knew it)
    ready: bool = False
    #: when the current process started, and when it said ``READY`` (monotonic s)
    started_at: float = 0.0
    ready_at: float = 0.0
    #: deaths within :data:`QUICK_S` of ``READY`` in a row
    quick_deaths: int = 0
    #: the current process's death is counted (it was found dead or killed)
    dead: bool = False
    #: when to start the next process (monotonic s; None: none due)
    start_at: float | None = 0.0
    #: why the slot was given up ("" while it is not)
    error: str = ""
    #: what the last process died of
    last_death: str = ""

    @property
    def pid(self) -> int | None:
        """The current process's pid (None between processes)."""
        return None if self.proc is None else self.proc.pid

    @property
    def restarts(self) -> int:
        """Processes started after the first."""
        return max(0, self.starts - 1)


@dataclass
class Supervisor:
    """Starts, watches and replaces the service's local workers (see the module notes).

    Parameters
    ----------
    broker : Broker
        The broker the workers connect to.
    command : list of str
        A worker's command line.
    env : dict
        Its environment.
    log : callable
        One line of text per death, restart and give-up (the service's log).
    """

    broker: Broker
    command: list[str]
    env: dict[str, str]
    log: Callable[[str], None] = lambda line: None
    #: seconds a worker has to say ``READY`` (:data:`STARTUP_S`)
    startup_s: float = STARTUP_S
    #: the fork server workers are forked from (None, or once it is gone: fresh processes)
    forks: ForkServer | None = None
    slots: list[Slot] = field(default_factory=list)
    deaths: int = 0
    restarts: int = 0
    #: every pid a slot ever ran (a report of one already counted is not a remote's)
    started: set[int] = field(default_factory=set)
    _stop: threading.Event = field(default_factory=threading.Event)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def start(self, n: int) -> None:
        """Add ``n`` slots and start their processes.

        With a fork server, once it is ready (or gone): ``pids()`` lists them on return.
        """
        if self.forks is not None:
            self.forks.wait_ready()
        with self._lock:
            self.slots += [Slot(len(self.slots) + i) for i in range(n)]
        self.tick()

    def run(self) -> None:
        """Watch until :meth:`stop` (the supervisor thread)."""
        while not self._stop.wait(TICK_S):
            self.tick()

    def stop(self) -> None:
        """Ask :meth:`run` to return."""
        self._stop.set()

    def tick(self) -> None:
        """Handle the broker's death reports, exited processes and due starts."""
        with self._lock:
            now = time.monotonic()
            for pid, why in self.broker.take_deaths():
                self._reported(pid, why, now)
            known = {w["pid"] for w in self.broker.info()["workers"]}
            for slot in self.slots:
                if slot.proc is not None and slot.pid in known and not slot.ready:
                    slot.ready, slot.ready_at, slot.failed_starts = True, now, 0
                self._check(slot, now)

    def _reported(self, pid: int | None, why: str, now: float) -> None:
        """The broker found worker ``pid`` dead: a local one is killed, a remote one counted."""
        slot = next((s for s in self.slots if s.proc is not None and s.pid == pid), None)
        if slot is None and pid in self.started:
            return  # a local worker whose exit was counted first
        if slot is None:
            self.deaths += 1
            self.log(f"worker {pid} (remote) dropped: {why}")
            return
        if slot.dead:
            return  # its exit was counted first
        self._died(slot, f"{why}; killed", now)
        _kill_group(slot.proc, signal.SIGKILL)

    def _check(self, slot: Slot, now: float) -> None:
        """Count a slot's exited process, reap it and start the next when due."""
        if (slot.proc is not None and not slot.ready and not slot.dead
                and now - slot.started_at > self.startup_s):
            self._died(slot, f"no READY {self.startup_s:g} s after it started; killed", now)
            _kill_group(slot.proc, signal.SIGKILL)  # hung at start-up: the group goes
        if slot.proc is not None and slot.proc.poll() is not None:
            if not slot.dead:
                code = slot.proc.returncode
                self._died(slot, _exit_text(code), now, outside=-code in OUTSIDE_SIGNALS)
                self.broker.forget(slot.proc.pid)
            slot.proc = None
        if slot.proc is None and slot.start_at is not None and now >= slot.start_at:
            self._spawn(slot)

    def _died(self, slot: Slot, why: str, now: float, outside: bool = False) -> None:
        """Count a death; plan the restart (at once, after a back-off, or never).

        ``outside``: killed by a signal from outside (:data:`OUTSIDE_SIGNALS`); before
        ``READY`` that is no failed start (it says nothing of whether the worker can
        start): it is restarted as one that died quickly after ``READY``.
        """
        self.deaths += 1
        slot.dead, slot.last_death = True, why
        if slot.ready or outside:
            since = slot.ready_at if slot.ready else slot.started_at
            slot.quick_deaths = slot.quick_deaths + 1 if now - since < QUICK_S else 0
            wait = (min(MAX_BACKOFF_S, BACKOFF_S * 2 ** (slot.quick_deaths - 2))
                    if slot.quick_deaths >= 2 else 0.0)
            slot.start_at = now + wait
            self.log(f"worker {slot.pid} died ({why}); restarting it"
                     + (f" in {wait:g} s (it died within {QUICK_S:g} s of starting work "
                        f"{slot.quick_deaths} times in a row)" if wait else ""))
            return
        slot.failed_starts += 1
        if slot.failed_starts >= MAX_FAILED_STARTS:
            slot.start_at = None
            slot.error = (f"worker {slot.index} given up: it died at start-up "
                          f"{slot.failed_starts} times in a row (last: {why})")
            self.log(slot.error)
            return
        wait = BACKOFF_S * 2 ** (slot.failed_starts - 1)
        slot.start_at = now + wait
        self.log(f"worker {slot.pid} died at start-up ({why}); restarting it in {wait:g} s")

    def _spawn(self, slot: Slot) -> None:
        """Start a slot's process (the leader of a process group of its own).

        Forked from the fork server while it works; not yet while it is starting
        (the next tick tries again); a fresh process without one or once it is gone.
        """
        slot.proc = None if self.forks is None else self.forks.spawn(self.command)
        if slot.proc is None and self.forks is not None and self.forks.state == "starting":
            return
        if slot.proc is None:
            slot.proc = subprocess.Popen(self.command, stdin=subprocess.DEVNULL, env=self.env,
                                         process_group=0)
        self.started.add(slot.proc.pid)
        slot.dead, slot.ready, slot.start_at = False, False, None
        slot.started_at = time.monotonic()
        self.restarts += slot.starts > 0
        slot.starts += 1

    def pids(self) -> list[int]:
        """Pids of the local workers running now (not found dead)."""
        with self._lock:
            return [s.pid for s in self.slots if s.proc is not None and not s.dead]

    def errors(self) -> list[str]:
        """Why slots were given up (one line each)."""
        with self._lock:
            return [s.error for s in self.slots if s.error]

    def info(self) -> dict[str, Any]:
        """The broker's :meth:`~Broker.info` with every worker's ``restarts`` and ``local``.

        Local workers not live (starting, or given up) are listed too, ``alive``
        false; ``last_seen_s`` is null for a worker never heard from.
        """
        out = self.broker.info()
        with self._lock:
            slots = {s.pid: s for s in self.slots if s.proc is not None and not s.dead}
            # a local worker found dead stays in the broker's books until its next loop
            out["workers"] = [w for w in out["workers"]
                              if w["pid"] in slots or w["pid"] not in self.started]
            out["ready"] = sum(not w["busy"] for w in out["workers"])
            out["busy"] = sum(w["busy"] for w in out["workers"])
            for w in out["workers"]:
                slot = slots.pop(w["pid"], None)
                w["restarts"], w["local"] = (slot.restarts, True) if slot else (0, False)
            out["workers"] += [
                {"pid": s.pid, "alive": False, "busy": False, "jobs": 0, "last_seen_s": None,
                 "restarts": s.restarts, "local": True}
                for s in slots.values()
            ]
        return out

    def close(self, timeout_s: float = CLOSE_S) -> None:
        """Stop watching; end every worker's process group (SIGTERM, then SIGKILL)."""
        self.stop()
        with self._lock:
            procs = [s.proc for s in self.slots if s.proc is not None]
            for p in procs:
                _kill_group(p, signal.SIGTERM)
                _kill_group(p, signal.SIGCONT)  # a stopped worker cannot act on SIGTERM
            end = time.monotonic() + timeout_s
            for p in procs:
                try:
                    p.wait(max(0.0, end - time.monotonic()))
                except subprocess.TimeoutExpired:
                    pass
                _kill_group(p, signal.SIGKILL)  # stragglers, and the group's children
                with contextlib.suppress(subprocess.TimeoutExpired):
                    p.wait(1.0)
            if self.forks is not None:
                self.forks.close()


def _kill_group(proc: subprocess.Popen | ForkedProc, signum: int) -> None:
    """Send ``signum`` to the process group ``proc`` leads (nothing if it is gone)."""
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signum)


def _exit_text(returncode: int) -> str:
    """``exit status 1`` or ``killed by SIGKILL``."""
    if returncode < 0:
        try:
            return f"killed by {signal.Signals(-returncode).name}"
        except ValueError:
            return f"killed by signal {-returncode}"
    return f"exit status {returncode}"
