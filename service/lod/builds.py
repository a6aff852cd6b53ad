"""Level-of-detail chains built off the render path, each in a child process of its own.

:class:`ChainBuilds` (used by :class:`service.lod.state.LodState` with ``background``) runs
``python -m service.lod.builds MESH.npz FOLDER OUT RECIPE.json PARENT_PID`` for a chain
that is neither in memory nor in the cache, one at a time, from a daemon thread.
Quadric decimation (fast-simplification) holds the GIL for 20-40 ms a call on the
bunny: in a thread of the rendering process it stalled renders and the service's
refreshes by as much, so no chain is built in the rendering process, with a cache
folder or without one.

**The child.**  The mesh's arrays come in a numpy file (``vertices``, ``polygons``,
``counts``; read with ``allow_pickle=False``), the chain's settings as JSON
(``fractions``, ``cloud_eps``, ``texture_res``, ``name``).  ``FOLDER`` is the cache
folder (``-`` for none): the chain is built there (:func:`service.lod.cache.build_chain`,
which takes its lock file).  Where it is not in the cache afterwards (no cache, or
the folder could not be written) the child writes it to ``OUT``, a temporary folder
of the parent's, in the cache's own format (:func:`service.lod.cache.write_chain`: numpy
files and JSON, no pickle).  On stdout, one line each: ``progress: DONE PLANNED``
after each decimation (as it happens), ``note: TEXT`` for what went wrong with the
cache, then ``levels: N`` and ``folder: PATH`` (where to read it).
A build that fails says why in one line on stderr and exits :data:`EXIT_FAILED` (the
mesh cannot be simplified: building it again would fail again) or
:data:`EXIT_TEMPFAIL` (an OSError or MemoryError: a full disk or a busy machine, which
may pass).  Nothing here is for users to run.

**Failures.**  A build that failed for a reason that may pass (the child killed by a
signal, :data:`EXIT_TEMPFAIL`, the child not started, the chain not readable
afterwards) is tried again after each wait of :data:`RETRY_S`; one that failed
deterministically (:data:`EXIT_FAILED`) is not.  Each failure is one line in
:attr:`ChainBuilds.notes`; a chain given up is in :attr:`ChainBuilds.failed` with its
reason, and the mesh is drawn in full (exact, only slower): nothing is lost.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from service.base.signals import end_with_parent
from service.lod.cache import build_chain, cache_dir, read_chain, write_chain
from service.lod.chain import LodChain, full_only, mesh_key
from service.lod.settings import BUILD_NICE, NOTES_KEPT, LodError, LodSettings
from service.render.mesh import Mesh
from service.render.scene import Scene

#: The child's exit status when the mesh cannot be simplified (not retried).
EXIT_FAILED = 1
#: The child's exit status for a failure that may pass (EX_TEMPFAIL: retried).
EXIT_TEMPFAIL = 75
#: Seconds waited before each retry of a build that failed for a reason that may
#: pass (so at most ``1 + len(RETRY_S)`` tries).
RETRY_S = (1.0, 4.0)
#: ``FOLDER`` argument of the child meaning "no cache folder".
NO_CACHE = "-"


class BuildFailed(LodError):
    """A chain's build failed; ``transient`` when building it again may succeed."""

    def __init__(self, why: str, transient: bool) -> None:
        super().__init__(why)
        self.transient = transient


@dataclass
class _Job:
    """A chain to build: its key, mesh and settings, tries so far, not before when."""

    key: str
    mesh: Mesh
    settings: LodSettings
    tries: int = 0
    not_before: float = 0.0


