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
import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from service.base.signals import end_process
from service.display import DisplaySettings
from service.kernel_cache import fingerprint, stamp_path
from service.numba_patches import apply_all as numba_patches

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


# ------------------------------------------------------------------ the kit
@dataclass
class _Kit:
    """Small inputs the jobs share (built once, on first use)."""

    display: DisplaySettings = field(
        default_factory=lambda: DisplaySettings(zones=3, angle_deg=16.0, cols=24, rows=16)
    )
    cache: dict[str, Any] = field(default_factory=dict)

    def scene(self, name: str = "game") -> Any:
        """A built-in scene (cached)."""
        from service.builtin_scenes import SCENES

        if name not in self.cache:
            self.cache[name] = SCENES[name]()
        return self.cache[name]


def _scenes(kit: _Kit) -> None:
    """Mesh builders: corner normals and ear-clipping of polygons (all built-in scenes)."""
    from service.builtin_scenes import SCENES
    from service.triangulate import ear_clip

    for name in SCENES:
        kit.scene(name).flatten()
    ear_clip(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.5, 0.4], [0.0, 1.0]]))


#: A mesh file with a concave and a non-planar polygon: loading repairs both by
#: ear-clipping (``service.mesh_repair``), as a user's mesh would be.
_OBJ = """v 0 0 0
v 1 0 0
v 1 1 0
v 0.5 0.3 0
v 0 1 0
v 2 0 0
v 3 0 0.4
v 3 1 0
v 2 1 0.3
f 1 2 3 4 5
f 6 7 8 9
"""


def _mesh_files(kit: _Kit) -> None:
    """A mesh file loaded as the service loads one (repair: ear-clipping)."""
    import tempfile
    import warnings
    from pathlib import Path

    from service.loaders import load_scene

    with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the repair's own warning
        path = Path(tmp) / "warmup.obj"
        path.write_text(_OBJ)
        load_scene(path).flatten()


def _render(method: str, model: str = "blinn", evaluation: str = "polygon",
            fallback: str = "frame") -> Callable:
    """A render job: frames and renders with motion.

    ``Renderer.render`` as holo-render and the game call it (light into uint8), and
    ``render_with_motion`` as the service's workers do (light into float32 too).
    """

    def job(kit: _Kit) -> None:
        from service.galilean.motion_field import render_with_motion
        from service.render.light import LightSettings
        from service.render.pipeline import Renderer, RenderSettings

        settings = RenderSettings(method=method, light=LightSettings(model, evaluation),
                                  painter_fallback=fallback)
        renderer = Renderer()
        for name in ("game", "cyclic"):  # cyclic: the painter's fallback too
            renderer.render(kit.scene(name), kit.display, settings)
            render_with_motion(renderer, kit.scene(name), kit.display, 0.1, 60.0, settings)

    return job


def _motion(colour_motion: bool, model: str) -> Callable:
    def job(kit: _Kit) -> None:
        from service.galilean.motion_field import render_with_motion
        from service.render.light import LightSettings
        from service.render.pipeline import Renderer, RenderSettings

        settings = RenderSettings(method="zbuffer", light=LightSettings(model))
        render_with_motion(Renderer(), kit.scene(), kit.display, 0.1, 60.0, settings,
                           colour_motion=colour_motion)

    return job


def _stage_refreshes(stage: Any, n: int = 3) -> None:
    for _ in range(n):
        stage.refresh()


