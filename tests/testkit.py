"""What every test folder shares: waiting on conditions, child processes, services.

Imported by name (``from testkit import ...``): the root ``conftest.py`` puts
``tests/`` on ``sys.path``. Fixtures built on these live in ``tests/conftest.py``.

Ports: a test never picks a port number for a process it starts. Services bind
``tcp://127.0.0.1:*`` and :func:`start_service` reads the endpoints they bound
from their ``holo-service: control ... frames ...`` line, so two tests (or two
test runs) cannot race for one port. :func:`free_port` remains for the few places
that need a number before anything binds (a client pointed at nothing, an address
a restarted service must reuse); it binds, closes and returns, so it can race.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import zmq

from service.base.signals import end_process

ROOT = Path(__file__).resolve().parents[1]


def shared_fixture(relative: str) -> Path:
    """A file of the project's shared fixtures, wherever this checkout sits.

    Searched in ``$HOLO_FIXTURES``, ``../shared/fixtures`` beside the checkout, then
    ``/work/shared/fixtures`` (a fresh clone elsewhere, as when checking ``make
    test``); the first candidate when none has it (the caller skips, naming it).
    """
    dirs = [Path(os.environ["HOLO_FIXTURES"])] if os.environ.get("HOLO_FIXTURES") else []
    dirs += [ROOT.parent / "shared" / "fixtures", Path("/work/shared/fixtures")]
    found = [d / relative for d in dirs if (d / relative).is_file()]
    return found[0] if found else dirs[0] / relative
posix_only = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals and ptys")
linux_only = pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="/proc")

SIGNALS = pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM],
                                  ids=["SIGINT", "SIGTERM"])
#: A small display served in process (no workers), for tests of the service's behaviour.
TINY_DISPLAY = ("--zones", "2", "--size", "32x24", "--workers", "0")
#: The game scene on :data:`TINY_DISPLAY` at 30 refreshes a second.
SMALL_SERVICE = ("--scene", "game", *TINY_DISPLAY, "--refresh", "30")

#: The rule of service.base.signals: the exit status after a clean stop on each signal.
STATUS = {signal.SIGINT: 130, signal.SIGTERM: 143}
#: Seconds for a deadline that only guards against a hang, never a speed check: a loaded
#: machine (a shared CI host, a first ``make test`` beside other work) can starve a test
#: for seconds, and a test must then pass, slowly, not fail.
HANG_S = 60.0


def wait_until(predicate: Callable[[], object], timeout_s: float, step_s: float = 0.01) -> object:
    """Poll ``predicate`` until it returns something truthy or the deadline passes.

    Returns its last value (falsy on time-out), so callers can assert on it.
    """
    deadline = time.monotonic() + timeout_s
    tick = threading.Event()  # never set: wait() is the poll interval
    while time.monotonic() < deadline:
        got = predicate()
        if got:
            return got
        tick.wait(step_s)
    return predicate()


def wait_for(pred: Callable[[], object], timeout: float = 20.0, what: str = "condition") -> None:
    """:func:`wait_until`, failing the test with ``what`` after ``timeout`` seconds."""
    if not wait_until(pred, timeout):
        raise AssertionError(f"{what} not met within {timeout} s")


@contextmanager
def held_lock(folder: Path, key: str) -> Iterator[None]:
    """Hold ``key``'s LOD build lock (``<folder>/<key>.lock``), as another process building
    that chain would: a build waits for it, deterministically, until the block ends."""
    import fcntl  # POSIX only, as the tests that use it

    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / f"{key}.lock", "ab") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        yield


def free_port() -> int:
    """A TCP port nobody listens on right now (racy: prefer binding ``:*``)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def children_of(pid: int) -> set[int]:
    """The process ids of ``pid``'s children, zombies included (Linux)."""
    out: set[int] = set()
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            out.update(int(t) for t in (task / "children").read_text().split())
        except OSError:  # the thread ended while we looked
            continue
    return out


