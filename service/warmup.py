"""Compile ahead: every numba kernel the service, the Galilean stage and the game use.

Numba compiles a kernel the first time it is called with new argument types and
keeps the machine code in its cache (``NUMBA_CACHE_DIR``, else ``__pycache__`` next
to the module), so a cold process pays for every kernel on its first frames: a
``holo-service`` with an empty cache took 124 s to publish its first 120 frames.
:func:`warm_up` pays that once, ahead, with progress: it runs each job of
:data:`JOBS` (a tiny render, refresh or mesh build through the same code paths, so
the kernels see the types they are really called with) and reports, per job, how
long it took and whether every kernel it needed came from the cache.

A job is *cached* when no kernel missed numba's cache during it (the dispatchers'
``stats.cache_misses`` did not grow); a second process with the same cache
compiles nothing (``tests/warmup``).  ``holo-warmup`` (:mod:`service.commands.holo_warmup`)
is the command; ``make venv`` runs it.
"""

from __future__ import annotations

import contextlib
import gc
import json
import os
import queue
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from numba.core.dispatcher import Dispatcher

from service import lookingglass
from service.autostereogram import warmup_jobs as sird_jobs
from service.base.signals import end_process
from service.engine import warmup_jobs as engine_jobs
from service.galilean import warmup_jobs as galilean_jobs
from service.kernel_cache import fingerprint, stamp_path
from service.loaders import warmup_jobs as loaders_jobs
from service.lod import warmup_jobs as lod_jobs
from service.numba_patches import apply_all as numba_patches
from service.render import warmup_jobs as render_jobs
from service.warmup_job import APART, EARLY, FIRST, HERE, PARTS, Job, Kit

__all__ = [
    "FIRST_FRAME_JOBS", "JOBS", "SERVICE_JOBS", "WarmupReport", "WarmupStep", "cache_counts",
    "cache_files", "dispatchers", "read_record", "record_path", "warm_up", "write_record",
]


@dataclass(frozen=True)
class WarmupStep:
    """One job of the warm-up, done.

    Attributes
    ----------
    done, total : int
        Jobs done so far (this one included) and in all.
    name : str
        The job (see :data:`JOBS`).
    seconds : float
        Wall time of the job.
    cached : bool
        True when every kernel it needed was loaded from numba's cache (nothing
        compiled).
    kernels : int
        Kernel signatures compiled during the job (0 when ``cached``).
    """

    done: int
    total: int
    name: str
    seconds: float
    cached: bool
    kernels: int = 0


@dataclass(frozen=True)
class WarmupReport:
    """What :func:`warm_up` did.

    Attributes
    ----------
    total : int
        Jobs run.
    compiled : int
        Jobs that compiled at least one kernel.
    cached : int
        Jobs whose kernels all came from the cache (``compiled + cached == total``).
    seconds : float
        Wall time of the whole warm-up.
    steps : tuple of WarmupStep
    kernels : int
        Kernel signatures loaded or compiled (numba dispatchers' overloads).
    """

    total: int
    compiled: int
    cached: int
    seconds: float
    steps: tuple[WarmupStep, ...] = ()
    kernels: int = 0


#: The modules whose ``JOBS`` the warm-up gathers: one per subsystem, each beside
#: the kernels it warms (:mod:`service.warmup_job`).  Their order is the jobs' order
#: within a part: level of detail before the short loaders, autostereogram and
#: looking-glass jobs, so that its chain of three jobs (``Job.after``: about 20 s,
#: one process) is not what the two processes end on.
JOB_MODULES = (
    render_jobs, engine_jobs, galilean_jobs, lod_jobs, loaders_jobs, sird_jobs, lookingglass,
)