class ChainBuilds:
    """Chains built off the render path: a daemon thread while any is queued, one at a time.

    :meth:`service.lod.state.LodState.chain` (with ``background``) hands a mesh whose chain
    is neither in memory nor in the cache to :meth:`submit` and draws the full mesh
    meanwhile; each frame it asks :meth:`take` whether the chain is done.  Each chain
    is built in a child process (see the module notes), at :data:`BUILD_NICE`.

    Parameters
    ----------
    cache : Path, True or False
        As :func:`service.lod.cache.build_chain`'s ``cache``.
    retry_s : tuple of float
        Waits before the retries of a build that failed for a reason that may pass.
    """

    def __init__(self, cache: Path | None | bool = True,
                 retry_s: tuple[float, ...] = RETRY_S) -> None:
        self.cache = cache
        self.retry_s = tuple(retry_s)
        self._lock = threading.Lock()
        self._idle = threading.Condition(self._lock)
        self._todo: list[_Job] = []
        self._pending: set[str] = set()
        self._done: dict[str, LodChain] = {}
        #: key -> why its build failed for good (the mesh is drawn in full)
        self.failed: dict[str, str] = {}
        #: the last few cache problems and failed builds, oldest first
        self.notes: deque[str] = deque(maxlen=NOTES_KEPT)
        #: builds finished (or failed) so far: a frame that sees it change looks again
        self.generation = 0
        #: pid of the build child running now, or None
        self.child_pid: int | None = None
        #: chains built so far (handed over or not)
        self.built = 0
        self._current: tuple[str, int, int] | None = None  # (mesh name, done, planned)
        self._queued_scene: set[str] = set()  # keys submit_scene has handed in
        self._keys: dict[int, tuple[Mesh, str, str]] = {}  # the last scene's meshes' hashes
        #: ``on_progress(mesh name, done, planned)``, from the build thread (a CLI's bar)
        self.on_progress: Callable[[str, int, int], None] | None = None
        self._child: subprocess.Popen | None = None
        self._thread: threading.Thread | None = None
        self._closed = False

    def submit(self, key: str, mesh: Mesh, settings: LodSettings) -> None:
        """Build the chain of ``mesh`` (hash ``key``) unless it is built, failed or queued."""
        with self._lock:
            if (self._closed or key in self._pending or key in self._done
                    or key in self.failed):
                return
            self._pending.add(key)
            self._todo.append(_Job(key, mesh, settings))
            self._idle.notify_all()
            if self._thread is None:  # the thread lives while there is work
                self._thread = threading.Thread(target=self._run, name="lod-chains",
                                                daemon=True)
                self._thread.start()

    def submit_scene(self, scene: Scene, settings: LodSettings) -> int:
        """Queue the chains of a scene's meshes that are neither cached nor known here.

        What ``load_scene`` and the game's scene loading call, so that chains build
        while the first frames draw full meshes, not from the frame that needs them.
        A mesh shared by several objects is queued once; a mesh already handed in (by
        this or an earlier scene) is not hashed for the cache again.

        Returns
        -------
        int
            How many chains were queued.
        """
        folder = cache_dir() if self.cache is True else (Path(self.cache) if self.cache else None)
        queued, keys = 0, {}
        for obj in scene.objects:
            if id(obj.mesh) in keys:
                continue
            known = self._keys.get(id(obj.mesh))
            key = (known[1] if known is not None and known[0] is obj.mesh
                   and known[2] == settings.recipe else mesh_key(obj.mesh, settings.recipe))
            keys[id(obj.mesh)] = (obj.mesh, key, settings.recipe)
            if key in self._queued_scene or (
                    folder is not None and (folder / f"{key}.json").is_file()):
                continue
            self._queued_scene.add(key)
            self.submit(key, obj.mesh, settings)
            queued += 1
        self._keys = keys
        return queued

    def status(self) -> dict:
        """What ``stats`` reports of the builds (``docs/protocol.md``, ``chains``).

        ``queued`` (waiting, retries included), ``building`` (the mesh's name, or
        None), ``progress`` (``[done, planned]`` decimations of that build, or None),
        ``built``, ``failed`` and ``notes`` (the last cache problems and failures).
        """
        with self._lock:
            current = self._current
            return {"queued": len(self._todo), "building": current and current[0],
                    "progress": list(current[1:]) if current else None,
                    "built": self.built, "failed": len(self.failed),
                    "notes": list(self.notes)}

    def take(self, key: str) -> LodChain | None:
        """The chain built for ``key`` (handed over once), or None."""
        with self._lock:
            return self._done.pop(key, None)

    def building(self, key: str) -> bool:
        """Whether ``key``'s chain is queued, being built or waiting for a retry."""
        with self._lock:
            return key in self._pending

    def wait_idle(self, timeout_s: float) -> bool:
        """Wait until no build is queued or running; False if still busy after ``timeout_s``."""
        with self._idle:
            return self._idle.wait_for(lambda: not self._pending, timeout_s)

    def close(self, timeout_s: float = 10.0) -> None:
        """Drop what is queued, end a running child (SIGTERM) and wait for the thread."""
        with self._lock:
            self._closed = True
            self._todo.clear()
            child, thread = self._child, self._thread
            self._idle.notify_all()
        if child is not None and child.poll() is None:
            child.terminate()
        if thread is not None:
            thread.join(timeout_s)

    def _next(self) -> _Job | None:
        """The next job whose time has come (waits for it), or None: the thread ends."""
        with self._lock:
            while self._todo and not self._closed:
                job = min(self._todo, key=lambda j: j.not_before)
                wait = job.not_before - time.monotonic()
                if wait <= 0:
                    self._todo.remove(job)
                    # building from now on for status(), not only once the child runs
                    self._current = (job.mesh.name or "a mesh", 0, 0)
                    return job
                self._idle.wait(wait)  # a retry's back-off (or a submit, or close)
            self._thread = None
            self._pending.clear()
            self._idle.notify_all()
            return None

    def _run(self) -> None:
        """The thread: build what is queued, then end (a daemon: a build dies with the process)."""
        while (job := self._next()) is not None:
            notes: list[str] = []
            chain, why, retry = None, "", None
            try:
                chain = self._build(job, notes)
            except Exception as exc:  # noqa: BLE001 - any failure: the full mesh stays
                why = str(exc) if isinstance(exc, BuildFailed) else f"{type(exc).__name__}: {exc}"
                why = why[:200]
                job.tries += 1
                if getattr(exc, "transient", False) and job.tries <= len(self.retry_s):
                    retry = self.retry_s[job.tries - 1]
                notes.append(_failure_note(job, why, retry, len(self.retry_s) + 1))
            with self._lock:
                self._current = None
                if chain is not None:
                    self._done[job.key] = chain
                    self.built += 1
                elif retry is not None and not self._closed:
                    job.not_before = time.monotonic() + retry
                    self._todo.append(job)
                else:
                    self.failed[job.key] = why
                if chain is not None or retry is None or self._closed:
                    self._pending.discard(job.key)
                self.notes.extend(notes)
                self.generation += 1
                self._idle.notify_all()

    def _build(self, job: _Job, notes: list) -> LodChain:
        """One chain, in a child process; raises :class:`BuildFailed`."""
        folder = cache_dir() if self.cache is True else (Path(self.cache) if self.cache else None)
        try:
            tmp = tempfile.TemporaryDirectory(prefix="holo-lod-")
        except OSError as exc:
            raise BuildFailed(f"no temporary folder for the build: {exc}", True) from None
        with tmp as out:
            return self._run_child(job, folder, Path(out), notes)

    def _run_child(self, job: _Job, folder: Path | None, out: Path, notes: list) -> LodChain:
        """Start the child, follow its progress, wait for it, and read the chain it built."""
        mesh, src = job.mesh, out / "mesh.npz"
        try:
            with open(src, "wb") as fh:
                np.savez(fh, vertices=mesh.vertices, polygons=mesh.polygons, counts=mesh.counts)
            recipe = {"fractions": list(job.settings.fractions),
                      "cloud_eps": list(job.settings.cloud_eps),
                      "texture_res": job.settings.texture_res, "name": mesh.name}
            args = [sys.executable, "-m", "service.lod.builds", str(src),
                    str(folder) if folder is not None else NO_CACHE, str(out / "chain"),
                    json.dumps(recipe), str(os.getpid())]
            with self._lock, open(out / "stderr.txt", "w+") as err:
                if self._closed:
                    raise BuildFailed("the renderer closed", False)
                # stderr to a file: a pipe read only at the end could fill and stall it
                self._child = subprocess.Popen(args, stdin=subprocess.DEVNULL,
                                               stdout=subprocess.PIPE, stderr=err, text=True)
                self.child_pid = self._child.pid
                self._current = (mesh.name or "a mesh", 0, 0)
            if self.on_progress is not None:
                self.on_progress(mesh.name or "a mesh", 0, 0)
            lines = self._follow(self._child, mesh.name or "a mesh")
            self._child.wait()
            stderr = (out / "stderr.txt").read_text(errors="replace")
        except OSError as exc:
            raise BuildFailed(f"the build could not run: {exc}", True) from None
        finally:
            with self._lock:
                code = self._child.returncode if self._child is not None else None
                self._child, self.child_pid = None, None
        return _result(job, code, "\n".join(lines), stderr, notes)

    def _follow(self, child: subprocess.Popen, name: str) -> list[str]:
        """The child's stdout lines but its ``progress:`` ones, which update :meth:`status`."""
        lines = []
        for line in child.stdout:
            parts = line.split()
            if len(parts) == 3 and parts[0] == "progress:" and parts[1].isdigit() \
                    and parts[2].isdigit():
                with self._lock:
                    self._current = (name, int(parts[1]), int(parts[2]))
                if self.on_progress is not None:
                    self.on_progress(name, int(parts[1]), int(parts[2]))
            else:
                lines.append(line.rstrip("\n"))
        child.stdout.close()
        return lines