def alive(pid: int) -> bool:
    """True while ``pid`` exists and is not a zombie."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def catches(pid: int, signum: int) -> bool:
    """True once process ``pid`` has a handler for ``signum`` (Linux ``SigCgt`` mask)."""
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    mask = next(int(ln.split()[1], 16) for ln in text.splitlines() if ln.startswith("SigCgt"))
    return bool(mask >> (signum - 1) & 1)


def rss_kb(pid: int) -> int:
    """Resident set size of a process from /proc, kB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


class Proc:
    """``python -m MODULE ARGS`` with its stdout / stderr lines collected by threads.

    Parameters
    ----------
    args : str
        The module and its arguments.
    stdout : file descriptor, optional
        Where stdout goes instead of a pipe (a pty's slave side).
    env : dict, optional
        Extra environment variables.
    """

    def __init__(self, *args: str, stdout: int | None = None,
                 env: dict[str, str] | None = None) -> None:
        self.p = subprocess.Popen([sys.executable, "-m", *args], cwd=ROOT, text=True,
                                  stdout=subprocess.PIPE if stdout is None else stdout,
                                  stderr=subprocess.PIPE, stdin=subprocess.DEVNULL,
                                  env={**os.environ, **(env or {})})
        self.out: list[str] = []
        self.err: list[str] = []
        streams = [(self.p.stderr, self.err)]
        if stdout is None:
            streams.append((self.p.stdout, self.out))
        self._threads = [threading.Thread(target=self._pump, args=s, daemon=True)
                         for s in streams]
        for t in self._threads:
            t.start()

    @staticmethod
    def _pump(stream, lines: list[str]) -> None:
        for line in stream:
            lines.append(line.rstrip("\n"))

    def wait_lines(self, pred: Callable[[], bool], timeout: float = 30.0) -> None:
        """Wait until ``pred()``; fail (with the last stderr lines) if the process ends."""
        deadline = time.monotonic() + timeout
        tick = threading.Event()
        while not pred():
            if time.monotonic() > deadline or self.p.poll() is not None:
                if pred():
                    return
                raise AssertionError(f"condition not met; rc={self.p.poll()}, "
                                     f"stderr={self.err[-8:]}")
            tick.wait(0.01)

    def signal(self, signum: int) -> None:
        """Send ``signum`` to the process."""
        self.p.send_signal(signum)

    def finish(self, timeout: float = 30.0) -> int:
        """Wait for the exit status; the output threads have finished after it."""
        rc = self.p.wait(timeout)
        for t in self._threads:
            t.join(timeout)
        return rc

    def kill(self) -> None:
        """Kill it if it still runs, and collect its output threads."""
        if self.p.poll() is None:
            self.p.kill()
        self.finish(10)


def raw_request(
    address: str,
    header: dict,
    buffers: tuple = (),
    timeout_ms: int = 5000,
    ctx: zmq.Context | None = None,
) -> dict | None:
    """One request with a fresh DEALER (raw pyzmq, protocol doc layout); reply header."""
    s = (ctx or zmq.Context.instance()).socket(zmq.DEALER)
    s.setsockopt(zmq.LINGER, 0)
    s.connect(address)
    try:
        s.send_multipart([b"", json.dumps(header).encode(), *buffers])
        if not s.poll(timeout_ms):
            return None
        frames = s.recv_multipart()
        return json.loads(frames[1])
    finally:
        s.close(0)


def _is_ready(reply: dict | None) -> bool:
    """A hello reply from a service that is ready (not warming up)."""
    return reply is not None and reply.get("status", "ready") == "ready"


_BOUND = re.compile(r"holo-service: control (\S+) frames (\S+)")


@dataclass
class ServiceProcess:
    """A running ``holo-service``; its stderr goes to ``log`` (a temporary file)."""

    proc: subprocess.Popen
    log: Path
    control: str = ""
    frames: str = ""
    _stopped: bool = field(default=False, repr=False)

    def output(self) -> str:
        """What it has written to stderr so far."""
        return self.log.read_text(errors="replace") if self.log.exists() else ""

    def bound(self) -> bool:
        """Read the endpoints it bound from its start-up line; True once there."""
        m = _BOUND.search(self.output())
        if m:
            self.control, self.frames = m.group(1), m.group(2)
        return m is not None

    def stop(self) -> None:
        """End it (signal, then kill) and pass its stderr on to pytest's capture."""
        if self._stopped:
            return
        self._stopped = True
        end_process(self.proc)
        sys.stderr.write(self.output())
        self.log.unlink(missing_ok=True)


