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
the budget (at the milliseconds per triangle the last frames measured), objects are
stepped to coarser levels, the smallest on screen first and, among equals, the
farthest; such objects are reported ``over_error``.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from service.display import DisplaySettings
from service.errors import HoloError, SettingsError
from service.mesh import Mesh
from service.scene import Scene, SceneObject

#: Triangle fractions of the decimated levels (each level's target, of the full mesh).
DEFAULT_FRACTIONS = (0.5, 0.25, 0.12, 0.06, 0.03, 0.015, 0.007)
#: Bump when the chain's contents or file layout change (old cache files are rebuilt).
CHAIN_VERSION = 1
#: Environment variable naming the cache folder.
CACHE_ENV = "HOLO_LOD_CACHE"
#: Levels smaller than this many triangles are not built.
MIN_TRIANGLES = 8


class LodError(HoloError, ValueError):
    """A level-of-detail chain cannot be built or read."""


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
    """

    error_px: float = 0.5
    enabled: bool = True
    budget_ms: float | None = None
    hysteresis: float = 0.25
    fractions: tuple[float, ...] = DEFAULT_FRACTIONS

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


@dataclass(frozen=True)
class LodChain:
    """A mesh's representations, finest (the full mesh) first.

    Attributes
    ----------
    levels : tuple of Mesh
        ``levels[0]`` is the full mesh.
    errors : ndarray, shape (L,), float64
        Geometric error of each level in mesh units, non-decreasing, ``errors[0] == 0``.
    triangles : ndarray, shape (L,), int64
    kinds : tuple of str
        ``"full"`` or ``"quadric"`` per level.
    radius : float
        Bounding-sphere radius about the bounding-box centre, mesh units.
    build_ms : float
        Time it took to build (0 when read from the cache).
    key : str
        The mesh's hash (:func:`mesh_key`).
    """

    levels: tuple[Mesh, ...]
    errors: np.ndarray
    triangles: np.ndarray
    kinds: tuple[str, ...]
    radius: float
    build_ms: float = 0.0
    key: str = ""


def mesh_key(mesh: Mesh, fractions: tuple[float, ...]) -> str:
    """SHA-256 of the mesh's arrays and the chain's recipe (hex, 32 characters)."""
    h = hashlib.sha256()
    h.update(f"lod-v{CHAIN_VERSION}:{','.join(f'{f:.6g}' for f in fractions)}".encode())
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


def _decimated(mesh: Mesh, fractions: tuple[float, ...]) -> list[tuple[Mesh, float]]:
    """The quadric levels of ``mesh`` and their errors, coarser each time, in order."""
    try:
        from service.simplify.quadric import decimate
    except ImportError as exc:  # fast-simplification missing
        raise LodError(f"level of detail needs the quadric simplifier: {exc}") from None
    full_tris = mesh.triangles
    out: list[tuple[Mesh, float]] = []
    last = full_tris.shape[0]
    for frac in sorted(fractions, reverse=True):
        if frac * full_tris.shape[0] < MIN_TRIANGLES:
            break
        v, f, err = decimate(mesh.vertices, full_tris, frac)
        if f.shape[0] >= last or f.shape[0] == 0:
            continue
        out.append((Mesh.from_triangles(v, f, f"{mesh.name}@{f.shape[0]}"), float(err)))
        last = f.shape[0]
    return out


def build_chain(mesh: Mesh, settings: LodSettings | None = None,
                cache: Path | None | bool = True) -> LodChain:
    """The LOD chain of ``mesh``, read from the cache or built (and then cached).

    Parameters
    ----------
    mesh : Mesh
    settings : LodSettings, optional
        Its ``fractions`` set the levels.
    cache : Path, True or False
        The cache folder, True for :func:`cache_dir`, False for no cache.

    Returns
    -------
    LodChain
    """
    fractions = (settings or LodSettings()).fractions
    key = mesh_key(mesh, fractions)
    folder = cache_dir() if cache is True else (Path(cache) if cache else None)
    if folder is not None:
        chain = read_chain(folder, key, mesh)
        if chain is not None:
            return chain
    t0 = time.perf_counter()
    levels = _decimated(mesh, fractions) if mesh.triangles.shape[0] else []
    errors = np.maximum.accumulate(np.array([0.0] + [e for _, e in levels]))
    chain = LodChain(
        levels=(mesh, *(m for m, _ in levels)),
        errors=errors,
        triangles=np.array([mesh.triangles.shape[0]] + [m.n_polygons for m, _ in levels],
                           np.int64),
        kinds=("full",) + ("quadric",) * len(levels),
        radius=_radius(mesh),
        build_ms=(time.perf_counter() - t0) * 1e3,
        key=key,
    )
    if folder is not None and len(chain.levels) > 1:
        write_chain(folder, chain)
    return chain


def write_chain(folder: Path, chain: LodChain) -> None:
    """Write ``<key>.npz`` (levels 1.. as ``vertices_k``, ``faces_k``) and ``<key>.json``.

    Written to temporary names and renamed, so a reader never sees half a file.
    """
    folder.mkdir(parents=True, exist_ok=True)
    arrays = {}
    for k, m in enumerate(chain.levels[1:], start=1):
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
    """The cached chain of ``mesh`` under ``key``, or None if absent, stale or corrupt.

    A bad cache file is never an error: the chain is rebuilt and the file rewritten.
    """
    npz, js = folder / f"{key}.npz", folder / f"{key}.json"
    if not (npz.is_file() and js.is_file()):
        return None
    try:
        head = json.loads(js.read_text())
        if head.get("version") != CHAIN_VERSION or head.get("key") != key:
            return None
        n = int(head["levels"])
        levels = [mesh]
        with np.load(npz, allow_pickle=False) as data:
            for k in range(1, n):
                levels.append(Mesh.from_triangles(data[f"vertices_{k}"], data[f"faces_{k}"],
                                                  f"{mesh.name}@{k}"))
        errors = np.asarray(head["errors"], np.float64)
        tris = np.asarray(head["triangles"], np.int64)
        if errors.shape != (n,) or tris.shape != (n,) or not np.all(np.diff(errors) >= 0):
            return None
        return LodChain(tuple(levels), errors, tris, tuple(head["kinds"]),
                        float(head["radius"]), 0.0, key)
    except (OSError, ValueError, KeyError, TypeError, HoloError, EOFError, zipfile.BadZipFile):
        return None


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
    """Each object's level: the coarsest whose predicted error is within budget.

    Parameters
    ----------
    errors : ndarray, shape (N, L), float64
        Geometric error of each object's levels in world units (mesh error x scale),
        non-decreasing along a row, ``errors[:, 0] == 0``; ``inf`` past a chain's end.
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
    n = pred.shape[0]
    rows = np.arange(n)
    coarsen = (pred <= error_px * (1.0 - hysteresis)).sum(axis=1) - 1
    level = np.maximum(coarsen, 0)
    if previous is not None:
        prev = np.clip(previous, 0, pred.shape[1] - 1)
        keep = (previous >= 0) & (prev > level) & (pred[rows, prev] <= error_px)
        level = np.where(keep, prev, level)
    return level.astype(np.int64), pred[rows, level]


