"""Polygon meshes: vertices plus convex polygons, with their triangulation.

A :class:`Mesh` keeps the polygons the thesis works with (for culling, sorting and
per-polygon light) and a fan triangulation of them (for rasterising).  Polygons are
stored padded: ``polygons[p, :counts[p]]`` are the vertex indices of polygon ``p``
in counter-clockwise order seen from the side its normal points to (right-handed,
as OBJ and PLY store them).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from service.errors import MeshError


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
    """

    vertices: np.ndarray
    polygons: np.ndarray
    counts: np.ndarray
    name: str = "mesh"
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        validate(self.vertices, self.polygons, self.counts, self.name)

    @property
    def n_polygons(self) -> int:
        """Number of polygons P."""
        return int(self.polygons.shape[0])

    @property
    def n_vertices(self) -> int:
        """Number of vertices V."""
        return int(self.vertices.shape[0])

    @property
    def triangles(self) -> np.ndarray:
        """Fan triangulation, shape (T, 3) int64 (cached)."""
        if "tri" not in self._cache:
            self._cache["tri"] = fan_triangulate(self.polygons, self.counts)
        return self._cache["tri"][0]

    @property
    def triangle_polygon(self) -> np.ndarray:
        """Polygon index of each triangle, shape (T,) int64 (cached)."""
        if "tri" not in self._cache:
            self._cache["tri"] = fan_triangulate(self.polygons, self.counts)
        return self._cache["tri"][1]

    @property
    def normals(self) -> np.ndarray:
        """Unit polygon normals in object coordinates, shape (P, 3) (cached)."""
        if "normals" not in self._cache:
            self._cache["normals"] = polygon_normals(self.vertices, self.polygons, self.counts)
        return self._cache["normals"]

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


def validate(vertices: np.ndarray, polygons: np.ndarray, counts: np.ndarray, name: str) -> None:
    """Check shapes, dtypes, finiteness and index ranges; raise :class:`MeshError`."""
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise MeshError(f"{name}: vertices must have shape (V, 3), got {vertices.shape}")
    if not np.all(np.isfinite(vertices)):
        bad = int(np.argwhere(~np.isfinite(vertices))[0, 0])
        raise MeshError(f"{name}: vertex {bad} is not finite")
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
    k = np.arange(polygons.shape[1])[None, :]
    used = k < counts[:, None]
    nxt = np.where(k + 1 < counts[:, None], np.minimum(k + 1, polygons.shape[1] - 1), 0)
    a = polygons[used].astype(np.int64)
    b = np.take_along_axis(polygons, nxt, axis=1)[used].astype(np.int64)
    fwd = np.sort(a * n_vertices + b)
    rev = np.sort(b * n_vertices + a)
    return bool(np.all(fwd[1:] != fwd[:-1]) and np.array_equal(fwd, rev))


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
    p, k = polygons.shape
    normal = np.zeros((p, 3))
    ar = np.arange(p)
    for i in range(k):
        has = counts > i
        cur = vertices[polygons[ar, i]]
        nxt_i = np.where(i + 1 < counts, np.minimum(i + 1, k - 1), 0)
        nxt = vertices[polygons[ar, nxt_i]]
        cross = np.stack(
            [
                (cur[:, 1] - nxt[:, 1]) * (cur[:, 2] + nxt[:, 2]),
                (cur[:, 2] - nxt[:, 2]) * (cur[:, 0] + nxt[:, 0]),
                (cur[:, 0] - nxt[:, 0]) * (cur[:, 1] + nxt[:, 1]),
            ],
            axis=1,
        )
        normal += np.where(has[:, None], cross, 0.0)
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(length > 1e-300, normal / np.where(length > 0, length, 1), 0.0)


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
    from service.normals_kernel import corner_normals_kernel

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