def launch_service(*args: str, env: dict[str, str] | None = None,
                   bound_timeout_s: float = HANG_S) -> ServiceProcess:
    """Start ``holo-service`` on loopback ports of its own choosing; wait until it has bound.

    It may still be warming up (for that, :func:`start_service`). Control, frames and
    (with local workers, not ``--workers 0``) the broker backend bind
    ``tcp://127.0.0.1:*`` unless ``args`` name them; the bound endpoints come back as
    ``control`` and ``frames`` (its first stderr line), so no two tests race for a port.
    """
    given = set(args)
    no_workers = any(a == "--workers" and b == "0" for a, b in zip(args, args[1:], strict=False))
    default = {"--control": "tcp://127.0.0.1:*", "--frames": "tcp://127.0.0.1:*"}
    if not no_workers:  # a broker backend only for local workers, as the service does
        default["--worker-address"] = "tcp://127.0.0.1:*"
    extra = [x for k, v in default.items() if k not in given for x in (k, v)]
    fd, name = tempfile.mkstemp(prefix="holo-service-", suffix=".log")
    cmd = [sys.executable, "-m", "service.commands.holo_service", *extra, *args]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdin=subprocess.DEVNULL, stderr=fd,
                            env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})})
    os.close(fd)
    svc = ServiceProcess(proc, Path(name))
    _wait_or_stop(svc, svc.bound, bound_timeout_s)
    return svc


def _wait_or_stop(svc: ServiceProcess, done: Callable[[], object], timeout_s: float) -> None:
    """Wait until ``done()`` while the service runs; else stop it and raise with its output."""
    proc = svc.proc
    try:
        if not wait_until(lambda: proc.poll() is not None or done(), timeout_s) \
                or proc.poll() is not None:
            raise RuntimeError(f"holo-service did not start (rc {proc.poll()}): "
                               f"{svc.output()[-2000:]}")
    except BaseException:
        svc.stop()
        raise


def start_service(*args: str, ready_timeout_s: float = 60.0,
                  env: dict[str, str] | None = None) -> ServiceProcess:
    """Start ``holo-service`` (as :func:`launch_service`); wait until it is ready.

    Until its warm-up is over the service answers hello with ``status: warming_up``
    (``docs/protocol.md`` 1.8); the tests want a service that renders.
    """
    svc = launch_service(*args, env=env, bound_timeout_s=ready_timeout_s)
    hello = {"v": 1, "type": "hello", "id": 0, "versions": [1]}
    _wait_or_stop(svc, lambda: _is_ready(raw_request(svc.control, hello, (), 500)),
                  ready_timeout_s)
    return svc