def _galilean_kernels(kit: _Kit) -> None:
    """The service refresh's stage kernels on made-up G(2) maps: no render kernel runs.

    The maps are laid out as ``stitch`` lays out a band render's (each field a
    C-contiguous copy), so the scatter, finish, show and head-motion kernels compile
    for the types :func:`_galilean_service` then loads them with.  Run beside the
    ``FIRST`` jobs in the second process (see :data:`EARLY`).
    """
    from service.galilean import GalileanSettings, GalileanStage
    from service.galilean.galpixmap import FIELDS, Galpixmap
    from service.render.scene import MotionState

    stage = GalileanStage(kit.display, GalileanSettings(order=2, refresh_hz=60.0))
    rng = np.random.default_rng(7)
    for k in range(2):
        blank = Galpixmap.empty(2, stage.fixed, stage.shape)
        f = {n: np.array(getattr(blank, n)) for n in FIELDS}
        f["depth"][:] = rng.integers(2**20, 2**21, f["depth"].shape)
        f["debris"][:], f["obj"][:] = 0, 0
        f["colour"][:] = rng.uniform(0, 255, f["colour"].shape)
        f["motion"][:] = rng.integers(-3000, 3000, f["motion"].shape)
        f["frac"][:] = rng.integers(-100, 100, f["frac"].shape)
        stage.submit(Galpixmap(order=2, fixed=stage.fixed, **f), stage.index + 1, None, True,
                     (), None, None, MotionState())
        stage.viewer(MotionState(velocity=[0.1 * k, 0.0, 0.0], angular_velocity=[0.0, 0.2, 0.0]))
        _stage_refreshes(stage)


def _galilean_service(kit: _Kit) -> None:
    """The service's path: band renders (``render_job``), stitched, submitted, refreshed."""
    from service.engine.jobs import render_job, stitch
    from service.galilean import GalileanSettings, GalileanStage
    from service.render.pipeline import Renderer
    from service.render.scene import MotionState

    d = kit.display
    stage = GalileanStage(d, GalileanSettings(order=2, refresh_hz=60.0))
    job = {
        "display": {"zones": d.zones, "angle_deg": d.angle_deg, "cols": d.cols, "rows": d.rows,
                    "width": d.width},
        "rows": [0, d.rows], "t": 0.1, "refresh_hz": 60.0, "order": 2,
        "render": {"method": "zbuffer", "light_model": "blinn", "specular": "polygon"},
    }
    renderer = Renderer()
    for k in range(2):
        half = d.rows // 2
        bands = [render_job(renderer, {**job, "rows": r}, kit.scene())[0]
                 for r in ([0, half], [half, d.rows])]
        rendered, buf = stitch(bands, MotionState(), stage.fixed, 2)
        stage.submit(buf, stage.index + 1, None, True, (), rendered.points,
                     rendered.point_derivs, rendered.viewer_motion)
        stage.viewer(MotionState(velocity=[0.1 * k, 0.0, 0.0], angular_velocity=[0.0, 0.2, 0.0]))
        _stage_refreshes(stage)


def _galilean_variants(kit: _Kit) -> None:
    """Stage settings that take other kernels: orders 0-3, cache, margin, no Poisson."""
    from service.galilean import GalileanSettings, GalileanStage
    from service.galilean.motion_field import render_with_motion
    from service.render.pipeline import Renderer

    renderer = Renderer()
    variants = [
        GalileanSettings(order=o, cache=c, margin=m, poisson=p, threads=th, expansion=e)
        for o, c, m, p, th, e in [
            (0, False, 0, True, 0, "average"), (1, True, 2, True, 1, "replicate"),
            (3, True, 0, False, 0, "average"), (2, False, 2, True, 1, "average"),
        ]
    ]
    up = render_with_motion(renderer, kit.scene(), kit.display, 0.1, 60.0)
    for s in variants:
        stage = GalileanStage(kit.display, s)
        stage.update(up)
        _stage_refreshes(stage, 4)


def _shadows(kit: _Kit) -> None:
    """Depth-only shadow renders (:mod:`service.galilean.shadow`): cull, sort, z-buffer.

    The local-update job reaches them too, but they are render kernels, not
    Galilean ones: compiled here, in the first process while the second one is
    still in its long service-refresh job, they leave that (longer) process
    sooner, which then loads them from the cache.  Called as ``render_local``
    calls it, so the signatures are the same.
    """
    from service.galilean.shadow import shadow_depth
    from service.render.pipeline import RenderSettings

    scene = kit.scene()
    shadow_depth(scene, range(1, len(scene.objects)), kit.display, 0.1, RenderSettings().cull)