def degrade_to_budget(
    level: np.ndarray, triangles: np.ndarray, priority: np.ndarray, max_triangles: float
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

    Returns
    -------
    ndarray, shape (N,), int64
    """
    level = level.copy()
    rows = np.arange(level.size)
    order = np.argsort(priority, kind="stable")
    for _ in range(triangles.shape[1]):
        total = triangles[rows, level].sum()
        if total <= max_triangles:
            break
        nxt = np.minimum(level + 1, triangles.shape[1] - 1)
        saving = (triangles[rows, level] - triangles[rows, nxt])[order]
        need = np.searchsorted(np.cumsum(saving), total - max_triangles) + 1
        step = order[: min(need, order.size)]
        level[step] = nxt[step]
    return level


@dataclass
class LodState:
    """What level of detail keeps between frames of one renderer.

    Chains by mesh identity, last levels per object (hysteresis), the milliseconds per
    triangle the last frames measured (budget), and one scene whose objects are
    replaced each frame, so the flattened scene's static parts stay cached while no
    level changes.
    """

    chains: dict = field(default_factory=dict)
    previous: np.ndarray | None = None
    names: tuple = ()
    ms_per_triangle: float = 0.0
    scene: Scene | None = None
    cache: Path | None | bool = True

    def chain(self, mesh: Mesh, settings: LodSettings) -> LodChain:
        """The chain of ``mesh`` (built or read once per renderer)."""
        got = self.chains.get(id(mesh))
        if got is None or got[0] is not mesh:
            got = self.chains[id(mesh)] = (mesh, build_chain(mesh, settings, self.cache))
        return got[1]

    def observe(self, triangles: int, ms: float) -> None:
        """Fold a frame's triangles and render milliseconds into the cost estimate."""
        if triangles > 0 and ms > 0:
            rate = ms / triangles
            self.ms_per_triangle = rate if not self.ms_per_triangle else (
                0.7 * self.ms_per_triangle + 0.3 * rate)

    def _tables(self, scene: Scene, settings: LodSettings) -> dict:
        """Per-object chain tables, rebuilt only when the scene's meshes change."""
        key = tuple(id(o.mesh) for o in scene.objects)
        if getattr(self, "_tab_key", None) == key and self._tab_fractions == settings.fractions:
            return self._tab
        chains, which, seen = [], [], {}
        for o in scene.objects:
            j = seen.setdefault(id(o.mesh), len(chains))
            if j == len(chains):
                chains.append(self.chain(o.mesh, settings))
            which.append(j)
        width = max((len(c.levels) for c in chains), default=1)
        err = np.full((len(chains), width), np.inf)
        tris = np.zeros((len(chains), width), np.int64)
        for j, c in enumerate(chains):
            err[j, : len(c.levels)] = c.errors
            tris[j] = c.triangles[np.minimum(np.arange(width), len(c.levels) - 1)]
        w = np.asarray(which, np.int64)
        self._tab = {"chains": chains, "which": w, "errors": err[w], "triangles": tris[w],
                     "radius": np.array([c.radius for c in chains])[w]}
        self._tab_key, self._tab_fractions = key, settings.fractions
        return self._tab

    def apply(self, scene: Scene, display: DisplaySettings,
              settings: LodSettings) -> tuple[Scene, dict]:
        """The scene with each object's chosen level, and the frame's LOD report.

        Returns
        -------
        scene : Scene
            Objects carry their chosen level's mesh (the same materials, placement
            and motion); kept between frames so the flattening's cache holds.
        report : dict
            ``levels`` and ``predicted_px`` per object, ``triangles`` (chosen) and
            ``triangles_full``, ``over_error`` (objects degraded past the budget by
            ``budget_ms``), ``select_ms`` (choosing only), ``error_px``.
        """
        objs = scene.objects
        tab = self._tables(scene, settings)
        names = tuple(o.name for o in objs)
        if self.previous is None or names != self.names or self.previous.size != len(objs):
            self.previous, self.names = np.full(len(objs), -1, np.int64), names
        t0 = time.perf_counter_ns()
        scale = np.fromiter((o.transform.scale for o in objs), np.float64, len(objs))
        ppu = pixels_per_unit(display)
        level, predicted = select_levels(tab["errors"] * scale[:, None], ppu,
                                         settings.error_px, self.previous, settings.hysteresis)
        if settings.budget_ms is not None and self.ms_per_triangle > 0 and len(objs):
            depth = -np.fromiter((o.transform.position[2] for o in objs), np.float64, len(objs))
            order = np.lexsort((-depth, tab["radius"] * scale * ppu))
            priority = np.empty(len(objs))
            priority[order] = np.arange(len(objs))
            level = degrade_to_budget(level, tab["triangles"], priority,
                                      settings.budget_ms / self.ms_per_triangle)
            predicted = tab["errors"][np.arange(len(objs)), level] * scale * ppu
        select_ms = (time.perf_counter_ns() - t0) / 1e6
        self.previous = level
        out = [o if lv == 0 else SceneObject(tab["chains"][j].levels[lv], o.material,
                                             o.transform, o.motion, o.name)
               for o, lv, j in zip(objs, level.tolist(), tab["which"].tolist(), strict=True)]
        if self.scene is None:
            self.scene = Scene([], [], scene.ambient)
        self.scene.objects, self.scene.lights = out, scene.lights
        self.scene.ambient = scene.ambient
        rows = np.arange(len(objs))
        return self.scene, {
            "error_px": settings.error_px,
            "levels": level.tolist(),
            "predicted_px": np.round(predicted, 4).tolist(),
            "triangles": int(tab["triangles"][rows, level].sum()),
            "triangles_full": int(tab["triangles"][:, 0].sum()),
            "over_error": int((predicted > settings.error_px).sum()),
            "select_ms": round(select_ms, 4),
            "pixels_per_unit": round(ppu, 3),
        }
