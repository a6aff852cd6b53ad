"""Polygon meshes: vertices plus convex polygons, with their triangulation.

A :class:`Mesh` keeps the polygons the thesis works with (for culling, sorting and
per-polygon light) and a fan triangulation of them (for rasterising).  Polygons are
stored padded: ``polygons[p, :counts[p]]`` are the vertex indices of polygon ``p``
in counter-clockwise order seen from the side its normal points to (right-handed,
as OBJ and PLY store them).

The fan triangulation is only right for planar, convex polygons, so building a
mesh checks every polygon of four or more vertices (:func:`polygon_shape_faults`)
and refuses a non-planar, concave or self-intersecting one; the rule and its
tolerance are in ``docs/file-formats.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from service.base.errors import MeshError
from service.normals_kernel import corner_normals_kernel, edges_closed_kernel, newell_normals_kernel


class Shading(NamedTuple):
    """Normals per-polygon light uses instead of a mesh's own face normals.

    A simplified level carries its full mesh's (:mod:`service.simplify.carry`).
    Smooth light (per vertex, per point) keeps the mesh's own :attr:`Mesh.corner_normals`:
    on the bunny they matched the full mesh's smooth light better than carried ones
    (``docs/simplify.md``, "Carried normals").

    Attributes
    ----------
    polygons : ndarray, shape (P, 3), float64
        Unit normal per polygon.
    """

    polygons: np.ndarray


@dataclass(frozen=True)
class Mesh:
    """An indexed polygon mesh.

    Attributes
    ----------
    vertices : ndarray, shape (V, 3), float64
        Vertex positions in object coordinates.
    polygons : ndarray, shape (P, K), int64
        Vertex indices of each polygon, padded with -1 after ``counts[p]`` entries.
    counts : ndarray, shape (P,), int64
        Number of vertices of each polygon (3 or more).
    name : str
        A label for messages.
    repair : MeshRepair or None
        What loading the mesh's file repaired (:mod:`service.mesh_repair`); None for
        a mesh not read from a file.
    shading : Shading or None
        Polygon normals per-polygon light uses (a level of detail carries its full
        mesh's); None: its own.  Its geometry (culling, which side a zone sees)
        always uses :attr:`normals`.
    """

    vertices: np.ndarray
    polygons: np.ndarray
    counts: np.ndarray
    name: str = "mesh"
    repair: Any = field(default=None, repr=False, compare=False)
    shading: Shading | None = field(default=None, repr=False, compare=False)
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        validate(self.vertices, self.polygons, self.counts, self.name)
        if self.shading is not None:
            _check_shading(self.shading, self.n_polygons, self.name)

    @property
    def n_polygons(self) -> int:
        """Number of polygons P."""
        return int(self.polygons.shape[0])

    @property
    def n_vertices(self) -> int:
        """Number of vertices V."""
        return int(self.vertices.shape[0])

    def _fan(self) -> tuple[np.ndarray, np.ndarray]:
        """:func:`fan_triangulate` of the polygons (cached): triangles, their polygons."""
        if "tri" not in self._cache:
            self._cache["tri"] = fan_triangulate(self.polygons, self.counts)
        return self._cache["tri"]

    @property
    def triangles(self) -> np.ndarray:
        """Fan triangulation, shape (T, 3) int64 (cached)."""
        return self._fan()[0]

    @property
    def triangle_polygon(self) -> np.ndarray:
        """Polygon index of each triangle, shape (T,) int64 (cached)."""
        return self._fan()[1]

    @property
    def normals(self) -> np.ndarray:
        """Unit polygon normals in object coordinates, shape (P, 3) (cached)."""
        if "normals" not in self._cache:
            self._cache["normals"] = polygon_normals(self.vertices, self.polygons, self.counts)
        return self._cache["normals"]

    @property
    def shading_normals(self) -> np.ndarray:
        """Unit polygon normals light uses, shape (P, 3): :attr:`shading`'s or :attr:`normals`."""
        return self.normals if self.shading is None else self.shading.polygons

    @property
    def corner_normals(self) -> np.ndarray:
        """Crease-aware smooth normals at triangle corners, shape (T, 3, 3) (cached)."""
        if "corner" not in self._cache:
            self._cache["corner"] = corner_normals(
                self.vertices, self.triangles, self.triangle_polygon, self.normals
            )
        return self._cache["corner"]

    @property
    def is_closed(self) -> bool:
        """Whether the mesh is a closed, consistently wound surface (cached).

        True when every directed edge (a, b) of every polygon appears exactly once
        and its reverse (b, a) appears exactly once too.  A back face of such a
        mesh is always hidden by one of its front faces.
        """
        if "closed" not in self._cache:
            self._cache["closed"] = edges_closed(self.polygons, self.counts, self.n_vertices)
        return self._cache["closed"]

    @classmethod
    def from_polygons(cls, vertices: np.ndarray, polys: list, name: str = "mesh") -> Mesh:
        """Build a mesh from a list of vertex-index sequences of any lengths >= 3."""
        verts = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
        if len(polys) == 0:
            return cls(verts, np.zeros((0, 3), np.int64), np.zeros(0, np.int64), name)
        k = max(len(p) for p in polys)
        arr = np.full((len(polys), k), -1, dtype=np.int64)
        counts = np.empty(len(polys), dtype=np.int64)
        for i, p in enumerate(polys):
            arr[i, : len(p)] = p
            counts[i] = len(p)
        return cls(verts, arr, counts, name)

    @classmethod
    def from_triangles(
        cls, vertices: np.ndarray, triangles: np.ndarray, name: str = "mesh"
    ) -> Mesh:
        """Build a mesh whose polygons are the given triangles, shape (T, 3)."""
        tri = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
        return cls(
            np.asarray(vertices, dtype=np.float64).reshape(-1, 3),
            tri.copy(),
            np.full(tri.shape[0], 3, dtype=np.int64),
            name,
        )


#: Largest vertex coordinate a mesh may have.  A face normal's length takes the
#: fourth power of the coordinates, which overflows float64 from about 1e77 (a mesh
#: at 1e150 rendered blank: every face culled on an infinite normal; at 1e300 it was
#: refused as "degenerate").  1e30 leaves that far behind, and no real mesh comes near.
MAX_COORDINATE = 1e30
#: Most polygons a mesh sent to the service or built from a primitive's parameters
#: may have (``service.net.wire`` refuses larger messages; about 60x the Stanford bunny).
MAX_POLYGONS = 4_000_000


def too_large(vertices: np.ndarray) -> tuple[str, int] | None:
    """The first vertex with a coordinate beyond :data:`MAX_COORDINATE`, or None.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3), finite

    Returns
    -------
    (message, vertex) or None
        ``message`` says the value and the remedy (no file or mesh name).
    """
    if not vertices.size or np.abs(vertices).max() <= MAX_COORDINATE:
        return None
    bad = int(np.argwhere(np.abs(vertices) > MAX_COORDINATE)[0, 0])
    value = float(np.abs(vertices[bad]).max())
    return (f"coordinate {value:g} is beyond {MAX_COORDINATE:g}: normals and areas would "
            "overflow; scale the mesh down", bad)


def validate(vertices: np.ndarray, polygons: np.ndarray, counts: np.ndarray, name: str) -> None:
    """Check shapes, finiteness, index ranges and polygon shapes; raise :class:`MeshError`.

    Polygons of four or more vertices must be planar and convex within
    :func:`shape_tolerance` (see :func:`polygon_shape_faults`).
    """
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise MeshError(f"{name}: vertices must have shape (V, 3), got {vertices.shape}")
    if not np.all(np.isfinite(vertices)):
        bad = int(np.argwhere(~np.isfinite(vertices))[0, 0])
        raise MeshError(f"{name}: vertex {bad} is not finite")
    big = too_large(vertices)
    if big is not None:
        raise MeshError(f"{name}: vertex {big[1]}: {big[0]}")
    if polygons.ndim != 2 or counts.ndim != 1 or polygons.shape[0] != counts.shape[0]:
        raise MeshError(f"{name}: polygons (P, K) and counts (P,) do not match")
    if counts.size and counts.min() < 3:
        bad = int(np.argmin(counts))
        raise MeshError(f"{name}: polygon {bad} has {counts[bad]} vertices; at least 3 needed")
    if counts.size and counts.max() > polygons.shape[1]:
        raise MeshError(f"{name}: a count exceeds the polygon array width")
    k = np.arange(polygons.shape[1])[None, :]
    used = k < counts[:, None]
    idx = polygons[used]
    if idx.size and (idx.min() < 0 or idx.max() >= vertices.shape[0]):
        rows = np.nonzero(np.any(used & ((polygons < 0) | (polygons >= vertices.shape[0])), 1))[0]
        raise MeshError(
            f"{name}: polygon {int(rows[0])} refers to a vertex outside 0..{vertices.shape[0] - 1}"
        )
    faults = polygon_shape_faults(vertices, polygons, counts)
    if faults.polygon.size:
        raise MeshError(f"{name}: {describe_fault(faults)}")


SHAPE_TOL = 1e-5
"""Planarity and convexity tolerance, as a fraction of the mesh's extent.

Mesh-relative rather than polygon-relative: the noise it must absorb (coordinates
stored as float32, or written with six decimals or six significant digits) and what
a deviation does on screen (1e-5 of an object 640 px wide is 0.006 px) both scale
with the mesh, and it stays the same when a mesh is moved or scaled as a whole.
"""

SHAPE_CHUNK = 1 << 18
"""Polygons times corners squared per vectorised step (bounds the temporaries)."""

PLANAR, CONVEX = 1, 2
"""Fault kinds in :class:`ShapeFaults`: off its plane, or outside one of its edges."""


class ShapeFaults(NamedTuple):
    """Polygons that break the planar-and-convex rule, in polygon order.

    Attributes
    ----------
    polygon : ndarray, shape (F,), int64
        Index of each bad polygon.
    kind : ndarray, shape (F,), int64
        ``PLANAR`` (a corner is off the polygon's plane) or ``CONVEX`` (a corner is
        outside the line of one of its edges: concave or self-intersecting).
    corner : ndarray, shape (F,), int64
        Position (0-based, within the polygon) of the corner that deviates most.
    edge : ndarray, shape (F, 2), int64
        For ``CONVEX``, the corners at the ends of the edge it is outside of
        (``-1`` for ``PLANAR``).
    deviation : ndarray, shape (F,), float64
        How far off, in mesh units.
    tolerance : float
        The tolerance used (``SHAPE_TOL`` times the mesh's extent).
    """

    polygon: np.ndarray
    kind: np.ndarray
    corner: np.ndarray
    edge: np.ndarray
    deviation: np.ndarray
    tolerance: float


def shape_tolerance(vertices: np.ndarray) -> float:
    """``SHAPE_TOL`` times the mesh's extent (largest side of its bounding box).

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
    """
    if vertices.shape[0] == 0:
        return 0.0
    return SHAPE_TOL * float(np.max(vertices.max(axis=0) - vertices.min(axis=0)))


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products of broadcast arrays of shape (..., 3) (faster than ``np.cross``)."""
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx], axis=-1)


def _unit(v: np.ndarray) -> np.ndarray:
    """Rows of ``v`` (shape (..., 3)) scaled to length 1; zero rows stay zero."""
    length = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, length, out=np.zeros_like(v), where=length > 0)


def _reference_normals(q: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Each polygon's plane normal, and whether it is degenerate (a line or a point).

    Parameters
    ----------
    q : ndarray, shape (n, k, 3)
        Corners of ``n`` polygons of ``k`` corners each, centred on their mean.
    tol : float

    Returns
    -------
    normal : ndarray, shape (n, 3)
        The Newell normal (unit); where that is much shorter than any convex polygon
        of the same diameter and width would give (a bow-tie's net area is zero), the
        normal of the plane through its diameter and its farthest corner instead.
    degenerate : ndarray, shape (n,), bool
        Every corner within ``tol`` of the line through its two farthest-apart corners.
    """
    n, k, _ = q.shape
    ar = np.arange(n)
    d = q[:, None, :, :] - q[:, :, None, :]  # d[:, j, i] = corner i - corner j
    j, i = np.divmod(np.einsum("njix,njix->nji", d, d).reshape(n, -1).argmax(axis=1), k)
    diam = np.linalg.norm(d[ar, j, i], axis=1)
    off = _cross(d[ar, j], _unit(d[ar, j, i])[:, None, :])  # (n, k, 3) off that line
    width = np.linalg.norm(off, axis=2)
    far = width.argmax(axis=1)
    newell = _cross(q, np.roll(q, -1, axis=1)).sum(axis=1)
    fallback = _cross(d[ar, j, i], d[ar, j, far])
    use_newell = np.linalg.norm(newell, axis=1) >= 0.5 * diam * width[ar, far]
    return _unit(np.where(use_newell[:, None], newell, fallback)), width[ar, far] <= tol


def _deviations(q: np.ndarray, normal: np.ndarray, tol: float) -> tuple[np.ndarray, ...]:
    """Planarity and convexity deviations of polygons against given plane normals.

    Parameters
    ----------
    q : ndarray, shape (n, k, 3)
        Corners of ``n`` polygons of ``k`` corners each, centred on their mean.
    normal : ndarray, shape (n, 3)
        Unit normals the polygons should be counter-clockwise about.
    tol : float

    Returns
    -------
    kind, corner : ndarray, shape (n,), int64
        ``kind`` is 0 (fine), ``PLANAR`` or ``CONVEX``; ``corner`` deviates most.
    edge : ndarray, shape (n, 2), int64
        The ends of the edge a ``CONVEX`` fault's corner is outside of, else -1.
    deviation : ndarray, shape (n,), float64
    """
    n, k, _ = q.shape
    ar = np.arange(n)
    height = np.abs(np.einsum("nkx,nx->nk", q, normal))
    # m_j = normal x e_j points into the polygon from edge j, as long as e_j's projection
    m = _cross(normal[:, None, :], np.roll(q, -1, axis=1) - q)
    left = np.matmul(m, q.transpose(0, 2, 1))  # m_j . q_i
    left -= np.diagonal(left, axis1=1, axis2=2)[:, :, None]  # left[:, j, i]: i's side of edge j
    length = np.sqrt(np.einsum("njx,njx->nj", m, m))[:, :, None]
    outside = left / -np.maximum(length, np.finfo(float).tiny)  # a zero m_j has left 0
    edge, corner = np.divmod(outside.reshape(n, -1).argmax(axis=1), k)
    convex_dev = outside[ar, edge, corner]
    planar_corner = height.argmax(axis=1)
    planar_dev = height[ar, planar_corner]
    planar = planar_dev > tol
    kind = np.where(planar, PLANAR, np.where(convex_dev > tol, CONVEX, 0))
    ends = np.where(planar[:, None], -1, np.stack([edge, (edge + 1) % k], axis=1))
    return (kind, np.where(planar, planar_corner, corner), ends,
            np.where(planar, planar_dev, convex_dev))


def _chunk_faults(pts: np.ndarray, tol: float) -> tuple[np.ndarray, ...]:
    """Faults of polygons with the same corner count (kind 0: fine or degenerate).

    Every polygon is first tested against its Newell normal; a polygon that fails, or
    whose Newell normal is too short to trust, is tested again against the normal
    from :func:`_reference_normals`, which also says whether it is degenerate.

    Parameters
    ----------
    pts : ndarray, shape (n, k, 3)
        Corner positions, in polygon order.
    tol : float

    Returns
    -------
    kind, corner, edge, deviation
        As :func:`_deviations` returns them.
    """
    q = pts - pts.mean(axis=1, keepdims=True)
    newell = _cross(q, np.roll(q, -1, axis=1)).sum(axis=1)
    size = np.sqrt(np.einsum("nkx,nkx->nk", q, q).max(axis=1))
    found = _deviations(q, _unit(newell), tol)
    suspect = (found[0] > 0) | (np.linalg.norm(newell, axis=1) <= tol * size)
    if suspect.any():
        normal, degenerate = _reference_normals(q[suspect], tol)
        again = _deviations(q[suspect], normal, tol)
        again[0][degenerate] = 0
        for whole, part in zip(found, again, strict=True):
            whole[suspect] = part
    return found


def polygon_shape_faults(
    vertices: np.ndarray, polygons: np.ndarray, counts: np.ndarray, tol: float | None = None
) -> ShapeFaults:
    """Polygons of 4 or more corners that are not planar, or not convex, within ``tol``.

    A polygon is planar when every corner is within ``tol`` of the plane through the
    corners' mean with the polygon's Newell normal.  It is convex when no corner lies
    more than ``tol`` outside (right of, seen from the normal) the line of any of its
    edges; that also refuses self-intersecting orders (a bow-tie, a pentagram) and
    outlines that double back, and allows collinear corners and repeated corners.
    Degenerate polygons (all corners within ``tol`` of one line) are not faults:
    they cover no area.  Triangles are always planar and convex.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3), finite
    polygons : ndarray, shape (P, K), indices in range, padded with -1
    counts : ndarray, shape (P,)
    tol : float, optional
        Default :func:`shape_tolerance` of ``vertices``.

    Returns
    -------
    ShapeFaults
    """
    big = counts >= 4
    if tol is None:
        tol = shape_tolerance(vertices) if big.any() else 0.0
    parts = [(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64),
              np.zeros((0, 2), np.int64), np.zeros(0))]
    for k in np.unique(counts[big]).tolist():
        rows = np.nonzero(counts == k)[0]
        step = max(1, SHAPE_CHUNK // (k * k))
        for start in range(0, rows.size, step):
            idx = rows[start : start + step]
            found = _chunk_faults(vertices[polygons[idx, :k]], tol)
            bad = found[0] > 0
            parts.append((idx[bad], *(f[bad] for f in found)))
    cols = [np.concatenate([p[c] for p in parts]) for c in range(5)]
    order = np.argsort(cols[0], kind="stable")
    return ShapeFaults(*(c[order] for c in cols), tol)


def describe_fault(faults: ShapeFaults, i: int = 0) -> str:
    """Words for fault ``i``: the polygon, what is wrong, and how many more there are."""
    p, corner, dev = int(faults.polygon[i]), int(faults.corner[i]), float(faults.deviation[i])
    limit = f"tolerance {faults.tolerance:.3g} = {SHAPE_TOL:g} of the mesh's extent"
    if faults.kind[i] == PLANAR:
        what = f"is not planar: its corner {corner} is {dev:.3g} off the polygon's plane"
    else:
        e0, e1 = (int(c) for c in faults.edge[i])
        what = (
            f"is not convex (concave or self-intersecting): its corner {corner} is {dev:.3g}"
            f" outside the line through its corners {e0} and {e1}"
        )
    more = faults.polygon.size - 1
    tail = f"; {more} more polygon(s) break this rule" if more > 0 else ""
    return (f"polygon {p} {what} ({limit}); polygons must be planar and convex "
            f"(split it into triangles){tail}")


def edges_closed(polygons: np.ndarray, counts: np.ndarray, n_vertices: int) -> bool:
    """True if the directed edges of the polygons pair up exactly (a closed surface).

    Parameters
    ----------
    polygons : ndarray, shape (P, K)
    counts : ndarray, shape (P,)
    n_vertices : int
    """
    if polygons.shape[0] == 0:
        return False

    return bool(
        edges_closed_kernel(
            np.ascontiguousarray(polygons, np.int64), counts.astype(np.int64), int(n_vertices)
        )
    )


def fan_triangulate(polygons: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split convex polygons into triangle fans.

    Parameters
    ----------
    polygons : ndarray, shape (P, K), int64
    counts : ndarray, shape (P,), int64

    Returns
    -------
    triangles : ndarray, shape (T, 3), int64
        With ``T = sum(counts - 2)``; polygon order is kept.
    triangle_polygon : ndarray, shape (T,), int64
        The polygon each triangle came from.
    """
    n_tri = counts - 2
    poly_of = np.repeat(np.arange(polygons.shape[0]), n_tri)
    first = np.cumsum(n_tri) - n_tri
    j = np.arange(poly_of.size) - np.repeat(first, n_tri)  # fan index within its polygon
    tri = np.stack(
        [polygons[poly_of, 0], polygons[poly_of, j + 1], polygons[poly_of, j + 2]], axis=1
    )
    return tri.astype(np.int64), poly_of.astype(np.int64)


def polygon_normals(vertices: np.ndarray, polygons: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Unit normals of polygons by Newell's method (robust for near-degenerate quads).

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
    polygons : ndarray, shape (P, K)
    counts : ndarray, shape (P,)

    Returns
    -------
    ndarray, shape (P, 3), float64
        Unit normals; zero vectors for degenerate polygons.
    """
    return newell_normals_kernel(
        np.ascontiguousarray(vertices, np.float64),
        np.ascontiguousarray(polygons, np.int64),
        counts.astype(np.int64),
    )


def polygon_mean(values: np.ndarray, polygons: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Mean of per-vertex values over each polygon's vertices.

    Parameters
    ----------
    values : ndarray, shape (V,) or (V, D)
    polygons : ndarray, shape (P, K)
    counts : ndarray, shape (P,)

    Returns
    -------
    ndarray, shape (P,) or (P, D)
    """
    used = np.arange(polygons.shape[1])[None, :] < counts[:, None]
    gathered = values[np.where(used, polygons, 0)]
    mask = used if values.ndim == 1 else used[..., None]
    return np.where(mask, gathered, 0).sum(axis=1) / (
        counts if values.ndim == 1 else counts[:, None]
    )


def corner_normals(
    vertices: np.ndarray,
    triangles: np.ndarray,
    triangle_polygon: np.ndarray,
    poly_normals: np.ndarray,
    crease_deg: float = 50.0,
) -> np.ndarray:
    """Smooth normals at every triangle corner, split at creases.

    A corner's normal averages the area-weighted normals of all triangles that share
    its vertex position and whose polygon normal lies within ``crease_deg`` of its own
    polygon's normal, so a sphere shades smoothly and a cube keeps its edges.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
    triangles : ndarray, shape (T, 3)
    triangle_polygon : ndarray, shape (T,)
    poly_normals : ndarray, shape (P, 3)
    crease_deg : float

    Returns
    -------
    ndarray, shape (T, 3, 3), float64
        Unit normal at each corner of each triangle.
    """
    # weld coincident vertex positions so loaders that repeat vertices still share normals
    _, weld = np.unique(np.round(vertices, 9), axis=0, return_inverse=True)
    weld = weld.reshape(-1).astype(np.int64)
    return corner_normals_kernel(
        vertices.astype(np.float64),
        triangles.astype(np.int64),
        weld,
        poly_normals[triangle_polygon].astype(np.float64),
        float(np.cos(np.radians(crease_deg))),
    )


def _check_shading(shading: Shading, n_polygons: int, name: str) -> None:
    """Raise :class:`MeshError` unless ``shading`` has one finite normal per polygon."""
    arr = shading.polygons
    if not isinstance(arr, np.ndarray) or arr.shape != (n_polygons, 3):
        got = getattr(arr, "shape", type(arr).__name__)
        raise MeshError(f"{name}: shading needs one normal per polygon, shape "
                        f"{(n_polygons, 3)}, got {got}")
    if not np.all(np.isfinite(arr)):
        raise MeshError(f"{name}: a shading normal is not finite")