def _galilean_local(kit: _Kit) -> None:
    """Local updates (Flinders Street buffers with depth-only shadows), grafted."""
    from service.galilean import GalileanSettings, GalileanStage
    from service.galilean.local_update import render_local
    from service.render.pipeline import Renderer

    stage = GalileanStage(kit.display, GalileanSettings(order=2))
    renderer = Renderer()
    for shadow in ("depth", "full"):
        local = render_local(renderer, kit.scene(), kit.display, [0], 0.1, 60.0, 2, stage.fixed,
                             shadow=shadow)
        stage.submit(local.buffer, None, (0,))
        _stage_refreshes(stage)


def _autostereograms(kit: _Kit) -> None:
    """The autostereogram output's kernels (service encoding, game mode, holo-sird)."""
    from service.autostereogram.output import warm_up_sird

    for method in ("row", "interpolated", "tiw"):
        warm_up_sird(method)


def _lookingglass(kit: _Kit) -> None:
    """The Looking Glass interleave (holo-render and the game's ``--display lookingglass:``)."""
    from service.lookingglass import Calibration, Interleaver

    cal = Calibration(pitch=50.0, slope=5.5, center=0.1, view_cone=40.0, inv_view=True,
                      dpi=300.0, screen_w=16, screen_h=10, views=3)
    Interleaver(cal)(np.zeros((3, 5, 8, 3), np.uint8))


def _level_of_detail(kit: _Kit) -> None:
    """Level of detail (``--lod``): decimation errors, billboard clouds built and drawn.

    Clouds are drawn by the pipeline and by the service's Galilean render (with motion).
    """
    from dataclasses import replace

    from service.billboard_render import BillboardObject
    from service.galilean.motion_field import render_with_motion
    from service.lod.settings import LodSettings
    from service.lod.state import LodState
    from service.render.pipeline import Renderer, RenderSettings

    scene = kit.scene()
    lod = LodSettings(error_px=1e6, fractions=(0.5,), cloud_eps=(0.2,), texture_res=16)
    renderer = Renderer()
    renderer.lod = LodState(cache=False)  # no chain written to the user's LOD cache
    renderer.render(scene, kit.display, RenderSettings(lod=lod))
    # the chain that render built (a second build cost every service start 0.1-0.2 s)
    chain = renderer.lod.chain(scene.objects[-1].mesh, lod)
    boards = [BillboardObject(level) for level, kind in zip(chain.levels, chain.kinds,
                                                            strict=True) if kind == "billboard"]
    for method in ("zbuffer", "runlength", "bsp", "raycast"):
        renderer.render(replace(scene, billboards=boards), kit.display,
                        RenderSettings(method=method))
    # the service's workers draw clouds inside the Galilean render, with their motion
    render_with_motion(renderer, replace(scene, billboards=boards), kit.display, 0.0, 60.0)


#: Where a job runs when :func:`warm_up` has two processes: ``FIRST`` jobs run
#: before the split (the render path every Galilean job calls), then ``APART``
#: jobs run in a second process while this one runs the ``HERE`` jobs.  The two
#: groups compile disjoint kernels: numba numbers a kernel's cache entries by
#: reading its index, so two processes adding different signatures of one kernel
#: at once could both write entry 1 (and one index would then name the other's
#: code).  The ``APART`` side is the longer one (the two scatter kernels: 92 s of
#: CPU against 74 s here, measured 2026-11-26), so render kernels that only a
#: Galilean job reached (the depth-only shadows) compile in the first ``HERE``
#: job instead, before the second process gets to them: it then loads them.
#: ``EARLY`` jobs start the second process as soon as a ``FIRST`` job had to
#: compile, and run there beside the rest of the ``FIRST`` jobs, so they must reach
#: none of their kernels: the Galilean stage's kernels on a made-up map (the scatter
#: kernels, 9 signatures, none shared with the render path: checked 2026-11-26).
#: The second process holds its ``APART`` jobs until this one's ``FIRST`` jobs end.
FIRST, HERE, APART, EARLY = "first", "here", "apart", "early"