def _gather(modules: tuple[Any, ...]) -> dict[str, Job]:
    """Every module's ``WARMUP_JOBS``, stably ordered by part (:data:`~service.warmup_job.PARTS`).

    Raises
    ------
    ValueError
        Two modules register a job of the same name.
    """
    merged: dict[str, Job] = {}
    for module in modules:
        for name, job in module.WARMUP_JOBS.items():
            if name in merged:
                raise ValueError(f"warm-up job {name!r} registered twice")
            merged[name] = job
    return dict(sorted(merged.items(), key=lambda item: PARTS.index(item[1].part)))


#: The warm-up's jobs, in order: name -> job.  Each runs the real code path on tiny
#: inputs, so the kernels compile for the types they are really called with.
JOBS: dict[str, Job] = _gather(JOB_MODULES)


#: The jobs a ``holo-service`` runs in process before it is ready
#: (:mod:`service.readiness`, step 3): the service's own render at its starting
#: settings and every kernel its refresh loop can reach (the Galilean refresh at any
#: order, the autostereogram encoding).  The others (every built-in scene, other
#: render methods and light models, level of detail, mesh repair, the game's paths)
#: load from the cache where first used, in the render thread or a request's
#: handler: a warm start's in-process jobs took 1.7 s of CPU, these 0.6 s
#: (2026-11-26, one numba thread, side by side on the loaded machine).
SERVICE_JOBS: tuple[str, ...] = tuple(name for name, job in JOBS.items() if job.service)

#: The jobs a ``holo-service`` on a cold cache compiles before its first frame
#: (:mod:`service.readiness`, "first frame first"): the mesh builders of its scene,
#: its render at the starting settings, the Galilean refresh at its starting order
#: (with the made-up-map job, which compiles the refresh's stage kernels in the
#: second process beside the render path) and the autostereogram encoding a client
#: may ask for.  Every other job,
#: the refresh's other orders and settings too, compiles in the background once the
#: service is ready; so does the plain scatter, which a stage runs only once it is
#: cached (``GalileanStage._plain_ready``), and ``Renderer.render``'s uint8 frames,
#: which a service does not draw.
FIRST_FRAME_JOBS: tuple[str, ...] = tuple(n for n, job in JOBS.items() if job.first_frame)


# ------------------------------------------------------------ cache counters
def dispatchers(prefix: str = "service") -> Iterator[Any]:
    """Every numba dispatcher defined in an imported module under ``prefix``."""
    seen: set[int] = set()
    for name, module in list(sys.modules.items()):
        if module is None or not (name == prefix or name.startswith(prefix + ".")):
            continue
        for obj in list(vars(module).values()):
            if isinstance(obj, Dispatcher) and id(obj) not in seen:
                seen.add(id(obj))
                yield obj


def cache_counts(prefix: str = "service") -> tuple[int, int, int]:
    """``(hits, misses, overloads)`` summed over :func:`dispatchers`.

    A miss is a signature numba did not find in its cache and compiled.
    """
    hits = misses = loaded = 0
    for d in dispatchers(prefix):
        hits += sum(d.stats.cache_hits.values())
        misses += sum(d.stats.cache_misses.values())
        loaded += len(d.overloads)
    return hits, misses, loaded


# ------------------------------------------------------------- the record
#: File name of :func:`write_record`'s record, beside the warm-cache stamp.
RECORD_NAME = "holo-warmup-last.json"


def cache_files() -> dict[str, list[int]]:
    """The numba cache files of the ``service`` kernels: relative path -> [size, mtime_ns].

    The cache is ``NUMBA_CACHE_DIR`` when set (every index and data file in it),
    else the ``__pycache__`` folders of the ``service`` package.
    """
    root = os.environ.get("NUMBA_CACHE_DIR")
    base = Path(root) if root else Path(__file__).parent
    found = base.rglob("*.nb[ic]") if root else base.rglob("__pycache__/*.nb[ic]")
    out = {}
    for path in found:
        with contextlib.suppress(OSError):  # a file replaced while we look
            st = path.stat()
            out[str(path.relative_to(base))] = [st.st_size, st.st_mtime_ns]
    return out


