"""Built-in meshes: cube, sphere, torus, and the dodge game's player and attacker.

Every primitive is a closed surface centred on the origin whose polygons wind
counter-clockwise seen from outside (right-handed normals point outward), so each
edge is shared by exactly two polygons that walk it in opposite directions and the
signed volume (divergence theorem) is positive.  Sphere-like primitives are built
by :func:`lathe` (a surface of revolution about the y axis); the attacker is a
geodesic sphere with spikes.
"""

from __future__ import annotations

from itertools import combinations

import numpy as np

from service.base.errors import SettingsError
from service.render.mesh import MAX_POLYGONS, Mesh


def _need(name: str, value: float, low: float, integer: bool = False) -> None:
    """Raise :class:`SettingsError` unless ``value >= low`` (and integral if asked)."""
    ok_type = isinstance(value, int | np.integer) if integer else np.isfinite(value)
    if not (ok_type and value >= low):
        kind = "an integer" if integer else "a finite number"
        raise SettingsError(f"{name} must be {kind} >= {low}, got {value!r}")


def _budget(name: str, polygons: int) -> None:
    """Raise :class:`SettingsError` if a primitive's parameters ask for too many polygons.

    Checked before anything is allocated: ``n_lat = n_lon = 100000`` in a scene file
    asked for 10^10 polygons and the process was killed for memory.
    """
    if polygons > MAX_POLYGONS:
        raise SettingsError(f"{name} would have {polygons:,} polygons "
                            f"(at most {MAX_POLYGONS:,}); lower its resolution")


def signed_volume(vertices: np.ndarray, polygons: np.ndarray, counts: np.ndarray) -> float:
    """Volume enclosed by a closed mesh, positive when its normals point outward.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
    polygons : ndarray, shape (P, K)
        Padded with -1 after ``counts[p]`` entries.
    counts : ndarray, shape (P,)

    Returns
    -------
    float
        Sum over fan triangles (a, b, c) of ``a . (b x c) / 6``.
    """
    total = 0.0
    a = vertices[polygons[:, 0]]
    for j in range(1, polygons.shape[1] - 1):
        has = counts > j + 1
        b = vertices[polygons[has, j]]
        c = vertices[polygons[has, j + 1]]
        total += float(np.einsum("ij,ij->", a[has], np.cross(b, c)))
    return total / 6.0


def outward_mesh(vertices: np.ndarray, polys: list, name: str) -> Mesh:
    """Build a closed mesh, reversing every polygon if its signed volume is negative.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
    polys : list of lists of int
        Consistently wound polygons (either way round).
    name : str
    """
    mesh = Mesh.from_polygons(vertices, polys, name)
    if signed_volume(mesh.vertices, mesh.polygons, mesh.counts) < 0:
        mesh = Mesh.from_polygons(vertices, [list(reversed(p)) for p in polys], name)
    return mesh


def lathe(profile: np.ndarray, n_around: int, name: str = "lathe") -> Mesh:
    """Surface of revolution of a profile about the y axis.

    Parameters
    ----------
    profile : ndarray, shape (M, 2)
        ``(radius, y)`` points from one end to the other.  An end with radius > 0 is
        closed by a flat cap (a fan of triangles around the axis); radius 0 at an
        end makes a pole.  Inner points must have radius > 0.
    n_around : int
        Number of segments around the axis (>= 3).
    name : str

    Returns
    -------
    Mesh
        Quads between rings and triangles at the poles, outward winding.
    """
    prof = np.asarray(profile, dtype=np.float64).reshape(-1, 2)
    if prof[0, 0] > 0:
        prof = np.vstack([[0.0, prof[0, 1]], prof])
    if prof[-1, 0] > 0:
        prof = np.vstack([prof, [0.0, prof[-1, 1]]])
    phi = 2 * np.pi * np.arange(n_around) / n_around
    verts = [[0.0, prof[0, 1], 0.0]]
    rings = [[0] * n_around]
    for r, y in prof[1:-1]:
        start = len(verts)
        verts.extend(np.stack([r * np.cos(phi), np.full(n_around, y), -r * np.sin(phi)], 1))
        rings.append(list(range(start, start + n_around)))
    rings.append([len(verts)] * n_around)
    verts.append([0.0, prof[-1, 1], 0.0])
    polys = []
    for up, low in zip(rings[:-1], rings[1:], strict=True):
        for j in range(n_around):
            k = (j + 1) % n_around
            quad = [up[j], low[j], low[k], up[k]]
            polys.append([v for i, v in enumerate(quad) if v != quad[i - 1]])
    return outward_mesh(np.array(verts), polys, name)