@dataclass(frozen=True)
class _Job:
    run: Callable[[_Kit], None]
    part: str
    #: a ``holo-service`` loads it before it is ready (:data:`SERVICE_JOBS`)
    service: bool = False
    #: a cold ``holo-service`` compiles it before its first frame (:data:`FIRST_FRAME_JOBS`)
    first_frame: bool = False


#: The warm-up's jobs, in order: name -> job.  Each runs the real code path on tiny
#: inputs, so the kernels compile for the types they are really called with.
JOBS: dict[str, _Job] = {
    "scenes: normals, triangulation": _Job(_scenes, FIRST, first_frame=True),
    "render zbuffer": _Job(_render("zbuffer"), FIRST, service=True, first_frame=True),
    "light ambient": _Job(_render("zbuffer", "ambient"), FIRST),
    "light phong": _Job(_render("zbuffer", "phong"), FIRST),
    "motion field": _Job(_motion(True, "blinn"), FIRST, service=True, first_frame=True),
    "motion field, no colour motion": _Job(_motion(False, "ambient"), FIRST),
    "galilean: refresh kernels, made-up map": _Job(_galilean_kernels, EARLY, first_frame=True),
    "galilean: service refresh": _Job(_galilean_service, APART, service=True,
                                      first_frame=True),
    "galilean: orders, cache, margin": _Job(_galilean_variants, APART, service=True),
    "galilean: local updates": _Job(_galilean_local, APART),
    "galilean: depth-only shadows": _Job(_shadows, HERE),
    "mesh files: repair": _Job(_mesh_files, HERE),
    "render runlength": _Job(_render("runlength"), HERE),
    "render runlength, pixel fallback": _Job(_render("runlength", fallback="pixel"), HERE),
    "render bsp": _Job(_render("bsp"), HERE),
    "render raycast": _Job(_render("raycast"), HERE),
    "light vertex (Gouraud)": _Job(_render("zbuffer", "blinn", "vertex"), HERE),
    "light point (per pixel)": _Job(_render("zbuffer", "blinn", "point"), HERE),
    "autostereograms: row, interpolated, tiw": _Job(_autostereograms, HERE, service=True,
                                                    first_frame=True),
    "level of detail, billboard clouds": _Job(_level_of_detail, HERE),
    "looking glass interleave": _Job(_lookingglass, HERE),
}


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
#: service is ready.
FIRST_FRAME_JOBS: tuple[str, ...] = tuple(n for n, job in JOBS.items() if job.first_frame)


# ------------------------------------------------------------ cache counters
def dispatchers(prefix: str = "service") -> Iterator[Any]:
    """Every numba dispatcher defined in an imported module under ``prefix``."""
    from numba.core.dispatcher import Dispatcher

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


def _run(name: str, kit: _Kit) -> tuple[float, int]:
    """Run job ``name``: (seconds, kernel signatures it compiled)."""
    misses0 = cache_counts()[1]
    t0 = time.perf_counter()
    JOBS[name].run(kit)
    return time.perf_counter() - t0, cache_counts()[1] - misses0


def _second_process(
    names: list[str], report: _Progress, hold_before: str | None = None
) -> tuple[Any, threading.Thread]:
    """``holo-warmup --jsonl`` for ``names`` in a child; a thread reports its jobs.

    With ``hold_before`` the child waits for a line on its stdin (:func:`_release`)
    before it runs that job.
    """
    cmd = [sys.executable, "-m", "service.commands.holo_warmup", "--jsonl", "--processes", "1",
           f"--parent-pid={os.getpid()}", *(f"--job={n}" for n in names)]
    if hold_before is not None:
        cmd.append(f"--hold-before={hold_before}")
    child = subprocess.Popen(cmd, stdout=subprocess.PIPE, stdin=subprocess.PIPE, text=True)

    def read() -> None:
        for line in child.stdout:  # read to the end, whatever comes: never block the child
            try:
                ev = json.loads(line)
            except ValueError:
                continue
            if isinstance(ev, dict) and ev.get("event") == "kernel":
                report.step(ev["name"], ev["seconds"], ev.get("kernels", 0 if ev["cached"] else 1))

    reader = threading.Thread(target=read, name="warmup-child", daemon=True)
    reader.start()
    return child, reader