def record_path() -> Path:
    """Where :func:`write_record` keeps the last full warm-up's record."""
    return stamp_path().parent / RECORD_NAME


def write_record(empty_at_start: bool, events: list[dict]) -> None:
    """Record a full warm-up: its events, whether the cache was empty, the files it left.

    With it a later process can tell that the cache holds what one warm-up from an
    empty cache wrote and nothing else (``files`` still match), and read what that
    warm-up reported (``tests/warmup`` checks a fresh clone's ``make test`` warm-up
    this way instead of compiling every kernel a second time).  A read-only cache
    gets no record.
    """
    path = record_path()
    record = {"fingerprint": fingerprint(), "empty_at_start": empty_at_start,
              "jobs": list(JOBS), "events": events, "files": cache_files()}
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(json.dumps(record))
        os.replace(tmp, path)
    except OSError:
        pass


def read_record() -> dict | None:
    """The last full warm-up's record if it still describes the cache, else None.

    It does while the sources, numba and Python are those it was made with, it ran
    every job of :data:`JOBS`, and the cache's files are exactly those it left.
    """
    try:
        record = json.loads(record_path().read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(record, dict):
        return None
    same = (record.get("fingerprint") == fingerprint() and record.get("jobs") == list(JOBS)
            and record.get("files") == cache_files())
    return record if same else None


class _Progress:
    """Numbers finished jobs (from this process or the second one) and reports them."""

    def __init__(self, total: int, progress: Callable[[WarmupStep], None] | None) -> None:
        self.total = total
        self.steps: list[WarmupStep] = []
        self._progress = progress
        self._lock = threading.Lock()

    def step(self, name: str, seconds: float, compiled: int) -> None:
        with self._lock:
            step = WarmupStep(len(self.steps) + 1, self.total, name, seconds, compiled == 0,
                              compiled)
            self.steps.append(step)
            if self._progress is not None:
                self._progress(step)


def _run(name: str, kit: Kit) -> tuple[float, int]:
    """Run job ``name``: (seconds, kernel signatures it compiled)."""
    misses0 = cache_counts()[1]
    t0 = time.perf_counter()
    JOBS[name].run(kit)
    return time.perf_counter() - t0, cache_counts()[1] - misses0


def claim(share: Path, name: str) -> bool:
    """Claim job ``name`` in the folder ``share`` two processes take ``HERE`` jobs from.

    True for the first process to ask (the claim is a file created exclusively,
    holding its pid), False for any later one: each shared job runs in one process,
    whichever is free first, so the two end close together whatever each job costs.
    """
    path = share / f"{list(JOBS).index(name)}.claim"
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    except FileExistsError:
        return False
    with os.fdopen(fd, "w") as f:
        f.write(str(os.getpid()))
    return True


def _second_process(
    names: list[str], report: _Progress, finished: queue.Queue, hold_before: str | None = None,
    share: Path | None = None,
) -> tuple[Any, threading.Thread]:
    """``holo-warmup --jsonl`` for ``names`` in a child; a thread reports its jobs.

    The thread also puts the name of each job the child finishes on ``finished``,
    and None once the child's output ends.  With ``hold_before`` the child waits
    for a line on its stdin (:func:`_release`) before it runs that job; with
    ``share`` it runs a ``HERE`` job of ``names`` only if it claims it there first
    (:func:`claim`).
    """
    cmd = [sys.executable, "-m", "service.commands.holo_warmup", "--jsonl", "--processes", "1",
           f"--parent-pid={os.getpid()}", *(f"--job={n}" for n in names)]
    if hold_before is not None:
        cmd.append(f"--hold-before={hold_before}")
    if share is not None:
        cmd.append(f"--share={share}")
    child = subprocess.Popen(cmd, stdout=subprocess.PIPE, stdin=subprocess.PIPE, text=True)

    def read() -> None:
        try:
            for line in child.stdout:  # read to the end, whatever comes: never block the child
                try:
                    ev = json.loads(line)
                except ValueError:
                    continue
                if isinstance(ev, dict) and ev.get("event") == "kernel":
                    report.step(ev["name"], ev["seconds"],
                                ev.get("kernels", 0 if ev["cached"] else 1))
                    finished.put(ev["name"])
        finally:
            finished.put(None)

    reader = threading.Thread(target=read, name="warmup-child", daemon=True)
    reader.start()
    return child, reader


def _release(child: Any) -> None:
    """Let a held second process go on (a line, then end of file, on its stdin)."""
    with contextlib.suppress(OSError):  # it ended already: nothing to release
        child.stdin.write("go\n")
        child.stdin.close()


#: Python's collector thresholds while the warm-up compiles (default 700, 10, 10):
#: numba makes and drops millions of IR, type and LLVM-builder objects, and at the
#: default a collection ran every 700 allocations; two render jobs and the made-up
#: map took 5 % less CPU (docs/compile-time.md, "The garbage collector"); a whole
#: cold warm-up peaked at 628 MB instead of 517.
COMPILE_GC_THRESHOLD = (100_000, 50, 1_000)


@contextlib.contextmanager
def fewer_collections() -> Iterator[None]:
    """Python's garbage collector runs less often inside (its thresholds restored after).

    What is alive on entry (numba, numpy, the modules) is frozen out of every
    collection (``gc.freeze``) and thawed on exit.
    """
    before = gc.get_threshold()
    gc.freeze()
    gc.set_threshold(*COMPILE_GC_THRESHOLD)
    try:
        yield
    finally:
        gc.set_threshold(*before)
        gc.unfreeze()


def warm_up(
    progress: Callable[[WarmupStep], None] | None = None,
    processes: int = 1,
    only: list[str] | None = None,
    before_job: Callable[[str], None] | None = None,
    share: Path | None = None,
) -> WarmupReport:
    """Compile, or load from numba's cache, every kernel of :data:`JOBS`.

    Parameters
    ----------
    progress : callable, optional
        Called with each :class:`WarmupStep` as its job finishes (from a second
        thread too when ``processes`` is 2: jobs are numbered as they finish).
    processes : int
        2: once a ``FIRST`` job had to compile (an empty cache), a second process
        runs the ``EARLY`` jobs beside the other ``FIRST`` jobs, then the ``APART``
        jobs beside the ``HERE`` jobs, and then takes ``HERE`` jobs too: each
        process claims the next unclaimed one (:func:`claim`), so both end close
        together; this process then runs the second one's jobs again (loaded from
        the cache: a check that another process finds them).
        1: everything here, in order.
    only : list of str, optional
        Run just these jobs of :data:`JOBS`.
    before_job : callable, optional
        Called with each job's name before it runs here (``holo-warmup
        --hold-before``: the second process waits there for its parent).
    share : Path, optional
        The second process's side of the ``HERE`` jobs' claims: run one only if it
        claims it in this folder (``holo-warmup --share``; its parent made it).

    Returns
    -------
    WarmupReport
    """
    # before anything compiles: less CPU for the same kernels (docs/compile-time.md),
    # and cache saves locked against other processes compiling into the same cache
    numba_patches()
    with fewer_collections():
        return _warm_up(progress, processes, only, before_job, share)


def _warm_up(progress: Callable[[WarmupStep], None] | None, processes: int,
             only: list[str] | None, before_job: Callable[[str], None] | None,
             share: Path | None) -> WarmupReport:
    """:func:`warm_up`'s body (its patches applied, its collector set)."""
    names = [n for n in JOBS if only is None or n in only]
    kit = Kit()
    report = _Progress(len(names), progress)
    t_all = time.perf_counter()
    split = processes > 1 and any(JOBS[n].part in (EARLY, APART) for n in names)
    pool = Path(tempfile.mkdtemp(prefix="holo-warmup-")) if split else None
    child = None
    finished: queue.Queue = queue.Queue()
    try:
        child, reader = _run_first(names, kit, report, pool, finished)
        ran = _run_here(names, kit, report, child is not None, before_job,
                        pool if child is not None else share)
        if child is not None:
            _check_child(names, kit, report, ran, finished)
            child.wait()
            reader.join()
    finally:
        if child is not None:
            end_process(child)
        if pool is not None:
            shutil.rmtree(pool, ignore_errors=True)
    steps = tuple(report.steps)
    n_cached = sum(s.cached for s in steps)
    return WarmupReport(len(steps), len(steps) - n_cached, n_cached,
                        time.perf_counter() - t_all, steps, cache_counts()[2])


def _run_here(names: list[str], kit: Kit, report: _Progress, child: bool,
              before_job: Callable[[str], None] | None, share: Path | None) -> list[str]:
    """Run the jobs after the ``FIRST`` ones here, but those a ``child`` process runs.

    With ``share``, a ``HERE`` job runs only if claimed there (the other process
    may have it).  Returns the jobs run here.
    """
    run_here = [n for n in names if JOBS[n].part != FIRST
                and (not child or JOBS[n].part not in (EARLY, APART))]
    ran = []
    mine: dict[str, bool] = {}  # claims asked: a job and those ``after`` it go together
    for name in run_here:
        if share is not None and JOBS[name].part == HERE:
            root = _claim_root(name, names)
            if root not in mine:
                mine[root] = claim(share, root)
            if not mine[root]:
                continue
        if before_job is not None:
            before_job(name)
        report.step(name, *_run(name, kit))
        ran.append(name)
    return ran


def _claim_root(name: str, names: list[str]) -> str:
    """The first job of ``name``'s chain of ``after`` jobs (within ``names``): its claim."""
    while JOBS[name].after in names:
        name = JOBS[name].after
    return name


def _check_child(names: list[str], kit: Kit, report: _Progress, ran: list[str],
                 finished: queue.Queue) -> None:
    """Run the child's jobs here again as it finishes them: they load what it compiled.

    The child's jobs are every ``EARLY`` and ``APART`` one and the ``HERE`` ones
    not in ``ran`` (run here).  Each is run as soon as the child reports it on
    ``finished`` (until None: the child's output ended), so this process, done
    with its own jobs, loads them while the child compiles its last ones (loaded
    after the child ended, they took 2.8 s more at the end of a cold warm-up).  A
    job the child did not report (it failed or was stopped) is reported from here.
    """
    loaded = set()
    for name in iter(finished.get, None):
        if name not in ran and name not in loaded:
            _run(name, kit)  # loads what the child compiled
            loaded.add(name)
    for name in (n for n in names if JOBS[n].part != FIRST and n not in ran and n not in loaded):
        report.step(name, *_run(name, kit))


def _run_first(
    names: list[str], kit: Kit, report: _Progress, pool: Path | None, finished: queue.Queue
) -> tuple[Any, threading.Thread | None]:
    """The ``FIRST`` jobs; with a ``pool`` folder, the second process starts at the first compile.

    Returns the second process (released to its ``APART`` jobs, then sharing the
    ``HERE`` jobs through ``pool``) and its reader thread, or (None, None) when
    every ``FIRST`` job was cached or there is no ``pool``.
    """
    child = reader = None
    rest = [n for n in names if JOBS[n].part in (EARLY, APART, HERE)]
    held = next((n for n in rest if JOBS[n].part == APART), None)
    try:
        for name in (n for n in names if JOBS[n].part == FIRST):
            report.step(name, *_run(name, kit))
            if pool is not None and child is None and not report.steps[-1].cached:
                child, reader = _second_process(rest, report, finished, held, pool)
    except BaseException:
        if child is not None:
            end_process(child)
        raise
    if child is not None:
        _release(child)
    return child, reader