class ColdWarmup:
    """A cache filled by one ``holo-warmup`` from an empty cache, and what it reported.

    Two ways, decided when the tests are collected:

    * **reused**: the last full ``holo-warmup`` on this checkout's cache started from
      an empty cache and the cache still holds exactly the files it left
      (:func:`service.warmup.read_record`): a fresh clone's ``make test``, whose
      ``make warmup`` just compiled everything.  Its cache files are copied into
      ``cache`` (numba's ``NUMBA_CACHE_DIR`` layout) before any test can add to
      the cache, and its recorded events are the result: no kernel compiles twice.
    * **cold here**: otherwise ``holo-warmup --jsonl`` runs into an empty ``cache``
      in the background.  The cold compile takes minutes, most of them on one core;
      started at collection, at a lower priority, it overlaps the rest of the suite
      on the other core instead of adding its minutes to ``make test``.

    With pytest-xdist the controller makes it (before any worker starts) and the
    workers :meth:`attach` to its folder: the events (``events.json`` when reused)
    or the background run's output and exit status (``rc``, written when it ends).
    """

    def __init__(self, folder: Path | None = None) -> None:
        from service.warmup import read_record

        self.owner = folder is None
        self.folder = Path(tempfile.mkdtemp(prefix="holo-cold-warmup-")) if folder is None \
            else folder
        self.cache = self.folder / "numba-cache"
        self.proc: subprocess.Popen | None = None
        self.events: list[dict] | None = None
        self.env = {**os.environ, "NUMBA_CACHE_DIR": str(self.cache), "PYTHONUNBUFFERED": "1"}
        if not self.owner:
            events = self.folder / "events.json"
            self.reused = events.exists()
            if self.reused:
                self.events = json.loads(events.read_text())
            return
        self.cache.mkdir()
        record = read_record()
        self.reused = record is not None and record.get("empty_at_start") is True
        if self.reused:
            self.events = record["events"]
            copy_numba_cache(self.cache)
            (self.folder / "events.json").write_text(json.dumps(self.events))
            return
        with (self.folder / "out").open("w") as out, (self.folder / "err").open("w") as err:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "service.commands.holo_warmup", "--jsonl"], cwd=ROOT,
                env=self.env, stdin=subprocess.DEVNULL, stdout=out, stderr=err,
                preexec_fn=lambda: os.nice(10),
            )

    @classmethod
    def attach(cls, folder: str | Path) -> ColdWarmup:
        """The cold warm-up another process (the xdist controller) made in ``folder``."""
        return cls(Path(folder))

    def announce(self) -> None:
        """Write the exit status to ``rc`` when the background run ends (for :meth:`attach`)."""
        if self.proc is None:
            return
        proc, rc = self.proc, self.folder / "rc"

        def wait() -> None:
            code = proc.wait()
            tmp = rc.with_suffix(".tmp")
            tmp.write_text(str(code))
            os.replace(tmp, rc)

        threading.Thread(target=wait, name="cold-warmup-rc", daemon=True).start()

    def result(self, timeout_s: float) -> tuple[int, list[dict], str]:
        """Wait for it: exit status, its JSON events, the tail of its stderr."""
        if self.reused:
            return 0, self.events, ""
        if self.proc is not None:
            rc = self.proc.wait(timeout_s)
        else:  # attached: the controller's run writes its status when it ends
            path = self.folder / "rc"
            if not wait_until(path.exists, timeout_s, 0.5):
                raise subprocess.TimeoutExpired("holo-warmup", timeout_s)
            rc = int(path.read_text())
        events = [json.loads(line) for line in (self.folder / "out").read_text().splitlines()]
        return rc, events, (self.folder / "err").read_text()[-2000:]

    def close(self) -> None:
        """Stop it if it still runs and remove its folder (only the process that made it)."""
        if not self.owner:
            return
        if self.proc is not None:
            end_process(self.proc)
        shutil.rmtree(self.folder, ignore_errors=True)


def copy_numba_cache(dst: Path) -> None:
    """Copy this process's numba cache of ``service`` into ``dst`` (with stamp and record).

    ``dst`` is laid out as numba lays out a ``NUMBA_CACHE_DIR``: a folder per source
    folder, named by numba's own rule.  An index file names its data files and the
    source's hash, not its folder, so the copy is a cache numba loads as is.
    """
    from numba.core.caching import _CacheLocator

    import service.warmup
    from service.kernel_cache import stamp_path
    from service.warmup import cache_files, record_path

    root = os.environ.get("NUMBA_CACHE_DIR")
    # the package folder as numba sees it (the module's __file__, not resolved)
    base = Path(root) if root else Path(service.warmup.__file__).parent
    for rel in cache_files():
        src = base / rel
        if root:
            target = dst / rel
        else:  # service/<...>/__pycache__/f.nbi -> dst/<folder>_<sha1>/f.nbi
            sub = _CacheLocator.get_suitable_cache_subpath(str(src.parent.parent / "x.py"))
            target = dst / sub / src.name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, target)
    for extra in (stamp_path(), record_path()):  # the warm stamp, the warm-up's record
        if extra.exists():
            shutil.copy2(extra, dst / extra.name)