def _release(child: Any) -> None:
    """Let a held second process go on (a line, then end of file, on its stdin)."""
    with contextlib.suppress(OSError):  # it ended already: nothing to release
        child.stdin.write("go\n")
        child.stdin.close()


def warm_up(
    progress: Callable[[WarmupStep], None] | None = None,
    processes: int = 1,
    only: list[str] | None = None,
    before_job: Callable[[str], None] | None = None,
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
        jobs beside the ``HERE`` jobs; this process then runs both groups again
        (loaded from the cache: a check that another process finds them).
        1: everything here, in order.
    only : list of str, optional
        Run just these jobs of :data:`JOBS`.
    before_job : callable, optional
        Called with each job's name before it runs here (``holo-warmup
        --hold-before``: the second process waits there for its parent).

    Returns
    -------
    WarmupReport
    """
    # before anything compiles: the same machine code at less CPU (docs/compile-time.md),
    # and cache saves locked against other processes compiling into the same cache
    numba_patches()
    names = [n for n in JOBS if only is None or n in only]
    kit = _Kit()
    report = _Progress(len(names), progress)
    t_all = time.perf_counter()
    split = processes > 1 and any(JOBS[n].part in (EARLY, APART) for n in names)
    child = None
    try:
        child, reader = _run_first(names, kit, report, split)
        _run_here(names, kit, report, child is not None, before_job)
        if child is not None:
            child.wait()
            reader.join()
            _check_child(names, kit, report)
    finally:
        if child is not None:
            end_process(child)
    steps = tuple(report.steps)
    n_cached = sum(s.cached for s in steps)
    return WarmupReport(len(steps), len(steps) - n_cached, n_cached,
                        time.perf_counter() - t_all, steps, cache_counts()[2])


def _run_here(names: list[str], kit: _Kit, report: _Progress, child: bool,
              before_job: Callable[[str], None] | None) -> None:
    """Run the jobs after the ``FIRST`` ones here, but those a ``child`` process runs."""
    run_here = [n for n in names if JOBS[n].part != FIRST
                and (not child or JOBS[n].part not in (EARLY, APART))]
    for name in run_here:
        if before_job is not None:
            before_job(name)
        report.step(name, *_run(name, kit))


def _check_child(names: list[str], kit: _Kit, report: _Progress) -> None:
    """Run the child's (finished) jobs here again: they load what it compiled.

    A job the child did not report (it failed or was stopped) is reported from here.
    """
    done = {s.name for s in report.steps}
    for name in (n for n in names if JOBS[n].part in (EARLY, APART)):
        seconds, compiled = _run(name, kit)  # loads what the child compiled
        if name not in done:
            report.step(name, seconds, compiled)


def _run_first(
    names: list[str], kit: _Kit, report: _Progress, split: bool
) -> tuple[Any, threading.Thread | None]:
    """The ``FIRST`` jobs; with ``split``, the second process starts at the first compile.

    Returns the second process (released to its ``APART`` jobs) and its reader
    thread, or (None, None) when every ``FIRST`` job was cached or ``split`` is off.
    """
    child = reader = None
    rest = [n for n in names if JOBS[n].part in (EARLY, APART)]
    held = next((n for n in rest if JOBS[n].part == APART), None)
    try:
        for name in (n for n in names if JOBS[n].part == FIRST):
            report.step(name, *_run(name, kit))
            if split and child is None and not report.steps[-1].cached:
                child, reader = _second_process(rest, report, held)
    except BaseException:
        if child is not None:
            end_process(child)
        raise
    if child is not None:
        _release(child)
    return child, reader
