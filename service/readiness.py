"""Warm-up of ``holo-service`` before it is ready: kernels compiled in a child process.

On an empty numba cache the kernels take tens of seconds to compile (minutes on a
slow machine).  Compiled lazily inside the service they held up its refresh loop
and even its heartbeats, so clients took it for dead.  Instead:

1. the service binds its sockets and answers requests at once, saying it is
   *warming up* (``docs/protocol.md`` 1.8); its control loop keeps sending
   heartbeats;
2. :class:`Warmup` runs ``python -m service.commands.holo_warmup --jsonl`` as a **child
   process** that fills numba's cache (``NUMBA_CACHE_DIR`` or ``__pycache__``) and
   reports one JSON line per warm-up job; the service's progress follows it
   (``compiling n/m``).  A child, not a thread: a compile holds the GIL for long
   stretches and cannot be interrupted, whereas a child is ended at once (SIGTERM)
   when the service is asked to stop, with no LLVM left half-way in this process;
3. when the child is done, the jobs a service's refresh loop can reach
   (:data:`service.warmup.SERVICE_JOBS`) run **in this process** (a thread), which
   now loads their kernels from the cache (``loading n/m``, about a second).  The
   other jobs' kernels (other render methods and light models, level of detail,
   the game's paths) are all in the cache too; they load where first used, in the
   render thread, which a refresh never waits on.  Should one of the service's jobs
   have to *compile* (the stamp below said warm but the cache was not), the other
   jobs run here too, before ready, as they did when every start loaded them all,
   so nothing compiles once the service is ready;
4. then the service is ready and starts its workers and loops.

**First frame first.**  On a cold cache the child of step 2 compiles only the jobs
of :data:`service.warmup.FIRST_FRAME_JOBS` (``--job`` for each: the render at the
starting settings, the Galilean refresh at its starting order, the autostereogram
encoding) and step 3 loads those, so the first frame waits for them alone.  Once ready, a second,
*background* child (``holo-warmup --jsonl --nice 10``, put on ``SCHED_IDLE``:
:func:`idle_priority`) compiles every other job on idle CPU time only while the
service runs, so a client's measurement of renders a second (``holo-game
--adapt``) need not wait for it; ``stats`` says how far it is and at what
priority (``compile``, :meth:`Warmup.background_dict`) and the log says when it
ends.  It
writes the warm stamp when it is done, so the next start skips both children.
Kernels that only make a refresh faster wait for it too: until the background
has cached :func:`service.galilean.scatter_bands.scatter_bands_plain`, the
Galilean stage runs :func:`~service.galilean.scatter_bands.scatter_bands` with its
still-galpixel bookkeeping off (the same map, bit for bit; it looks at numba's
cache index once a second, :func:`service.kernel_cache.kernel_ready`), so the
first frame does not wait for the plain kernel's 27 s of CPU.
numba's cache saves are locked between processes
(:func:`service.numba_patches.locked_cache_saves`): a render that needs a kernel
the background has not reached yet compiles it in its own process meanwhile.

If the child fails (it crashed, or ``service.commands.holo_warmup`` is missing), step 3
compiles in process instead (slower, but the service still gets ready and its
heartbeats go on).  :meth:`Warmup.as_dict` is what replies and heartbeats carry.

**A warm cache skips the child.**  Starting a Python process that imports numba and
loads 60 kernels costs seconds (14 s on a loaded 2-core machine), on every start.
So once a warm-up has found every kernel in the cache, it writes a small JSON stamp
beside the cache (:func:`service.kernel_cache.mark_warm`: ``holo-warmup-stamp.json``
in ``NUMBA_CACHE_DIR``, else in ``service/__pycache__``) naming the sources (every
``service`` module's size and mtime), numba's and Python's versions.  While the stamp
matches (:func:`service.kernel_cache.is_warm`), the service goes straight to step 3.
Any edit of a module, a new numba or an emptied cache voids it.  ``holo-warmup``
writes it too.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from typing import Any

from service.base.signals import end_process
from service.kernel_cache import is_warm, mark_warm
from service.warmup import FIRST_FRAME_JOBS, JOBS, SERVICE_JOBS, warm_up

#: The phases in order; ``ready`` and ``failed`` are final.
PHASES = ("starting", "compiling", "loading", "ready", "failed")
#: The child's command (``holo-warmup --jsonl``).
CHILD = (sys.executable, "-m", "service.commands.holo_warmup", "--jsonl")
#: Niceness of the background compile (every job the service did not need first),
#: where :data:`IDLE_POLICY` is not to be had.
BACKGROUND_NICE = 10
#: The background compile's scheduling policy: ``SCHED_IDLE`` (Linux) runs it only
#: on CPU time that no other program wants, so a client measuring the service's
#: renders a second (``holo-game --adapt``) measures the machine, not the compile.
#: Niceness 10 alone still left it about a tenth of a busy core (weight 110 against
#: 1024).  None where the OS has no such policy.
IDLE_POLICY: int | None = getattr(os, "SCHED_IDLE", None)


class _Abort(Exception):  # noqa: N818 -- control flow, never leaves this module
    """Raised from the progress callback to end the in-process warm-up early."""


class Warmup:
    """The warm-up of one service: a child process, then an in-process load.

    Parameters
    ----------
    log : callable, optional
        Called with one line of progress text per step (the CLI prints it).
    child : sequence of str
        The child's command line (default :data:`CHILD`).
    env : dict, optional
        The child's environment (default: this process's).
    trust_stamp : bool
        Skip the child when :func:`is_warm` (default); False always runs it.
    jobs : sequence of str, optional
        The warm-up jobs run in this process (step 3); default
        :data:`service.warmup.SERVICE_JOBS`.
    background : bool
        First frame first (default): on a cold cache the child compiles only
        ``first`` and, once ready, a background child compiles the rest.  False: the
        child compiles every job before ready.
    first : sequence of str, optional
        The jobs of a cold start's first phase; default
        :data:`service.warmup.FIRST_FRAME_JOBS` (``jobs`` when ``jobs`` is given).
    """

    def __init__(
        self,
        log: Callable[[str], None] | None = None,
        child: tuple[str, ...] = CHILD,
        env: dict[str, str] | None = None,
        trust_stamp: bool = True,
        jobs: tuple[str, ...] | None = None,
        background: bool = True,
        first: tuple[str, ...] | None = None,
    ) -> None:
        self.log = log or (lambda line: None)
        self.trust_stamp = trust_stamp
        self.jobs = SERVICE_JOBS if jobs is None else tuple(jobs)
        self.first = tuple(first) if first is not None else (
            FIRST_FRAME_JOBS if jobs is None else self.jobs)
        self.background = background and bool(self.first)
        self.child_cmd, self.env = tuple(child), env
        self.phase = "starting"
        self.done, self.total = 0, len(JOBS)
        self.step = ""
        self.note = ""
        self.t0 = time.monotonic()
        self.compile_s: float | None = None
        self.load_s: float | None = None
        self.child: subprocess.Popen | None = None
        self.bg: dict[str, Any] = {"phase": "none", "done": 0, "total": 0, "seconds": None}
        self.bg_child: subprocess.Popen | None = None
        self.ready = threading.Event()
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------ control
    def start(self) -> None:
        """Start the warm-up thread (it starts the child)."""
        self._thread = threading.Thread(target=self._run, name="warmup", daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        """End the child and its own children (SIGTERM, then SIGKILL) and the thread.

        The child runs in a process group of its own, so the second process
        ``holo-warmup`` starts on an empty cache ends with it even when the child
        must be killed.  Safe to call twice.
        """
        self._stop.set()
        with self._lock:
            children = (self.child, self.bg_child)
        for child in children:
            if child is not None:
                _end_group(child, 3.0)
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout_s)

    def as_dict(self) -> dict[str, Any]:
        """The progress as replies and heartbeats carry it (``docs/protocol.md`` 1.8)."""
        with self._lock:
            return {
                "phase": self.phase,
                "done": self.done,
                "total": self.total,
                "step": self.step,
                "elapsed_s": round(time.monotonic() - self.t0, 2),
                "child_pid": None if self.child is None else self.child.pid,
                "note": self.note,
            }

    def background_dict(self) -> dict[str, Any]:
        """The background compile (``stats``' ``compile``): phase, jobs done and total.

        ``phase``: ``none`` (nothing to compile: the cache was warm, or first frame
        first is off), ``compiling``, ``done`` or ``failed``; ``seconds`` once it ended;
        ``priority`` once it started: ``idle`` (:data:`IDLE_POLICY`: it gets only CPU
        time no other program wants) or ``nice 10``.
        """
        with self._lock:
            return dict(self.bg)

    def summary(self) -> str:
        """One line for the log once ready."""
        comp = "" if self.compile_s is None else f"child {self.compile_s:.1f} s, "
        load = "" if self.load_s is None else f"in process {self.load_s:.1f} s"
        note = f"; {self.note}" if self.note else ""
        return f"{self.total} warm-up jobs ({comp}{load}){note}"

    # ------------------------------------------------------------- thread
    def _run(self) -> None:
        rest = False  # the child compiled only this service's jobs: the rest follow
        try:
            warm = self.trust_stamp and is_warm()
            ok = True if warm else self._child(self.first if self.background else None)
            rest = ok and not warm and self.background
            if self._stop.is_set():
                return
            if not ok:
                self._set(phase="compiling", done=0, note=self.note)
            jobs = tuple(n for n in self.jobs if n in self.first) if rest else self.jobs
            if self._in_process("loading" if ok else "compiling", jobs) == 0 and ok and not rest:
                mark_warm()
        except _Abort:
            return
        except Exception as exc:  # noqa: BLE001 -- the service still gets ready
            self._set(note=f"warm-up failed ({type(exc).__name__}: {exc}); "
                      "kernels compile when first used")
            self.log(f"warming up: {self.note}")
        if not self._stop.is_set():
            self._set(phase="ready", done=self.total)
            self.ready.set()
        if rest and not self._stop.is_set():
            self._background()

    def _set(self, **fields: Any) -> None:
        with self._lock:
            for k, v in fields.items():
                setattr(self, k, v)

    def _background(self) -> None:
        """Compile every other job in a low-priority child while the service runs."""
        t0 = time.monotonic()
        left = len([n for n in JOBS if n not in self.first])
        self._set(bg={"phase": "compiling", "done": 0, "total": len(JOBS), "seconds": None,
                      "priority": f"nice {BACKGROUND_NICE}"})
        how = "idle CPU only" if IDLE_POLICY is not None else f"nice {BACKGROUND_NICE}"
        self.log(f"ready first; compiling the other {left} warm-up jobs in the background "
                 f"({how}); stats: compile")
        try:
            # a process group of its own (ended as one), but not a session of its own: with
            # the kernel's autogroups (sched_autogroup_enabled) a new session is a new
            # scheduling group, weighed as much as the whole service, so neither its
            # niceness nor SCHED_IDLE would yield to the service or its clients
            proc = subprocess.Popen(
                (*self.child_cmd, f"--nice={BACKGROUND_NICE}"), stdin=subprocess.DEVNULL,
                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=self.env,
                process_group=0,
            )
        except OSError as exc:
            self._set(bg={**self.bg, "phase": "failed"})
            self.log(f"background compile did not start ({exc}); kernels compile when first "
                     "used")
            return
        priority = "idle" if idle_priority(proc.pid) else f"nice {BACKGROUND_NICE}"
        with self._lock:
            self.bg_child = proc
            self.bg = {**self.bg, "priority": priority}
        if self._stop.is_set():
            _end_group(proc, 3.0)
        with proc.stdout:
            for line in proc.stdout:
                with contextlib.suppress(ValueError):
                    ev = json.loads(line)
                    if isinstance(ev, dict) and ev.get("event") == "kernel":
                        self._set(bg={**self.bg, "done": int(ev.get("done", 0))})
        rc = proc.wait()
        seconds = round(time.monotonic() - t0, 1)
        phase = "done" if rc == 0 else "failed"
        self._set(bg={**self.bg, "phase": phase, "seconds": seconds})
        if not self._stop.is_set():
            self.log(f"background compile {phase} after {seconds} s"
                     + ("" if rc == 0 else f" (exit status {rc}); kernels compile when first "
                        "used"))

    def _child(self, only: tuple[str, ...] | None = None) -> bool:
        """Run the child to the end (``only``: just these jobs); True when it exited 0."""
        t0 = time.monotonic()
        self._set(phase="compiling")
        cmd = (*self.child_cmd, *(f"--job={name}" for name in only or ()))
        # stderr to a file, not a pipe: warnings there must never fill a pipe and stall it
        err_file = tempfile.TemporaryFile("w+")
        try:
            proc = subprocess.Popen(
                cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                stderr=err_file, text=True, env=self.env, start_new_session=True,
            )
        except OSError as exc:
            err_file.close()
            self._set(note=f"warm-up child did not start ({exc}); compiling in process")
            return False
        with self._lock:
            self.child = proc
        if self._stop.is_set():  # stop() came before the child was known
            _end_group(proc, 3.0)
        with proc.stdout:
            for line in proc.stdout:
                self._child_line(line)
        rc = proc.wait()
        with err_file:
            err_file.seek(0)
            err = err_file.read()
        self.compile_s = time.monotonic() - t0
        if rc != 0 and not self._stop.is_set():
            last = (err.strip().splitlines() or [""])[-1][:200]
            self._set(note=f"warm-up child exited {rc} ({last}); compiling in process")
            self.log(f"warming up: {self.note}")
        return rc == 0

    def _child_line(self, line: str) -> None:
        try:
            ev = json.loads(line)
        except ValueError:
            return
        if not isinstance(ev, dict) or ev.get("event") != "kernel":
            return
        self._set(done=int(ev.get("done", 0)), total=int(ev.get("total", self.total)),
                  step=str(ev.get("name", "")))
        cached = bool(ev.get("cached"))  # worded as holo-warmup words it
        how = "cached" if cached else f"{float(ev.get('seconds', 0)):.1f} s"
        word = "loading" if cached else "compiling"
        self.log(f"warming up: {word} {self.done}/{self.total} {self.step} ({how})")

    def _in_process(self, phase: str, jobs: tuple[str, ...]) -> int:
        """The service's warm-up jobs in this process (loads what the child compiled).

        When one of them had to compile (the cache was not as warm as the stamp or
        the child said), every other job runs too, before ready, so that nothing
        compiles later inside the refresh loop.  Returns the number of jobs that
        had to compile (0: all came from the cache).
        """
        t0 = time.monotonic()
        self._set(phase=phase, done=0, total=len(jobs))
        offset = 0

        def progress(step: Any) -> None:
            if self._stop.is_set():
                raise _Abort
            self._set(done=offset + step.done, total=offset + step.total, step=step.name)

        compiled = warm_up(progress, only=list(jobs)).compiled
        rest = [name for name in JOBS if name not in jobs]
        if compiled and rest:
            offset = len(jobs)
            self._set(phase="compiling", note="the cache lacked kernels; warming up every job")
            self.log(f"warming up: {self.note}")
            compiled += warm_up(progress, only=rest).compiled
        self.load_s = time.monotonic() - t0
        return compiled


def idle_priority(pid: int) -> bool:
    """Put every thread of process ``pid`` on :data:`IDLE_POLICY`; True if it took.

    The main thread first, then every thread already started (``/proc/PID/task``):
    a thread started later inherits its starter's policy, and so does a process
    the child forks (``holo-warmup``'s second process).  False where the OS has no
    such policy or refuses it (the niceness the child sets itself still holds).
    """
    if IDLE_POLICY is None:
        return False
    try:
        os.sched_setscheduler(pid, IDLE_POLICY, os.sched_param(0))
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return False
    for tid in tasks:
        with contextlib.suppress(OSError, ValueError):  # a thread that just ended
            os.sched_setscheduler(int(tid), IDLE_POLICY, os.sched_param(0))
    return True


def _end_group(proc: subprocess.Popen, timeout_s: float) -> None:
    """SIGTERM the child's process group, then SIGKILL it if the child does not go."""
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGTERM)
    try:
        proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        pass
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGKILL)  # and whatever it started
    end_process(proc, timeout_s)


