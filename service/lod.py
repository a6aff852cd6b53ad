"""Level of detail: per object per frame, the cheapest representation within an error budget.

Each mesh gets a *chain* of representations (:class:`LodChain`): the full mesh, then
quadric-decimated levels (:func:`service.simplify.quadric.decimate`), each with its
geometric error in mesh units (a sampled symmetric Hausdorff distance to the full
mesh).  A chain is built once and cached on disk by the mesh's hash
(:func:`cache_dir`; format in ``docs/file-formats.md``: ``<hash>.npz`` arrays plus
``<hash>.json`` header, no pickle).

Each frame :func:`select_levels` picks, for every object, the coarsest level whose
*predicted screen error* stays under ``LodSettings.error_px``:

    predicted px = level error (mesh units) x object scale x pixels per world unit

**Which projection.** Every view zone of this display is an off-axis *parallel*
projection (:mod:`service.display`): a world displacement ``d`` moves a point on
zone ``k``'s pixel grid by ``(d_x - d_z tan(theta_k), d_y) / s``, whatever its
depth.  The longest such move per unit of ``|d|`` is ``sqrt(1 + tan^2 theta_k) / s``,
so the pixels per world unit (:func:`pixels_per_unit`) are that at the widest zone
and **do not shrink with depth**: a far object is not smaller on this display.  The
game and the service draw every object at its world size through these same parallel
projections (the head-tracked mode only chooses which zone to show), so in this
project the level depends on the object's size (mesh error x scale) and on the
pixel size, not on its distance.  :func:`select_levels` takes the pixels per unit
per object, so a perspective viewer (``f / depth``) could pass its own.

**Hysteresis.** An object moves to a coarser level only when that level's
predicted error is under ``(1 - hysteresis) x error_px``, and back to a finer one
only when its level's error goes over ``error_px``; between the two it keeps its
level, so a scale or zoom hovering at a threshold does not flicker.  The chosen
level never predicts more than ``error_px`` unless ``budget_ms`` forced it.

**Time budget.** With ``budget_ms``, when the triangles chosen would cost more than
the budget, objects are stepped to coarser levels, the smallest on screen first and,
among equals, the farthest; such objects are reported ``over_error``.  The cost is
predicted by a *measured* model (:class:`FrameCost`): a line ``fixed + per triangle``
fitted to the renderer's own last frames (their triangles and render milliseconds),
not a constant; the first frame, with nothing measured, is chosen by error alone.

**Building off the render path.**  A chain takes seconds to build (the bunny: 2 s
quiet, 5-9 s on a loaded machine), longer than the service's render timeout.  A
renderer whose :class:`LodState` has ``background`` (the service's and its workers')
hands a chain that is not cached to a :class:`service.lod_build.ChainBuilds` thread
(which builds it in a child process, with a cache folder or without) and draws that
mesh in full meanwhile (exact, slower); the report's ``chains`` says how many are
ready, building or failed.  A build that failed for a reason that may pass (the
child killed, a full disk) is tried again a bounded number of times; one that fails
deterministically is not.  Processes sharing a cache folder build each chain once
(a lock file).  A damaged or torn cache file is reported and rebuilt.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import time
import warnings
import zipfile
from collections import OrderedDict, deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO

import numpy as np

from service.display import DisplaySettings
from service.errors import HoloError, SettingsError
from service.mesh import Mesh
from service.npy_file import read_npz
from service.scene import Scene, SceneObject

if TYPE_CHECKING:  # service.lod_build imports this module
    from service.lod_build import ChainBuilds

#: Triangle fractions of the decimated levels (each level's target, of the full mesh).
DEFAULT_FRACTIONS = tuple(round(0.7 ** k, 4) for k in range(1, 15))
#: Billboard-cloud levels: EPS as fractions of the mesh's bounding-box diagonal.  None
#: by default: where LOD may choose a cloud (about 10 px across at EPS 1 %) it costs
#: 2-6x less than the full mesh but 2-4x more than the quadric level of the same
#: predicted error (holo-bench billboard part 4, docs/simplify.md "Cost"), and in the
#: crowd it saved no time while raising the image error; opt in with e.g. (0.01,).
DEFAULT_CLOUD_EPS: tuple[float, ...] = ()
#: Billboard texels are grown by this many EPS to close cracks (service.simplify).
CLOUD_DILATE = 0.5
#: A cloud's cost in triangles per quad: a quad covers many pixels, each with a texel
#: lookup, alpha and depth tests and its own light; holo-bench billboard part 4
#: measured a quad at about 60-130 triangles' worth of frame time (5 zones, 320x240,
#: bunny, torus and spiky attacker at 10 px).  Counting it as the two triangles it
#: is drawn as let LOD pick a cloud that cost 1.9x the quadric level beside it.
QUAD_TRIANGLES = 100
#: Bump when the chain's contents or file layout change (old cache files are rebuilt).
CHAIN_VERSION = 8
#: Environment variable naming the cache folder.
CACHE_ENV = "HOLO_LOD_CACHE"
#: An error this many times the finer level's is a jump whose plateau end is sought.
PLATEAU_JUMP = 1.5
#: Decimations spent seeking each such plateau end (bisection on the fraction).
PLATEAU_STEPS = 3
#: fast-simplification's aggressiveness for the chain's levels (its default is 7).  At
#: 4 the sampled error of the levels 70 % to 2 % measured 0.47-1.19x (mostly 0.6-0.9x)
#: that at 7 on the bunny, the torus and the spiky attacker, at about the same cost.
QUADRIC_AGG = 4
#: Dead band of the time budget, a fraction of it (:meth:`LodState._budget`).
BUDGET_BAND = 0.1
#: Levels smaller than this many triangles are not built.
MIN_TRIANGLES = 8

#: Chains a renderer keeps in memory by mesh hash (the least recently used go first).
CHAINS_KEPT = 64
#: Cache problems and failed builds a renderer keeps for its LOD report.
NOTES_KEPT = 4
#: Nice value a background chain build's process adds to its own (renders come first).
BUILD_NICE = 5
#: ``progress(done, planned)``: decimations done and planned of a chain's build.
Progress = Callable[[int, int], None]


class LodError(HoloError, ValueError):
    """A level-of-detail chain cannot be built or read."""


class LodCacheWarning(UserWarning):
    """The chain cache folder could not be written; the chain is used uncached."""


@dataclass(frozen=True)
class LodSettings:
    """Level-of-detail choices for a render.

    Attributes
    ----------
    error_px : float > 0
        Largest predicted screen error of a chosen level, in pixels (default 0.5).
    enabled : bool
        False renders every object with its full mesh (``--lod off``).
    budget_ms : float or None
        Optional frame-time budget; objects are degraded past ``error_px`` to meet it.
    hysteresis : float in [0, 1)
        Coarsen only when the coarser level predicts under ``(1 - hysteresis) x error_px``.
    fractions : tuple of float in (0, 1)
        Triangle fractions of the decimated levels.
    cloud_eps : tuple of float in (0, 1)
        Billboard-cloud levels (issue 13B), each with EPS this fraction of the mesh's
        bounding-box diagonal; () for none (the default, see ``DEFAULT_CLOUD_EPS``).
        Used only where billboards can be drawn (``Renderer.render``).
    texture_res : int
        Texels across the bounding-box diagonal of each cloud's textures.
    """

    error_px: float = 0.5
    enabled: bool = True
    budget_ms: float | None = None
    hysteresis: float = 0.25
    fractions: tuple[float, ...] = DEFAULT_FRACTIONS
    cloud_eps: tuple[float, ...] = DEFAULT_CLOUD_EPS
    texture_res: int = 256

    def __post_init__(self) -> None:
        if not (np.isfinite(self.error_px) and self.error_px > 0):
            raise SettingsError(f"LOD error must be a number of pixels > 0, got {self.error_px}")
        if self.budget_ms is not None and not (
            np.isfinite(self.budget_ms) and self.budget_ms > 0
        ):
            raise SettingsError(f"LOD budget must be > 0 ms, got {self.budget_ms}")
        if not 0 <= self.hysteresis < 1:
            raise SettingsError(f"LOD hysteresis must be in [0, 1), got {self.hysteresis}")
        if not self.fractions or not all(0 < f < 1 for f in self.fractions):
            raise SettingsError(f"LOD fractions must be in (0, 1), got {self.fractions}")
        if not all(0 < f < 1 for f in self.cloud_eps):
            raise SettingsError(f"LOD cloud EPS fractions must be in (0, 1), got {self.cloud_eps}")
        if not (isinstance(self.texture_res, int) and self.texture_res >= 1):
            raise SettingsError(f"LOD texture_res must be an integer >= 1, got {self.texture_res}")

    @property
    def recipe(self) -> str:
        """What the chain is built from, for its cache key."""
        fr = ",".join(f"{f:.6g}" for f in self.fractions)
        ce = ",".join(f"{f:.6g}" for f in self.cloud_eps)
        return f"q[{fr}]b[{ce}]t{self.texture_res}"


def lod_from(error_px: float | None, budget_ms: float | None) -> LodSettings | None:
    """Settings from an error budget (px) and a time budget (ms), as the service sends them.

    0 or None means not set; neither set: None (level of detail off); a time budget
    alone turns it on at the default 0.5 px.
    """
    error_px, budget_ms = float(error_px or 0.0), float(budget_ms or 0.0)
    if error_px <= 0 and budget_ms <= 0:
        return None
    return LodSettings(error_px=error_px if error_px > 0 else 0.5,
                       budget_ms=budget_ms if budget_ms > 0 else None)


@dataclass(frozen=True)
class LodChain:
    """A mesh's representations, finest (the full mesh) first.

    Attributes
    ----------
    levels : tuple of Mesh or BillboardCloud
        Dearest first (by ``triangles``): ``levels[0]`` is the full mesh, then quadric
        meshes and billboard clouds (:class:`service.simplify.billboard.BillboardCloud`)
        in order of cost.
    errors : ndarray, shape (L,), float64
        Geometric error of each level in mesh units, ``errors[0] == 0``,
        non-decreasing over the mesh levels (a cloud's is :func:`cloud_error`).
    triangles : ndarray, shape (L,), int64
        Triangles of a mesh level; for a cloud, its quads times :data:`QUAD_TRIANGLES`
        (the measured cost of a quad in triangles' worth of frame time).
    kinds : tuple of str
        ``"full"``, ``"quadric"`` or ``"billboard"`` per level.
    radius : float
        Bounding-sphere radius about the bounding-box centre, mesh units.
    build_ms : float
        Time it took to build (0 when read from the cache).
    key : str
        The mesh's hash (:func:`mesh_key`).
    ready : bool
        False for the stand-in of a chain still being built (or whose build failed):
        the full mesh alone (:func:`full_only`).
    """

    levels: tuple[Mesh, ...]
    errors: np.ndarray
    triangles: np.ndarray
    kinds: tuple[str, ...]
    radius: float
    build_ms: float = 0.0
    key: str = ""
    ready: bool = True


def full_only(mesh: Mesh, key: str = "") -> LodChain:
    """The stand-in chain of ``mesh`` while its chain is built: the full mesh alone."""
    return LodChain((mesh,), np.zeros(1), np.array([mesh.triangles.shape[0]], np.int64),
                    ("full",), _radius(mesh), 0.0, key, ready=False)


def mesh_key(mesh: Mesh, recipe: str) -> str:
    """SHA-256 of the mesh's arrays and the chain's recipe (hex, 32 characters)."""
    h = hashlib.sha256()
    h.update(f"lod-v{CHAIN_VERSION}:{recipe}".encode())
    for a in (mesh.vertices.astype(np.float64), mesh.polygons.astype(np.int64),
              mesh.counts.astype(np.int64)):
        h.update(str(a.shape).encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:32]


def cache_dir() -> Path:
    """The chain cache folder.

    ``$HOLO_LOD_CACHE`` if set, else ``$XDG_CACHE_HOME/holo-realizer/lod`` (by default
    ``~/.cache/holo-realizer/lod``).
    """
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV])
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "holo-realizer" / "lod"


def _radius(mesh: Mesh) -> float:
    if mesh.n_vertices == 0:
        return 0.0
    centre = (mesh.vertices.min(axis=0) + mesh.vertices.max(axis=0)) / 2
    return float(np.sqrt(((mesh.vertices - centre) ** 2).sum(axis=1).max()))


def _decimated(mesh: Mesh, fractions: tuple[float, ...],
               progress: Progress | None = None) -> list[tuple[Mesh, float]]:
    """The quadric levels of ``mesh`` and their errors, coarser each time, in order.

    ``progress(done, planned)`` is called after each decimation (``planned`` grows
    when a plateau's end is sought).
    """
    try:
        from service.simplify.quadric import decimate
    except ImportError as exc:  # fast-simplification missing
        raise LodError(f"level of detail needs the quadric simplifier: {exc}") from None
    full_tris = mesh.triangles
    count = [0, sum(f * full_tris.shape[0] >= MIN_TRIANGLES for f in fractions)]

    def level(frac: float) -> tuple[Mesh, float, float]:
        v, f, err = decimate(mesh.vertices, full_tris, frac, agg=QUADRIC_AGG)
        count[0] += 1
        count[1] = max(count)
        if progress is not None:
            progress(count[0], count[1])
        return Mesh.from_triangles(v, f, f"{mesh.name}@{f.shape[0]}"), float(err), frac

    out: list[tuple[Mesh, float, float]] = []
    last = full_tris.shape[0]
    for frac in sorted(fractions, reverse=True):
        if frac * full_tris.shape[0] < MIN_TRIANGLES:
            break
        got = level(frac)
        if got[0].n_polygons >= last or got[0].n_polygons == 0:
            continue
        out.append(got)
        last = got[0].n_polygons
    front = _pareto(out)
    return [(m, e) for m, e, _ in _plateau_ends(front, level)]


def _pareto(levels: list) -> list:
    """Only the levels with less error than every coarser one (finest first).

    ``levels``: ``(mesh, error, ...)`` tuples.  A sampled Hausdorff error comes in
    plateaus (one feature sets it over a range of fractions, the bunny's 0.00187
    from 30 % down to 20 % of its triangles); a finer level on a plateau costs more
    for the same predicted error and would never be chosen, so each plateau keeps
    its coarsest level.
    """
    out, best = [], np.inf
    for lv in reversed(levels):
        if lv[1] < best:
            out.append(lv)
            best = lv[1]
    return out[::-1]


def _plateau_ends(front: list, level, jump: float = PLATEAU_JUMP,
                  steps: int = PLATEAU_STEPS) -> list:
    """Each level before an error jump pushed towards its plateau's coarse end.

    Where the next coarser level's error is ``jump`` times this one's or more, the
    fraction between the two is bisected (geometrically, ``steps`` decimations) for
    the fewest triangles that keep this level's error: an object at that jump's
    threshold then draws the fewest triangles its budget allows.

    Parameters
    ----------
    front : list of (Mesh, float, float)
        Levels (mesh, error, fraction), finest first, errors increasing.
    level : callable
        ``level(fraction) -> (Mesh, error, fraction)``.
    """
    out = list(front)
    for i in range(len(out) - 1):
        (_, err, hi), (_, nxt, lo) = out[i], out[i + 1]
        if nxt < jump * err:
            continue
        for _ in range(steps):
            mid = float(np.sqrt(hi * lo))
            got = level(mid)
            if got[1] <= err and got[0].n_polygons < out[i][0].n_polygons:
                out[i], hi = got, mid
            else:
                lo = mid
    return out


def cloud_error(eps: float, diagonal: float, texture_res: int) -> float:
    """Geometric error bound of a billboard cloud, mesh units: ``2 EPS`` + a texel diagonal.

    Every source face corner lies within ``eps`` of its billboard and is shot onto it
    along the plane normal (a move of at most ``eps``); opaque texels are then grown
    by ``CLOUD_DILATE x eps``; a texel is ``diagonal / texture_res`` wide.  The sum of
    those (1.5 EPS + half a texel diagonal) was exceeded on screen (holo-bench lod, the
    bunny: 9 px measured in city-block steps against 7.3 predicted), so the bound is
    widened to 2 EPS + a whole texel diagonal, which held on the three benchmark
    meshes.  What it still leaves out is in ``docs/simplify.md`` (thin parts seen from
    their other side, grazing angles).
    """
    return 2.0 * eps + np.sqrt(2.0) * diagonal / texture_res


def _clouds(mesh: Mesh, settings: LodSettings) -> list[tuple[object, float]]:
    """Billboard-cloud levels of ``mesh`` (most billboards first) with their error bounds."""
    if not settings.cloud_eps:
        return []
    try:
        from service.billboard_render import BillboardObject  # noqa: F401 (drawable?)
        from service.simplify.billboard import build_cloud
    except ImportError:  # billboard clouds not available in this build
        return []
    diagonal = float(np.linalg.norm(mesh.vertices.max(axis=0) - mesh.vertices.min(axis=0)))
    out = []
    for frac in sorted(settings.cloud_eps):
        cloud = build_cloud(mesh.vertices, mesh.triangles, frac * diagonal, settings.texture_res)
        out.append((cloud, cloud_error(float(cloud.eps), diagonal, settings.texture_res)))
    return out


def build_chain(mesh: Mesh, settings: LodSettings | None = None,
                cache: Path | None | bool = True, notes: list | None = None,
                progress: Progress | None = None) -> LodChain:
    """The LOD chain of ``mesh``, read from the cache or built (and then cached).

    Builds of one chain are serialised across processes by a lock file
    (``<key>.lock`` in the cache folder, removed when the build ends): a second
    process asking for a chain being built waits for it and reads the cache instead
    of building it again.  A damaged
    or torn cache file is reported (``notes``, else a :class:`LodCacheWarning`) and
    rebuilt; an unwritable cache folder is reported and the chain used uncached.

    Parameters
    ----------
    mesh : Mesh
    settings : LodSettings, optional
        Its ``fractions`` set the levels.
    cache : Path, True or False
        The cache folder, True for :func:`cache_dir`, False for no cache.
    notes : list of str, optional
        Where to put what went wrong with the cache (instead of warnings: a
        background build's thread must not touch the warnings filters).
    progress : callable, optional
        ``progress(done, planned)`` after each decimation of a build.

    Returns
    -------
    LodChain
    """
    settings = settings or LodSettings()
    key = mesh_key(mesh, settings.recipe)
    folder = cache_dir() if cache is True else (Path(cache) if cache else None)
    if folder is None:
        return _build(mesh, settings, key, progress)
    chain, _problem = _read_cache(folder, key, mesh)
    if chain is not None:
        _drop_stale_lock(folder, key)
        return chain
    return _build_locked(mesh, settings, folder, key, notes, progress)


def _build_locked(mesh: Mesh, settings: LodSettings, folder: Path, key: str,
                  notes: list | None, progress: Progress | None) -> LodChain:
    """Build the chain under its lock file and cache it (see :func:`build_chain`).

    Another process may have built it while this one waited for the lock: then it
    is read from the cache.
    """
    with _build_lock(folder, key):
        chain, problem = _read_cache(folder, key, mesh)  # built meanwhile by another?
        if chain is not None:
            return chain
        if problem:
            _note(notes, f"level-of-detail cache {folder / key}.* is damaged ({problem}); "
                  "rebuilding it")
        chain = _build(mesh, settings, key, progress)
        if len(chain.levels) > 1:
            try:
                write_chain(folder, chain)
            except OSError as exc:  # a read-only or odd cache folder: go on without it
                _note(notes, f"level-of-detail cache not written ({folder}): {exc}")
    return chain


def _note(notes: list | None, message: str) -> None:
    """Report a cache problem: into ``notes`` when given, else as a warning."""
    if notes is None:
        warnings.warn(message, LodCacheWarning, stacklevel=3)
    else:
        notes.append(message)


@contextlib.contextmanager
def _build_lock(folder: Path, key: str) -> Iterator[None]:
    """Hold ``<folder>/<key>.lock`` exclusively (``flock``) while building one chain.

    The file is removed on the way out, while still held, so the cache keeps no lock
    files.  That is race-free with the usual check: a process that opened the file
    before it was removed and got the lock after finds that the path no longer names
    the file it holds (:func:`_lock_path`), and opens the path again.  Where the lock
    file cannot be made (no folder, no ``fcntl``) the build goes on unlocked: at worst
    two processes build the same chain and the later rename wins.  The lock goes with
    the process, so a builder that dies frees it (and its file stays until the next
    build of that chain removes it).
    """
    path = folder / f"{key}.lock"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fh = _lock_path(path, blocking=True)
    except (ImportError, OSError):
        yield
        return
    try:
        yield
    finally:
        _unlink_held(path, fh)


def _lock_path(path: Path, blocking: bool) -> BinaryIO | None:
    """Open ``path`` and ``flock`` it exclusively, making sure the path still names it.

    Returns the open file holding the lock, or None when ``blocking`` is false and
    another process holds it.  Raises ImportError without ``fcntl``, OSError when the
    file cannot be opened.
    """
    import fcntl

    while True:
        fh = open(path, "ab")  # noqa: SIM115 (returned, holding the lock)
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | (0 if blocking else fcntl.LOCK_NB))
        except BlockingIOError:
            fh.close()
            return None
        try:
            if os.path.samestat(os.fstat(fh.fileno()), os.stat(path)):
                return fh
        except FileNotFoundError:  # removed by the holder we waited for
            pass
        fh.close()  # a file no longer at the path: lock the one that is there now


def _unlink_held(path: Path, fh: BinaryIO) -> None:
    """Remove a lock file this process holds, then release it."""
    with contextlib.suppress(OSError):
        path.unlink()
    fh.close()


def _drop_stale_lock(folder: Path, key: str) -> None:
    """Remove a ``<key>.lock`` left beside a cached chain, unless a process holds it.

    A builder that died leaves its file, and so did versions before the lock files
    were removed.
    """
    path = folder / f"{key}.lock"
    if not path.exists():
        return
    with contextlib.suppress(ImportError, OSError):
        fh = _lock_path(path, blocking=False)
        if fh is not None:
            _unlink_held(path, fh)


def _build(mesh: Mesh, settings: LodSettings, key: str,
           progress: Progress | None = None) -> LodChain:
    """Build the chain of ``mesh`` (no cache)."""
    t0 = time.perf_counter()
    n = mesh.triangles.shape[0]
    levels = _decimated(mesh, settings.fractions, progress) if n else []
    clouds = _clouds(mesh, settings) if n >= MIN_TRIANGLES else []
    errors = np.maximum.accumulate(np.array([0.0] + [e for _, e in levels]))
    parts = ([(mesh, 0.0, n, "full")]
             + [(m, e, m.n_polygons, "quadric") for (m, _), e in zip(levels, errors[1:],
                                                                      strict=True)]
             + [(c, e, QUAD_TRIANGLES * c.n_billboards, "billboard") for c, e in clouds])
    parts = parts[:1] + sorted(parts[1:], key=lambda p: -p[2])  # dearest first (stable)
    return LodChain(
        levels=tuple(p[0] for p in parts),
        errors=np.array([p[1] for p in parts], np.float64),
        triangles=np.array([p[2] for p in parts], np.int64),
        kinds=tuple(p[3] for p in parts),
        radius=_radius(mesh),
        build_ms=(time.perf_counter() - t0) * 1e3,
        key=key,
    )


def write_chain(folder: Path, chain: LodChain) -> None:
    """Write a chain's cache files.

    ``<key>.npz`` holds mesh levels 1.. as ``vertices_k``, ``faces_k``; each billboard
    level k is ``<key>.b<k>.hbc``; the header ``<key>.json`` comes last.  Written to
    temporary names and renamed, so a reader never sees half a file.
    """
    folder.mkdir(parents=True, exist_ok=True)
    arrays = {}
    for k, m in enumerate(chain.levels[1:], start=1):
        if chain.kinds[k] == "billboard":
            from service.simplify.cloud_file import save_cloud

            tmp_cloud = folder / f".{chain.key}.b{k}.{os.getpid()}.tmp.hbc"
            save_cloud(m, tmp_cloud)
            os.replace(tmp_cloud, folder / f"{chain.key}.b{k}.hbc")
            continue
        arrays[f"vertices_{k}"] = m.vertices
        arrays[f"faces_{k}"] = m.triangles
    header = {
        "format": "holo-lod-chain", "version": CHAIN_VERSION, "key": chain.key,
        "levels": len(chain.levels), "kinds": list(chain.kinds),
        "errors": chain.errors.tolist(), "triangles": chain.triangles.tolist(),
        "radius": chain.radius, "build_ms": round(chain.build_ms, 3),
    }
    npz, js = folder / f"{chain.key}.npz", folder / f"{chain.key}.json"
    tmp = folder / f".{chain.key}.{os.getpid()}.tmp.npz"
    with open(tmp, "wb") as fh:
        np.savez(fh, **arrays)
    os.replace(tmp, npz)
    tmp_js = folder / f".{chain.key}.{os.getpid()}.tmp.json"
    tmp_js.write_text(json.dumps(header))
    os.replace(tmp_js, js)


def read_chain(folder: Path, key: str, mesh: Mesh) -> LodChain | None:
    """The cached chain of ``mesh`` under ``key``, or None if absent or damaged.

    A bad cache file is never an error: :func:`build_chain` reports it and rebuilds.
    """
    return _read_cache(folder, key, mesh)[0]


def _read_cache(folder: Path, key: str, mesh: Mesh) -> tuple[LodChain | None, str]:
    """``(chain, "")``, ``(None, "")`` when not cached, or ``(None, what is wrong)``."""
    npz, js = folder / f"{key}.npz", folder / f"{key}.json"
    have = (npz.is_file(), js.is_file())
    if have == (False, False):
        return None, ""
    if not all(have):  # the header is written last: a write cut short, or a file deleted
        return None, f"{(js if have[0] else npz).name} is missing"
    try:
        return _parse_cache(folder, key, mesh, json.loads(js.read_text())), ""
    except (OSError, ValueError, KeyError, TypeError, IndexError, ImportError, HoloError,
            EOFError, zipfile.BadZipFile) as exc:
        return None, f"{type(exc).__name__}: {exc}"[:200]


def _parse_cache(folder: Path, key: str, mesh: Mesh, head: dict) -> LodChain:
    """The chain from its header and arrays; ValueError (or another) when they disagree."""
    if not isinstance(head, dict) or head.get("version") != CHAIN_VERSION or head.get("key") != key:
        raise ValueError("the header is not this chain's (format version or key differ)")
    n, kinds = int(head["levels"]), tuple(head["kinds"])
    levels: list = [mesh]
    data = read_npz(folder / f"{key}.npz")
    for k in range(1, n):
        if kinds[k] == "billboard":
            from service.simplify.cloud_file import load_cloud

            levels.append(load_cloud(folder / f"{key}.b{k}.hbc"))
            continue
        levels.append(Mesh.from_triangles(data[f"vertices_{k}"], data[f"faces_{k}"],
                                          f"{mesh.name}@{k}"))
    errors = np.asarray(head["errors"], np.float64)
    tris = np.asarray(head["triangles"], np.int64)
    meshes = np.array([kind != "billboard" for kind in kinds])
    if (errors.shape != (n,) or tris.shape != (n,) or len(kinds) != n
            or not np.all(np.diff(errors[meshes]) >= 0)):
        raise ValueError("the header's levels, errors and triangles disagree")
    return LodChain(tuple(levels), errors, tris, kinds, float(head["radius"]), 0.0, key)


def pixels_per_unit(display: DisplaySettings) -> float:
    """Largest pixels per world unit of any zone's parallel projection (see module doc).

    Zone ``k`` maps a displacement ``d`` to ``(d_x - d_z t_k, d_y) / s``; its largest
    stretch is ``sqrt(1 + t_k^2) / s``, the same at every depth.
    """
    t = float(np.abs(display.shears()).max()) if display.zones else 0.0
    return float(np.sqrt(1.0 + t * t) / display.pixel_size)


def select_levels(
    errors: np.ndarray,
    ppu: np.ndarray | float,
    error_px: float,
    previous: np.ndarray | None = None,
    hysteresis: float = 0.25,
) -> tuple[np.ndarray, np.ndarray]:
    """Each object's level: the cheapest (last) whose predicted error is within budget.

    Levels are ordered by cost, dearest (the full mesh) first; their errors need not
    grow with the index.

    Parameters
    ----------
    errors : ndarray, shape (N, L), float64
        Geometric error of each object's levels in world units (mesh error x scale),
        ``errors[:, 0] == 0``; ``inf`` past a chain's end.
    ppu : float or ndarray, shape (N,)
        Pixels per world unit for each object.
    error_px : float
    previous : ndarray, shape (N,), int64, optional
        Last frame's levels (-1: none) for the hysteresis.
    hysteresis : float

    Returns
    -------
    level : ndarray, shape (N,), int64
    predicted : ndarray, shape (N,), float64
        Predicted screen error of the chosen level, pixels.
    """
    pred = errors * np.asarray(ppu, np.float64).reshape(-1, 1)
    n, width = pred.shape
    rows = np.arange(n)
    # the cheapest (last) level within the bound; level 0 (error 0) always is.  An
    # object with a level already coarsens only under the stricter bound; a new one
    # (no previous level) has nothing to flicker from and takes the whole budget
    fresh = np.ones(n, np.bool_) if previous is None else np.asarray(previous) < 0
    bound = np.where(fresh, error_px, error_px * (1.0 - hysteresis))
    within = pred <= bound[:, None]
    level = width - 1 - np.argmax(within[:, ::-1], axis=1)
    if previous is not None:
        prev = np.clip(previous, 0, pred.shape[1] - 1)
        keep = ~fresh & (prev > level) & (pred[rows, prev] <= error_px)
        level = np.where(keep, prev, level)
    return level.astype(np.int64), pred[rows, level]


def degrade_to_budget(
    level: np.ndarray, triangles: np.ndarray, priority: np.ndarray, max_triangles: float,
    last: np.ndarray | None = None,
) -> np.ndarray:
    """Step objects to coarser levels, lowest ``priority`` first, until under a budget.

    Parameters
    ----------
    level : ndarray, shape (N,), int64
    triangles : ndarray, shape (N, L), int64
        Triangles of each object's levels; a chain's end repeats its last level.
    priority : ndarray, shape (N,)
        Lower is degraded first (small on screen, far).
    max_triangles : float
    last : ndarray, shape (N,), int64, optional
        Each object's coarsest allowed level (default the table's last column).

    Returns
    -------
    ndarray, shape (N,), int64
    """
    level = level.copy()
    rows = np.arange(level.size)
    last = np.full(level.size, triangles.shape[1] - 1) if last is None else last
    order = np.argsort(priority, kind="stable")
    for _ in range(triangles.shape[1]):
        total = triangles[rows, level].sum()
        if total <= max_triangles:
            break
        nxt = np.maximum(np.minimum(level + 1, last), level)
        saving = (triangles[rows, level] - triangles[rows, nxt])[order]
        need = np.searchsorted(np.cumsum(saving), total - max_triangles) + 1
        step = order[: min(need, order.size)]
        level[step] = nxt[step]
    return level


@dataclass
class FrameCost:
    """Measured cost model of one renderer's frames: ``ms = fixed_ms + per_triangle x T``.

    Fitted by least squares to the last ``window`` frames' (triangles, milliseconds)
    as the renderer measured them (:meth:`observe`; :func:`fit_cost`): far outliers
    dropped (a frame slowed by another process), the fixed part at most the cheapest
    frame's cost.  Until the frames span triangle counts at least 25 % apart
    (or when the fit says triangles cost nothing) the model is proportional,
    ``ms = per_triangle x T`` with the median of the frames' ratios: with a time
    budget that changes the triangle count, so the next frames span a range.

    Attributes
    ----------
    window : int
        Frames kept.
    samples : list of (int, float)
        (triangles, ms) of the frames kept, oldest first.
    fixed_ms, per_triangle : float
        The fitted line (0 until a frame is observed).
    skip_first : bool
        Leave out the first frame observed: it pays one-off costs (first calls into
        the kernels, first touch of the buffers); in the service a first render of
        the bunny scene measured 12 us per triangle against 2-5 after it, and the
        budget degraded a frame for it.
    """

    window: int = 32
    samples: list = field(default_factory=list)
    fixed_ms: float = 0.0
    per_triangle: float = 0.0
    skip_first: bool = True

    @property
    def ready(self) -> bool:
        """Whether a frame has been measured."""
        return self.per_triangle > 0

    def observe(self, triangles: int, ms: float) -> None:
        """Add a frame's triangles and milliseconds and refit."""
        if not (triangles > 0 and np.isfinite(ms) and ms > 0):
            return
        if self.skip_first:  # a cold frame: first calls, first touch of its buffers
            self.skip_first = False
            return
        self.samples.append((int(triangles), float(ms)))
        del self.samples[:-self.window]
        self.fixed_ms, self.per_triangle = fit_cost(np.array(self.samples, np.float64))

    def predict(self, triangles: float) -> float:
        """Predicted milliseconds of a frame of ``triangles`` triangles."""
        return self.fixed_ms + self.per_triangle * triangles

    def max_triangles(self, budget_ms: float) -> float:
        """Most triangles a frame may have to take at most ``budget_ms`` (0 if none)."""
        return max(budget_ms - self.fixed_ms, 0.0) / self.per_triangle

    def as_dict(self) -> dict:
        """The model as the LOD report carries it."""
        return {"fixed_ms": round(self.fixed_ms, 3),
                "us_per_triangle": round(self.per_triangle * 1e3, 5),
                "frames": len(self.samples)}


def fit_cost(samples: np.ndarray) -> tuple[float, float]:
    """``(fixed_ms, ms_per_triangle)`` fitted to frames (see :class:`FrameCost`).

    A least-squares line; with 8 frames or more, those over three median deviations
    off it are dropped and it is fitted again.  The fixed part is then held to
    ``[0, the cheapest frame's ms]`` (no frame can cost less than the fixed part: on
    a loaded machine a few slow frames can otherwise tilt the line into a fixed cost
    larger than whole frames measured) and the slope refitted through it.

    Parameters
    ----------
    samples : ndarray, shape (N, 2), float64
        Triangles and milliseconds per frame, N >= 1, triangles > 0.
    """
    t, ms = samples[:, 0], samples[:, 1]
    if len(t) >= 2 and t.max() >= 1.25 * t.min():
        keep = np.ones(len(t), np.bool_)
        b, a = np.polyfit(t, ms, 1)
        if len(t) >= 8:  # enough frames to tell an outlier from the line
            resid = np.abs(ms - (a + b * t))
            new = resid <= 3.0 * 1.4826 * (float(np.median(resid)) or 1e-9)
            if new.sum() >= 6 and t[new].max() >= 1.25 * t[new].min():
                keep = new
                b, a = np.polyfit(t[keep], ms[keep], 1)
        a = min(max(float(a), 0.0), float(ms[keep].min()))
        b = float(((ms[keep] - a) * t[keep]).sum() / (t[keep] ** 2).sum())
        if b > 0 and _slope_known(t[keep], ms[keep], a, b):
            return a, b
    return 0.0, float(np.median(ms / t))


def _slope_known(t: np.ndarray, ms: np.ndarray, a: float, b: float) -> bool:
    """Whether the frames pin the slope down: its standard error under 25 % of it.

    Frames of nearly one triangle count on a busy machine give a line whose slope is
    noise (the service measured 9-12 us per triangle against 2 from a wider spread);
    the proportional model is right near the frames measured, which is where the
    budget's next choice lies, and the frames it causes widen the spread.
    """
    n = len(t)
    if n < 3:
        return True  # two frames 25 % apart: no noise estimate, take the line
    resid = ms - (a + b * t)
    spread = float(((t - t.mean()) ** 2).sum())
    se = float(np.sqrt((resid ** 2).sum() / (n - 2) / spread)) if spread > 0 else np.inf
    return se < 0.25 * b


@dataclass
class LodState:
    """What level of detail keeps between frames of one renderer.

    Chains by mesh identity (and by mesh hash, for the same mesh arriving as a new
    object, as each service job's scene does), last levels per object (hysteresis),
    the measured cost model of the frames (:class:`FrameCost`, for ``budget_ms``;
    reset when the display changes), and one scene whose objects are replaced each
    frame, so the flattened scene's static parts stay cached while no level changes.

    With ``background`` a chain that is not in the cache is built by a
    :class:`ChainBuilds` thread while frames draw that object's full mesh (exact,
    slower); the first frame after it is done uses it.  Without (the default), the
    frame that first needs a chain builds it (``progress(mesh name, done, planned)``
    hears how far it got) and its cache problems go to ``notes``.
    """

    chains: dict = field(default_factory=dict)
    previous: np.ndarray | None = None
    names: tuple = ()
    cost: FrameCost = field(default_factory=FrameCost)
    scene: Scene | None = None
    cache: Path | None | bool = True
    display_key: tuple = ()
    background: bool = False
    progress: Callable[[str, int, int], None] | None = None
    builds: ChainBuilds | None = None
    #: cache problems met by chains built in the frame (the background's: ``builds``)
    notes: deque = field(default_factory=lambda: deque(maxlen=NOTES_KEPT))
    _by_key: OrderedDict = field(default_factory=OrderedDict)
    _last: tuple | None = None

    def chain(self, mesh: Mesh, settings: LodSettings) -> LodChain:
        """The chain of ``mesh``: read or built once per renderer, or its stand-in.

        With ``background`` the stand-in (:func:`full_only`, ``ready`` False) is
        returned while the chain is built; without, the chain is built here.
        """
        got = self.chains.get(id(mesh))
        mine = got is not None and got[0] is mesh and got[2] == settings.recipe
        if mine and got[1].ready:
            return got[1]
        key = got[1].key if mine else mesh_key(mesh, settings.recipe)
        chain = self._by_key.get(key)
        if chain is None:
            chain = self._fetch(mesh, settings, key)
            if chain.ready:
                self._by_key[key] = chain
                while len(self._by_key) > CHAINS_KEPT:
                    self._by_key.popitem(last=False)
        else:
            self._by_key.move_to_end(key)
        if chain.levels[0] is not mesh:  # the same mesh as another object: draw its own
            chain = replace(chain, levels=(mesh, *chain.levels[1:]))
        self.chains[id(mesh)] = (mesh, chain, settings.recipe)
        return chain

    def _fetch(self, mesh: Mesh, settings: LodSettings, key: str) -> LodChain:
        """A chain not in memory: built here, or (background) from the cache or a stand-in."""
        if not self.background:
            report = self.progress
            tell = None if report is None else (lambda d, n: report(mesh.name, d, n))
            notes: list[str] = []
            try:
                return build_chain(mesh, settings, self.cache, notes, tell)
            finally:
                self.notes.extend(notes)
        if self.builds is None:
            from service.lod_build import ChainBuilds  # it imports this module

            self.builds = ChainBuilds(self.cache)
        done = self.builds.take(key)
        if done is not None:
            return done
        folder = cache_dir() if self.cache is True else (Path(self.cache) if self.cache else None)
        cached = read_chain(folder, key, mesh) if folder is not None else None
        if cached is not None:
            return cached
        self.builds.submit(key, mesh, settings)  # no-op once built, failed or queued
        return full_only(mesh, key)

    def close(self, timeout_s: float = 10.0) -> None:
        """End the background builds: a running build child is stopped (SIGTERM).

        A chain it had not finished is built again by the next renderer that needs it.
        """
        if self.builds is not None:
            self.builds.close(timeout_s)

    def chain_status(self, chains: list) -> dict:
        """``ready``, ``building`` and ``failed`` counts of distinct chains, and ``notes``."""
        failed = self.builds.failed if self.builds is not None else {}
        ready = sum(c.ready for c in chains)
        bad = sum(not c.ready and c.key in failed for c in chains)
        out = {"ready": ready, "building": len(chains) - ready - bad, "failed": bad}
        notes = list(self.notes) + (list(self.builds.notes) if self.builds is not None else [])
        if notes:
            out["notes"] = notes[-NOTES_KEPT:]
        return out

    def observe(self, triangles: int, ms: float) -> None:
        """A frame's triangles and render milliseconds (the LOD step not included)."""
        self.cost.observe(triangles, ms)

    def _tables(self, scene: Scene, settings: LodSettings) -> dict:
        """Per-object chain tables, rebuilt only when the scene's meshes change."""
        generation = self.builds.generation if self.builds is not None else 0
        key = (tuple(id(o.mesh) for o in scene.objects), settings.recipe, generation)
        if getattr(self, "_tab_key", None) == key:
            return self._tab
        chains, which, seen = [], [], {}
        for o in scene.objects:
            j = seen.setdefault(id(o.mesh), len(chains))
            if j == len(chains):
                chains.append(self.chain(o.mesh, settings))
            which.append(j)
        # only this scene's meshes: a service job's scene brings new mesh objects each time
        self.chains = {k: v for k, v in self.chains.items() if k in seen}
        width = max((len(c.levels) for c in chains), default=1)
        err = np.full((len(chains), width), np.inf)
        tris = np.zeros((len(chains), width), np.int64)
        for j, c in enumerate(chains):
            err[j, : len(c.levels)] = c.errors
            tris[j] = c.triangles[np.minimum(np.arange(width), len(c.levels) - 1)]
        cloud = np.zeros((len(chains), width), np.bool_)
        for j, c in enumerate(chains):
            cloud[j, : len(c.levels)] = [k == "billboard" for k in c.kinds]
        w = np.asarray(which, np.int64)
        n_levels = np.array([len(c.levels) for c in chains], np.int64)
        n_meshes = np.array([sum(k != "billboard" for k in c.kinds) for c in chains], np.int64)
        self._tab = {"chains": chains, "which": w, "errors": err[w], "triangles": tris[w],
                     "radius": np.array([c.radius for c in chains])[w],
                     "mesh_errors": np.where(cloud, np.inf, err)[w],
                     "last": (n_levels - 1)[w], "last_mesh": (n_meshes - 1)[w],
                     "ready": np.array([c.ready for c in chains], np.bool_)[w],
                     "status": self.chain_status(chains)}
        self._tab_key = key
        return self._tab

    def apply(self, scene: Scene, display: DisplaySettings, settings: LodSettings,
              clouds: bool = True) -> tuple[Scene, dict]:
        """The scene with each object's chosen level, and the frame's LOD report.

        ``clouds``: whether billboard-cloud levels may be chosen (the renderer draws
        ``Scene.billboards``); the Galilean path (:mod:`service.galilean.motion_field`)
        draws meshes only and passes False.

        Returns
        -------
        scene : Scene
            Objects carry their chosen level's mesh (the same materials, placement
            and motion); kept between frames so the flattening's cache holds.
        report : dict
            ``levels`` and ``predicted_px`` per object, ``triangles`` (chosen) and
            ``triangles_full``, ``over_error`` (objects degraded past the budget by
            ``budget_ms``), ``billboards`` (objects drawn as their billboard cloud),
            ``select_ms`` (choosing only), ``error_px``, ``chains`` (the scene's
            distinct chains ``ready``, ``building`` and ``failed``, and ``notes``:
            the last cache problems and failed builds, when there are any).
        """
        objs = scene.objects
        old = getattr(self, "_tab", None)
        tab = self._tables(scene, settings)
        self._reset_history(objs, old, tab)
        key = (display.zones, display.rows, display.cols, display.pixel_size)
        if key != self.display_key:  # another display: the frames cost something else
            self.cost, self.display_key = FrameCost(), key
        t0 = time.perf_counter_ns()
        ppu = pixels_per_unit(display)
        level, predicted = self._select(objs, tab, ppu, settings, clouds)
        select_ms = (time.perf_counter_ns() - t0) / 1e6
        self.previous = level
        out, boards = self._objects(scene, tab, level)
        self._fill_scene(scene, out, boards)
        return self.scene, self._report(scene, tab, level, predicted, boards, settings,
                                        select_ms, ppu)

    def _report(self, scene: Scene, tab: dict, level: np.ndarray, predicted: np.ndarray,
                boards: list, settings: LodSettings, select_ms: float, ppu: float) -> dict:
        """The frame's LOD report (see :meth:`apply`).

        ``level`` and ``predicted`` (shape (n,)) are :meth:`_select`'s per object.
        """
        rows = np.arange(len(scene.objects))
        report = {
            "error_px": settings.error_px,
            "levels": level.tolist(),
            "predicted_px": np.round(predicted, 4).tolist(),
            "triangles": int(tab["triangles"][rows, level].sum()),
            "triangles_full": int(tab["triangles"][:, 0].sum()),
            "over_error": int((predicted > settings.error_px).sum()),
            "billboards": len(boards) - len(getattr(scene, "billboards", [])),
            "select_ms": round(select_ms, 4),
            "pixels_per_unit": round(ppu, 3),
            "chains": tab["status"],
        }
        if settings.budget_ms is not None:
            report.update(budget_ms=settings.budget_ms, cost_model=self.cost.as_dict(),
                          predicted_ms=(round(self.cost.predict(report["triangles"]), 3)
                                        if self.cost.ready else None))
        return report

    def _reset_history(self, objs: list, old: dict | None, tab: dict) -> None:
        """Forget last frame's levels where they no longer say anything.

        All of them when the objects changed (names or count); those of the objects
        whose chain just arrived (``tab`` ready where ``old`` was not), which had no
        level to flicker from.
        """
        names = tuple(o.name for o in objs)
        if self.previous is None or names != self.names or self.previous.size != len(objs):
            self.previous, self.names = np.full(len(objs), -1, np.int64), names
        elif old is not None and tab is not old and old["ready"].size == len(objs):
            self.previous = np.where(tab["ready"] & ~old["ready"], -1, self.previous)

    def _select(self, objs: list, tab: dict, ppu: float, settings: LodSettings,
                clouds: bool) -> tuple[np.ndarray, np.ndarray]:
        """Each object's level for the error budget, then (``budget_ms``) the time budget.

        Returns
        -------
        level : ndarray, shape (n,), int64
            The chosen level of each of the ``n`` objects.
        predicted : ndarray, shape (n,), float64
            Its predicted screen error in pixels.
        """
        scale = np.fromiter((o.transform.scale for o in objs), np.float64, len(objs))
        errors = tab["errors"] if clouds else tab["mesh_errors"]
        level, predicted = select_levels(errors * scale[:, None], ppu,
                                         settings.error_px, self.previous, settings.hysteresis)
        if settings.budget_ms is not None and self.cost.ready and len(objs):
            level = self._budget(objs, tab, level, scale * ppu, settings.budget_ms, clouds)
            predicted = errors[np.arange(len(objs)), level] * scale * ppu
        return level, predicted

    def _fill_scene(self, scene: Scene, out: list, boards: list) -> None:
        """Put this frame's objects, billboards, lights and ambient in the kept scene."""
        if self.scene is None:
            self.scene = Scene([], [], scene.ambient)
        self.scene.objects, self.scene.lights = out, scene.lights
        self.scene.ambient = scene.ambient
        if boards:
            self.scene.billboards = boards
        elif hasattr(self.scene, "billboards"):
            self.scene.billboards = []

    def _objects(self, scene: Scene, tab: dict, level: np.ndarray) -> tuple[list, list]:
        """The objects at their levels, and the billboards (the scene's, then clouds).

        When the scene's objects are the very same ones as last frame and no level
        changed, last frame's list is handed back (objects are immutable), which
        spares building ~200 objects a frame (0.15 ms of a 0.25 ms LOD step).
        """
        objs = scene.objects
        last = self._last
        if (last is not None and last[4] is tab and len(last[0]) == len(objs)
                and np.array_equal(last[1], level)
                and all(a is b for a, b in zip(last[0], objs, strict=True))
                and not getattr(scene, "billboards", None)):
            return last[2], list(last[3])
        out, boards = [], list(getattr(scene, "billboards", []))
        for o, lv, j in zip(objs, level.tolist(), tab["which"].tolist(), strict=True):
            chain = tab["chains"][j]
            if lv == 0:
                out.append(o)
            elif chain.kinds[lv] == "billboard":
                from service.billboard_render import BillboardObject

                boards.append(BillboardObject(chain.levels[lv], o.material, o.transform, o.name))
            else:
                out.append(SceneObject(chain.levels[lv], o.material, o.transform, o.motion,
                                       o.name))
        self._last = (list(objs), level.copy(), out, list(boards), tab)
        return out, boards

    def _budget(self, objs: list, tab: dict, level: np.ndarray, size_px: np.ndarray,
                budget_ms: float, clouds: bool) -> np.ndarray:
        """The error's levels, degraded to the time budget with a dead band.

        Last frame's degrading is held while its predicted cost stays within
        ``[(1 - 2 BUDGET_BAND), 1] x budget``; over the budget the levels are planned
        again for ``(1 - BUDGET_BAND) x budget``; once the error's own levels fit
        ``(1 - 2 BUDGET_BAND) x budget`` they are taken back.  A frame cost (and a
        model) that wobbles by a few % then moves no object between levels.
        """
        rows = np.arange(level.size)
        cost = lambda lv: self.cost.predict(tab["triangles"][rows, lv].sum())  # noqa: E731
        held = np.maximum(level, self.previous)  # last frame's degrading kept
        if cost(held) > budget_ms:
            return self._degrade(objs, tab, level, size_px,
                                 (1 - BUDGET_BAND) * budget_ms, clouds)
        return level if cost(level) <= (1 - 2 * BUDGET_BAND) * budget_ms else held

    def _degrade(self, objs: list, tab: dict, level: np.ndarray, size_px: np.ndarray,
                 budget_ms: float, clouds: bool) -> np.ndarray:
        """Levels stepped coarser until the cost model predicts ``budget_ms`` or less.

        The smallest on screen (chain radius x scale x pixels per unit) go first and,
        among equals, the farthest (largest ``-z``).
        """
        depth = -np.fromiter((o.transform.position[2] for o in objs), np.float64, len(objs))
        order = np.lexsort((-depth, tab["radius"] * size_px))
        priority = np.empty(len(objs))
        priority[order] = np.arange(len(objs))
        return degrade_to_budget(level, tab["triangles"], priority,
                                 self.cost.max_triangles(budget_ms),
                                 tab["last"] if clouds else tab["last_mesh"])