def _result(job: _Job, code: int | None, stdout: str, stderr: str, notes: list) -> LodChain:
    """The chain a child reported on stdout, or :class:`BuildFailed` saying why not."""
    lines = stdout.splitlines()
    notes.extend(line[len("note: "):] for line in lines if line.startswith("note: "))
    if code is None or code < 0:
        name = signal.Signals(-code).name if code is not None and -code in _SIGNALS else code
        raise BuildFailed(f"the build process was killed ({name})", True)
    if code != 0:
        why = (stderr.strip().splitlines() or [f"exit status {code}"])[-1]
        raise BuildFailed(why, code != EXIT_FAILED)
    if "levels: 1" in lines:  # nothing to simplify: the full mesh is the whole chain
        return replace(full_only(job.mesh, job.key), ready=True)
    where = next((line[len("folder: "):] for line in lines if line.startswith("folder: ")), "")
    chain = read_chain(Path(where), job.key, job.mesh) if where else None
    if chain is None:  # e.g. the cache file deleted or damaged between
        raise BuildFailed(f"the built chain could not be read from {where or 'anywhere'}", True)
    return chain


_SIGNALS = {int(s) for s in signal.Signals}


def _failure_note(job: _Job, why: str, retry: float | None, tries: int) -> str:
    """One line on a failed try: what failed and what happens next."""
    name = job.mesh.name or "a mesh"
    if retry is not None:
        return (f"level-of-detail chain of {name}: build failed ({why}); trying again in "
                f"{retry:g} s (try {job.tries + 1} of {tries})")
    after = f" after {job.tries} tries" if job.tries > 1 else ""
    return f"level-of-detail chain of {name} not built{after} ({why}); drawn with its full mesh"