def cube(size: float = 1.0) -> Mesh:
    """Axis-aligned cube of edge ``size`` centred on the origin: 8 vertices, 6 quads."""
    _need("cube size", size, 1e-12)
    corners = np.array([[(i & 1), (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], float)
    verts = (corners - 0.5) * size
    faces = []
    for axis in range(3):
        for side in (0, 1):
            ids = [i for i in range(8) if corners[i, axis] == side]
            a, b = [(axis + 1) % 3, (axis + 2) % 3]
            ring = sorted(ids, key=lambda i: np.arctan2(verts[i, b], verts[i, a]))
            normal = np.zeros(3)
            normal[axis] = 1 if side else -1
            n_ring = np.cross(verts[ring[1]] - verts[ring[0]], verts[ring[2]] - verts[ring[1]])
            faces.append(ring if n_ring @ normal > 0 else ring[::-1])
    return Mesh.from_polygons(verts, faces, "cube")


def sphere(radius: float = 0.5, n_lat: int = 16, n_lon: int = 32) -> Mesh:
    """UV sphere: ``n_lon * (n_lat - 2)`` quads plus ``2 * n_lon`` cap triangles.

    Parameters
    ----------
    radius : float
    n_lat : int
        Bands from pole to pole (>= 2).
    n_lon : int
        Segments around the y axis (>= 3).
    """
    _need("sphere radius", radius, 1e-12)
    _need("sphere n_lat", n_lat, 2, integer=True)
    _need("sphere n_lon", n_lon, 3, integer=True)
    _budget("sphere", n_lat * n_lon)
    theta = np.pi * np.arange(n_lat + 1) / n_lat
    profile = np.stack([radius * np.sin(theta), radius * np.cos(theta)], 1)
    profile[[0, -1], 0] = 0.0
    return lathe(profile, n_lon, "sphere")


def torus(R: float = 0.5, r: float = 0.15, n_major: int = 32, n_minor: int = 12) -> Mesh:
    """Torus about the z axis (its hole faces the viewer): ``n_major * n_minor`` quads.

    Parameters
    ----------
    R : float
        Distance from the centre to the tube's centre line (> r).
    r : float
        Tube radius.
    n_major, n_minor : int
        Segments around the ring and around the tube (>= 3 each).
    """
    _need("torus r", r, 1e-12)
    _need("torus R", R, r * (1 + 1e-9))
    _need("torus n_major", n_major, 3, integer=True)
    _need("torus n_minor", n_minor, 3, integer=True)
    _budget("torus", n_major * n_minor)
    u = 2 * np.pi * np.arange(n_major)[:, None] / n_major
    v = 2 * np.pi * np.arange(n_minor)[None, :] / n_minor
    rad = R + r * np.cos(v)
    verts = np.stack(
        np.broadcast_arrays(rad * np.cos(u), rad * np.sin(u), r * np.sin(v)), -1
    ).reshape(-1, 3)
    polys = []
    for i in range(n_major):
        for j in range(n_minor):
            i1, j1 = (i + 1) % n_major, (j + 1) % n_minor
            polys.append([i * n_minor + j, i1 * n_minor + j, i1 * n_minor + j1, i * n_minor + j1])
    return outward_mesh(verts, polys, "torus")


def _prism(tri: np.ndarray, thickness: float, angle: float) -> tuple[np.ndarray, list]:
    """A fin: triangle ``tri`` (3, 2) in (span, y), extruded along w, turned about y."""
    half = thickness / 2
    local = np.array([[s, y, w] for w in (-half, half) for s, y in tri])
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    faces = [[0, 1, 2], [3, 5, 4], [0, 3, 4, 1], [1, 4, 5, 2], [2, 5, 3, 0]]
    return local @ rot.T, faces


def _combine(parts: list[Mesh], name: str) -> Mesh:
    """Join closed meshes into one (each part keeps its own vertices)."""
    verts, polys, off = [], [], 0
    for m in parts:
        verts.append(m.vertices)
        polys.extend([list(row[:c] + off) for row, c in zip(m.polygons, m.counts, strict=True)])
        off += m.n_vertices
    return Mesh.from_polygons(np.concatenate(verts), polys, name)


def player(detail: int = 4, size: float = 0.35) -> Mesh:
    """The dodge game's player: a rocket-like ship pointing up (+y) with four fins.

    A lathed body (ellipsoidal nose, cylinder, tapered tail with a flat exhaust cap)
    and four swept fins, two in the display plane (x) and two in depth (z).

    Parameters
    ----------
    detail : int
        Resolution level (>= 1): ``6 * detail`` segments around, ``3 * detail`` nose
        bands; about ``24 * detail**2`` polygons (452 at 4).
    size : float
        Length of the ship along y in world units.
    """
    _need("player detail", detail, 1, integer=True)
    _need("player size", size, 1e-12)
    _budget("player", 6 * detail * (4 * detail + 2) + 32)  # a bound: 452 at 4
    t = np.linspace(0.0, 1.0, 3 * detail + 1)
    nose = np.stack([0.12 * np.sin(t * np.pi / 2), 0.1 + 0.4 * np.cos(t * np.pi / 2)], 1)
    body_y = np.linspace(0.1, -0.35, detail + 1)[1:]
    body = np.stack([np.full(detail, 0.12), body_y], 1)
    tail = np.array([[0.085, -0.5]])
    parts = [lathe(np.vstack([nose, body, tail]), 6 * detail, "body")]
    wing = np.array([[0.08, 0.0], [0.1, -0.36], [0.42, -0.42]])
    fin = np.array([[0.08, -0.1], [0.1, -0.38], [0.3, -0.44]])
    for k, shape in enumerate((wing, fin, wing, fin)):
        verts, faces = _prism(shape, 0.025, k * np.pi / 2)
        parts.append(outward_mesh(verts, faces, "fin"))
    mesh = _combine(parts, "player")
    return Mesh(mesh.vertices * size, mesh.polygons, mesh.counts, "player")


def _icosahedron() -> tuple[np.ndarray, list]:
    """Unit icosahedron: vertices (12, 3) and 20 outward triangles."""
    g = (1 + 5**0.5) / 2
    base = []
    for a in (-1, 1):
        for b in (-g, g):
            base += [[0, a, b], [a, b, 0], [b, 0, a]]
    verts = np.array(base, float) / np.sqrt(1 + g * g)
    edge = np.linalg.norm(verts[0] - verts[1:], axis=1).min()
    close = np.isclose(np.linalg.norm(verts[:, None] - verts[None], axis=2), edge)
    faces = []
    for a, b, c in combinations(range(12), 3):
        if close[a, b] and close[b, c] and close[a, c]:
            n = np.cross(verts[b] - verts[a], verts[c] - verts[a])
            faces.append([a, b, c] if n @ verts[a] > 0 else [a, c, b])
    return verts, faces


def geodesic_sphere(freq: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit geodesic sphere: each icosahedron face cut into ``freq**2`` triangles.

    Returns
    -------
    vertices : ndarray, shape (10 * freq**2 + 2, 3)
        Unit vectors; the first 12 are the icosahedron's vertices.
    triangles : ndarray, shape (20 * freq**2, 3), int64
        Outward counter-clockwise.
    """
    ico, faces = _icosahedron()
    index: dict[tuple, int] = {((i, 1),): i for i in range(12)}
    points = [ico[i] for i in range(12)]

    def vid(face: list, i: int, j: int) -> int:
        weights = (freq - i - j, i, j)
        key = tuple(sorted((v, w / freq) for v, w in zip(face, weights, strict=True) if w))
        if key not in index:
            p = sum(w * ico[v] for v, w in key)
            index[key] = len(points)
            points.append(p / np.linalg.norm(p))
        return index[key]

    tris = []
    for f in faces:
        for i in range(freq):
            for j in range(freq - i):
                tris.append([vid(f, i, j), vid(f, i + 1, j), vid(f, i, j + 1)])
                if i + j < freq - 1:
                    tris.append([vid(f, i + 1, j), vid(f, i + 1, j + 1), vid(f, i, j + 1)])
    return np.array(points), np.array(tris, dtype=np.int64)


def attacker(detail: int = 8, radius: float = 0.1, spike: float = 0.9) -> Mesh:
    """The dodge game's attacker: a spiky ball (a sea mine) with 12 spikes.

    A geodesic sphere whose surface rises into a cone-like spike around each of the
    icosahedron's 12 vertices.

    Parameters
    ----------
    detail : int
        Geodesic frequency (>= 1): ``20 * detail**2`` triangles (1,280 at 8).
    radius : float
        Radius of the ball between spikes.
    spike : float
        Spike height as a fraction of ``radius`` (>= 0).
    """
    _need("attacker detail", detail, 1, integer=True)
    _need("attacker radius", radius, 1e-12)
    _need("attacker spike", spike, 0.0)
    _budget("attacker", 20 * detail**2)
    unit, tris = geodesic_sphere(detail)
    dirs = unit[:12]
    near = np.max(unit @ dirs.T, axis=1)
    base = np.cos(np.radians(26.0))
    rise = np.clip((near - base) / (1 - base), 0.0, 1.0) ** 1.5
    verts = unit * (radius * (1 + spike * rise))[:, None]
    return Mesh.from_triangles(verts, tris, "attacker")


PRIMITIVES = {
    "cube": cube,
    "sphere": sphere,
    "torus": torus,
    "player": player,
    "attacker": attacker,
}
"""Primitive builders by name (used by scene files and built-in scenes)."""
