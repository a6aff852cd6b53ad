"""A mesh's chain of representations (:class:`LodChain`), each with its geometric error.

The full mesh, quadric-decimated levels and billboard clouds, dearest first.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass

import numpy as np

from service.lod.settings import (
    CHAIN_VERSION,
    COLOUR_ANGLES,
    MIN_TRIANGLES,
    PLATEAU_JUMP,
    PLATEAU_STEPS,
    QUAD_TRIANGLES,
    QUADRIC_AGG,
    LodError,
    LodSettings,
    Progress,
)
from service.render.mesh import Mesh


@dataclass(frozen=True)
class LodChain:
    """A mesh's representations, finest (the full mesh) first.

    Attributes
    ----------
    levels : tuple of Mesh or BillboardCloud
        Dearest first (by ``triangles``): ``levels[0]`` is the full mesh, then quadric
        meshes (lit with the full mesh's normals: :attr:`Mesh.shading`, carried by
        :mod:`service.simplify.carry`) and billboard clouds
        (:class:`service.simplify.billboard.BillboardCloud`) in order of cost.
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
    turned : ndarray, shape (L, A, 2), float64 or None
        Per level, the share of the full mesh's area whose light normal turns by more
        than each of :data:`COLOUR_ANGLES` (A of them), for per-polygon light and for
        smooth light: what the selector predicts colour error from.  0 for the full
        mesh and for billboard clouds (not counted); None: all 0.
    area : float
        The full mesh's surface area, mesh units squared.
    """

    levels: tuple[Mesh, ...]
    errors: np.ndarray
    triangles: np.ndarray
    kinds: tuple[str, ...]
    radius: float
    build_ms: float = 0.0
    key: str = ""
    ready: bool = True
    turned: np.ndarray | None = None
    area: float = 0.0


def full_only(mesh: Mesh, key: str = "") -> LodChain:
    """The stand-in chain of ``mesh`` while its chain is built: the full mesh alone."""
    return LodChain((mesh,), np.zeros(1), np.array([mesh.triangles.shape[0]], np.int64),
                    ("full",), _radius(mesh), 0.0, key, ready=False)


def surface_area(mesh: Mesh) -> float:
    """Total area of the mesh's triangles, mesh units squared."""
    c = mesh.vertices[mesh.triangles]
    return float(0.5 * np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]),
                                      axis=1).sum())


def mesh_key(mesh: Mesh, recipe: str) -> str:
    """SHA-256 of the mesh's arrays and the chain's recipe (hex, 32 characters)."""
    h = hashlib.sha256()
    h.update(f"lod-v{CHAIN_VERSION}:{recipe}".encode())
    for a in (mesh.vertices.astype(np.float64), mesh.polygons.astype(np.int64),
              mesh.counts.astype(np.int64)):
        h.update(str(a.shape).encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:32]


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
    try:  # deferred: a build child that cannot load the compiled simplifier says so
        from service.simplify.quadric import decimate
    except ImportError as exc:  # fast-simplification missing or broken
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


def _carried(full: Mesh, level: Mesh) -> tuple[Mesh, np.ndarray]:
    """``level`` lit with ``full``'s normals, and its turned shares (:attr:`LodChain.turned`)."""
    from service.simplify.carry import carried_level  # deferred: as _decimated's

    return carried_level(full, level.vertices, level.triangles, level.name,
                         np.radians(COLOUR_ANGLES))


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
    from service.simplify.billboard import build_cloud  # deferred: as _decimated's
    diagonal = float(np.linalg.norm(mesh.vertices.max(axis=0) - mesh.vertices.min(axis=0)))
    out = []
    for frac in sorted(settings.cloud_eps):
        cloud = build_cloud(mesh.vertices, mesh.triangles, frac * diagonal, settings.texture_res)
        out.append((cloud, cloud_error(float(cloud.eps), diagonal, settings.texture_res)))
    return out


def build_uncached(mesh: Mesh, settings: LodSettings, key: str,
           progress: Progress | None = None) -> LodChain:
    """Build the chain of ``mesh`` (no cache)."""
    t0 = time.perf_counter()
    n = mesh.triangles.shape[0]
    levels = _decimated(mesh, settings.fractions, progress) if n else []
    carried = [_carried(mesh, m) for m, _ in levels]
    clouds = _clouds(mesh, settings) if n >= MIN_TRIANGLES else []
    errors = np.maximum.accumulate(np.array([0.0] + [e for _, e in levels]))
    none = np.zeros((len(COLOUR_ANGLES), 2))
    parts = ([(mesh, 0.0, n, "full", none)]
             + [(m, e, m.n_polygons, "quadric", t) for (m, t), e in zip(carried, errors[1:],
                                                                         strict=True)]
             + [(c, e, QUAD_TRIANGLES * c.n_billboards, "billboard", none) for c, e in clouds])
    parts = parts[:1] + sorted(parts[1:], key=lambda p: -p[2])  # dearest first (stable)
    return LodChain(
        levels=tuple(p[0] for p in parts),
        errors=np.array([p[1] for p in parts], np.float64),
        triangles=np.array([p[2] for p in parts], np.int64),
        kinds=tuple(p[3] for p in parts),
        radius=_radius(mesh),
        build_ms=(time.perf_counter() - t0) * 1e3,
        key=key,
        turned=np.array([p[4] for p in parts], np.float64),
        area=surface_area(mesh),
    )