def main(argv: list[str] | None = None) -> int:
    """The child: build one chain; see the module notes."""
    args = sys.argv[1:] if argv is None else argv
    if len(args) > 4:
        # a service stopped mid-build would otherwise leave its build running
        end_with_parent(int(args[4]), signal.SIGTERM)
    try:
        mesh_file, out, recipe = Path(args[0]), Path(args[2]), json.loads(args[3])
        folder = None if args[1] == NO_CACHE else Path(args[1])
        os.nice(BUILD_NICE)  # renders come first
        with np.load(mesh_file, allow_pickle=False) as data:
            mesh = Mesh(data["vertices"], data["polygons"], data["counts"],
                        str(recipe.get("name", "mesh")))
        settings = LodSettings(fractions=tuple(recipe["fractions"]),
                               cloud_eps=tuple(recipe["cloud_eps"]),
                               texture_res=int(recipe["texture_res"]))
        notes: list[str] = []
        chain = build_chain(mesh, settings, folder if folder is not None else False,
                            notes=notes, progress=_print_progress)
        if folder is None or not (folder / f"{chain.key}.json").is_file():
            folder = out  # not cached: hand it over through the parent's temporary folder
            if len(chain.levels) > 1:
                write_chain(out, chain)
    except (OSError, MemoryError) as exc:  # a full disk, a busy machine: may pass
        return _fail(exc, EXIT_TEMPFAIL)
    except Exception as exc:  # noqa: BLE001 - one line to the parent, whatever it was
        return _fail(exc, EXIT_FAILED)
    for note in notes:
        print("note: " + note.replace("\n", " "))
    print(f"levels: {len(chain.levels)}")
    print(f"folder: {folder}")
    return 0


def _print_progress(done: int, planned: int) -> None:
    """The child's ``progress: DONE PLANNED`` line after each decimation."""
    print(f"progress: {done} {planned}", flush=True)


def _fail(exc: BaseException, status: int) -> int:
    """Say why on stderr, in one line, and return ``status``."""
    print(f"{type(exc).__name__}: {exc}"[:300].replace("\n", " "), file=sys.stderr)
    return status


if __name__ == "__main__":
    raise SystemExit(main())
