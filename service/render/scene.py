"""Scene model: objects (mesh + material + transform + motion), lights, and flattening.

Coordinates (thesis Fig. 1-1): right-handed, x to the right, y up, z out of the
display toward the viewer, who sits near the +z axis.  The display plane is z = 0.
Orientation is a unit quaternion ``(w, x, y, z)`` rotating object coordinates into
world coordinates; a world point is ``position + R(orientation) @ (scale * p)``.

All objects' polygons go into one list (thesis section 3.2) in object order, so a
tie in average depth is resolved deterministically by object order.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from service.base.errors import SettingsError
from service.render.mesh import Mesh


@dataclass(frozen=True)
class Material:
    """Surface reflectance (thesis chapter 4).

    Attributes
    ----------
    colour : tuple of 3 floats in [0, 1]
        Diffuse and ambient colour.
    ambient, diffuse, specular : float >= 0
        Coefficients k_a, k_d, k_s.
    shininess : float >= 1
        Exponent n of (R.V)^n or (N.H)^n (the thesis uses 1 to 5).
    """

    colour: tuple[float, float, float] = (0.8, 0.8, 0.8)
    ambient: float = 0.2
    diffuse: float = 0.7
    specular: float = 0.5
    shininess: float = 5.0

    def __post_init__(self) -> None:
        c = tuple(float(v) for v in self.colour)
        if len(c) != 3 or not all(0.0 <= v <= 1.0 for v in c):
            raise SettingsError(f"material colour must be 3 values in [0, 1], got {self.colour}")
        object.__setattr__(self, "colour", c)
        for name in ("ambient", "diffuse", "specular"):
            if not getattr(self, name) >= 0:
                raise SettingsError(f"material {name} must be >= 0")
        if not self.shininess >= 1:
            raise SettingsError("material shininess must be >= 1")


@dataclass(frozen=True)
class Transform:
    """Placement of an object.

    Attributes
    ----------
    position : ndarray, shape (3,)
    orientation : ndarray, shape (4,)
        Unit quaternion (w, x, y, z).
    scale : float
    """

    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    orientation: np.ndarray = field(default_factory=lambda: np.array([1.0, 0, 0, 0]))
    scale: float = 1.0

    def __post_init__(self) -> None:
        pos = np.asarray(self.position, dtype=np.float64).reshape(3)
        q = np.asarray(self.orientation, dtype=np.float64).reshape(4)
        n = np.linalg.norm(q)
        if not np.isfinite(n) or n < 1e-12 or not np.all(np.isfinite(pos)):
            raise SettingsError("transform needs a finite position and a non-zero quaternion")
        if not (np.isfinite(self.scale) and self.scale > 0):
            raise SettingsError(f"transform scale must be finite and > 0, got {self.scale}")
        object.__setattr__(self, "position", pos)
        object.__setattr__(self, "orientation", q / n)

    def matrix(self) -> np.ndarray:
        """Rotation times scale, shape (3, 3)."""
        return quaternion_matrix(self.orientation) * self.scale

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Object to world coordinates, shape (N, 3) -> (N, 3)."""
        return points @ self.matrix().T + self.position


@dataclass(frozen=True)
class MotionState:
    """Linear and angular velocity and acceleration (world units and radians per second).

    The Galilean stage uses these to give every pixel its apparent motion.
    """

    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    acceleration: np.ndarray = field(default_factory=lambda: np.zeros(3))
    angular_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    angular_acceleration: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        for name in ("velocity", "acceleration", "angular_velocity", "angular_acceleration"):
            try:
                v = np.asarray(getattr(self, name), dtype=np.float64)
            except (TypeError, ValueError) as exc:
                raise SettingsError(f"motion {name} must be 3 numbers: {exc}") from None
            if v.size != 3:
                raise SettingsError(f"motion {name} must be 3 numbers, got shape {v.shape}")
            v = v.reshape(3)
            if not np.all(np.isfinite(v)):
                raise SettingsError(f"motion {name} must be finite")
            object.__setattr__(self, name, v)


@dataclass(frozen=True)
class Light:
    """A light source.

    Attributes
    ----------
    kind : {"directional", "point"}
        A light at infinity (``vector`` is the direction *toward* the light) or a
        point light (``vector`` is its position).
    vector : ndarray, shape (3,)
    colour : tuple of 3 floats
    intensity : float
    """

    kind: str = "directional"
    vector: np.ndarray = field(default_factory=lambda: np.array([0.3, 0.5, 1.0]))
    colour: tuple[float, float, float] = (1.0, 1.0, 1.0)
    intensity: float = 1.0

    def __post_init__(self) -> None:
        if self.kind not in ("directional", "point"):
            raise SettingsError(f"light kind must be 'directional' or 'point', got {self.kind!r}")
        v = np.asarray(self.vector, dtype=np.float64).reshape(3)
        with np.errstate(over="ignore"):  # a length past float64 is refused, not a warning
            length = float(np.sqrt(np.sum(v * v)))
        if not np.isfinite(length) or (self.kind == "directional" and length == 0):
            raise SettingsError(
                "light vector must be finite, of a length below 1e154 (and non-zero for a "
                "directional light)"
            )
        object.__setattr__(self, "vector", v)
        object.__setattr__(self, "colour", tuple(float(c) for c in self.colour))


@dataclass(frozen=True)
class SceneObject:
    """One object of a scene: a mesh with its material, placement and motion."""

    mesh: Mesh
    material: Material = field(default_factory=Material)
    transform: Transform = field(default_factory=Transform)
    motion: MotionState = field(default_factory=MotionState)
    name: str = ""


@dataclass
class Scene:
    """Objects and lights.  ``ambient`` is the ambient light level (0-1).

    ``billboards`` are billboard-cloud objects
    (:class:`service.billboard_render.BillboardObject`), drawn after the meshes.
    """

    objects: list[SceneObject] = field(default_factory=list)
    lights: list[Light] = field(default_factory=lambda: [Light()])
    ambient: float = 1.0
    billboards: list = field(default_factory=list)
    _static: dict = field(default_factory=dict, repr=False, compare=False)
    #: A scene file's ``[quality]`` table (``mode``, ``max_error``); empty otherwise.
    quality: dict = field(default_factory=dict, compare=False)

    def flatten(self) -> SceneArrays:
        """All objects' polygons in one list, in world coordinates.

        The parts that do not depend on the objects' placement (polygon lists,
        triangulation, materials) are kept between calls while the meshes and
        materials stay the same, so a moving scene re-does only the transforms.
        """
        return flatten(self)


@dataclass(frozen=True)
class SceneArrays:
    """A scene flattened into one polygon list (world coordinates).

    Attributes
    ----------
    vertices : ndarray, shape (V, 3), float64
    polygons : ndarray, shape (P, K), int64, padded with -1
    counts : ndarray, shape (P,), int64
    triangles : ndarray, shape (T, 3), int64
    triangle_polygon : ndarray, shape (T,), int64
    polygon_object : ndarray, shape (P,), int64
        Index of the object each polygon belongs to.
    normals : ndarray, shape (P, 3), float64
        Unit polygon normals in world coordinates.
    materials : ndarray, shape (P, 7), float64
        Per polygon: r, g, b, ambient, diffuse, specular, shininess.
    polygon_closed : ndarray, shape (P,), bool
        Whether the polygon belongs to a closed mesh (its back faces always hidden).
    corner_normals : ndarray, shape (T, 3, 3), float64
        Smooth normals at triangle corners (for per-vertex and per-point light),
        computed on first use.
    shading_normals : ndarray, shape (P, 3), float64
        Polygon normals per-polygon light uses: ``normals`` except where a mesh carries
        others (:attr:`service.render.mesh.Mesh.shading`, a level of detail's).
    """

    vertices: np.ndarray
    polygons: np.ndarray
    counts: np.ndarray
    triangles: np.ndarray
    triangle_polygon: np.ndarray
    polygon_object: np.ndarray
    normals: np.ndarray
    materials: np.ndarray
    polygon_closed: np.ndarray
    _corners: list = field(default_factory=list, repr=False, compare=False)
    _lazy: dict = field(default_factory=dict, repr=False, compare=False)
    _shading: np.ndarray | None = field(default=None, repr=False, compare=False)

    @property
    def shading_normals(self) -> np.ndarray:
        """Polygon normals for light in world coordinates, shape (P, 3)."""
        return self.normals if self._shading is None else self._shading

    @property
    def n_polygons(self) -> int:
        """Number of polygons P."""
        return int(self.polygons.shape[0])

    @property
    def corner_normals(self) -> np.ndarray:
        """Smooth corner normals in world coordinates, shape (T, 3, 3) (cached)."""
        if "corner" not in self._lazy:
            parts = [
                (m.corner_normals.reshape(-1, 3) @ rot.T).reshape(-1, 3, 3)
                for m, rot in self._corners
            ]
            self._lazy["corner"] = np.concatenate(parts) if parts else np.zeros((0, 3, 3))
        return self._lazy["corner"]


def quaternion_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion (w, x, y, z), shape (3, 3)."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def quaternion_matrices(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of unit quaternions (w, x, y, z), shape (N, 4) -> (N, 3, 3).

    The same arithmetic as :func:`quaternion_matrix`, element by element.
    """
    q = np.asarray(q, dtype=np.float64).reshape(-1, 4)
    w, x, y, z = (q / np.sqrt((q * q).sum(axis=1, keepdims=True))).T
    return np.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        axis=1,
    ).reshape(-1, 3, 3)


def axis_angle_quaternion(axis: np.ndarray, angle: float) -> np.ndarray:
    """Unit quaternion (w, x, y, z) for a rotation of ``angle`` radians about ``axis``."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * a])


def euler_quaternion(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """Quaternion for yaw about y, then pitch about x, then roll about z (radians)."""
    qy = axis_angle_quaternion([0, 1, 0], yaw)
    qx = axis_angle_quaternion([1, 0, 0], pitch)
    qz = axis_angle_quaternion([0, 0, 1], roll)
    return quaternion_multiply(quaternion_multiply(qy, qx), qz)


def quaternion_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b of quaternions (w, x, y, z)."""
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


def _runs(scene: Scene) -> list[tuple[Mesh, int, int]]:
    """Runs of consecutive objects sharing one mesh: (mesh, first object, end object)."""
    runs: list[tuple[Mesh, int, int]] = []
    for i, obj in enumerate(scene.objects):
        if runs and runs[-1][0] is obj.mesh:
            runs[-1] = (obj.mesh, runs[-1][1], i + 1)
        else:
            runs.append((obj.mesh, i, i + 1))
    return runs


def _static_parts(scene: Scene) -> dict:
    """Placement-independent arrays of a scene, cached on it while meshes and materials hold.

    Objects that share a mesh and follow each other (a crowd, the game's attackers)
    are written as one broadcast block, so the cost is a few array operations per
    run of objects, not per object.

    Returns
    -------
    dict
        ``polygons`` (P, K), ``counts`` (P,), ``triangles`` (T, 3),
        ``triangle_polygon`` (T,), ``polygon_object`` (P,), ``materials`` (P, 7),
        ``polygon_closed`` (P,); for the transforms ``runs`` (:func:`_runs`),
        ``vertex_start`` and ``polygon_start`` (O + 1,).
    """
    key = tuple((id(o.mesh), o.material) for o in scene.objects)
    if scene._static.get("key") == key:
        return scene._static
    runs = _runs(scene)
    objs = scene.objects
    n_p = np.array([o.mesh.n_polygons for o in objs], np.int64)
    v0, p0, t0 = _starts(objs, n_p)
    k = max((o.mesh.polygons.shape[1] for o in objs), default=3)
    polygons, counts, triangles, tri_poly, closed = _run_blocks(runs, v0, p0, t0, k)
    mats = _materials(objs)
    poly_obj = np.repeat(np.arange(len(objs), dtype=np.int64), n_p)
    # a new dict, not the old one refilled: scenes moved from this one share it
    # (service.scene_motion), and one of them changed must not change the others'
    scene._static = dict(
        key=key, polygons=polygons, counts=counts, triangles=triangles,
        triangle_polygon=tri_poly, polygon_object=poly_obj, materials=mats[poly_obj],
        polygon_closed=closed, runs=runs, vertex_start=v0, polygon_start=p0,
    )
    return scene._static


def _starts(objs: list, n_p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where each object's vertices, polygons and triangles start in the scene's arrays.

    Parameters
    ----------
    objs : list of SceneObject, length O
    n_p : ndarray, shape (O,), int64
        Their polygon counts.

    Returns
    -------
    v0, p0, t0 : ndarray, shape (O + 1,), int64
        Starts of vertices, polygons and triangles; the last entry is the total.
    """
    n_v = np.array([o.mesh.n_vertices for o in objs], np.int64)
    n_t = np.array([o.mesh.triangles.shape[0] for o in objs], np.int64)
    v0, p0, t0 = (np.concatenate([[0], np.cumsum(n)]) for n in (n_v, n_p, n_t))
    return v0, p0, t0


def _run_blocks(runs: list, v0: np.ndarray, p0: np.ndarray, t0: np.ndarray,
                k: int) -> tuple[np.ndarray, ...]:
    """The scene's polygon and triangle arrays, one broadcast block per run of objects.

    Parameters
    ----------
    runs : list of (Mesh, int, int)
        :func:`_runs`: a mesh and the objects ``a:b`` that share it.
    v0, p0, t0 : ndarray, shape (O + 1,), int64
        :func:`_starts`.
    k : int
        Most corners of a polygon.

    Returns
    -------
    polygons : ndarray, shape (P, k), int64, padded with -1
    counts : ndarray, shape (P,), int64
    triangles : ndarray, shape (T, 3), int64
    triangle_polygon : ndarray, shape (T,), int64
    polygon_closed : ndarray, shape (P,), bool
    """
    polygons = np.full((p0[-1], k), -1, np.int64)
    counts = np.empty(p0[-1], np.int64)
    triangles = np.empty((t0[-1], 3), np.int64)
    tri_poly = np.empty(t0[-1], np.int64)
    closed = np.empty(p0[-1], np.bool_)
    for mesh, a, b in runs:
        n, vo = b - a, v0[a:b, None, None]
        ps, pe, ts, te = p0[a], p0[b], t0[a], t0[b]
        local = mesh.polygons
        padded = mesh.counts.size and mesh.counts.min() < local.shape[1]
        block = np.where(local >= 0, local + vo, -1) if padded else local[None] + vo
        polygons[ps:pe, : local.shape[1]] = block.reshape(-1, local.shape[1])
        counts[ps:pe].reshape(n, -1)[:] = mesh.counts
        triangles[ts:te] = (mesh.triangles[None] + vo).reshape(-1, 3)
        tri_poly[ts:te].reshape(n, -1)[:] = mesh.triangle_polygon[None] + p0[a:b, None]
        closed[ps:pe] = mesh.is_closed
    return polygons, counts, triangles, tri_poly, closed


def _materials(objs: list) -> np.ndarray:
    """Each object's material as a row: colour (3), ambient, diffuse, specular, shininess.

    Returns
    -------
    ndarray, shape (O, 7), float64
    """
    return np.array(
        [[*o.material.colour, o.material.ambient, o.material.diffuse, o.material.specular,
          o.material.shininess] for o in objs], np.float64,
    ).reshape(-1, 7)


def _placed(
    scene: Scene, static: dict, orientations: np.ndarray | None = None,
    positions: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, list, np.ndarray | None]:
    """World vertices, polygon normals, (mesh, rotation) per object, and light's normals.

    Vertices (V, 3), normals (P, 3); light's normals (P, 3) are None when no mesh
    carries its own (:attr:`Mesh.shading`).

    One batched matrix product per run of objects sharing a mesh.  ``orientations``
    (O, 4) and ``positions`` (O, 3), when given, replace the objects' transforms.
    """
    objs = scene.objects
    v0, p0 = static["vertex_start"], static["polygon_start"]
    verts = np.empty((v0[-1], 3))
    normals = np.empty((p0[-1], 3))
    carried = any(mesh.shading is not None for mesh, _, _ in static["runs"])
    shading = np.empty((p0[-1], 3)) if carried else None
    if not objs:
        return verts, normals, [], shading
    if orientations is None:
        orientations = np.array([o.transform.orientation for o in objs])
    rot = quaternion_matrices(orientations)
    pos = positions if positions is not None else np.array([o.transform.position for o in objs])
    scale = np.array([o.transform.scale for o in objs], np.float64)
    for mesh, a, b in static["runs"]:
        n = b - a
        out = verts[v0[a] : v0[b]].reshape(n, -1, 3)
        np.matmul(mesh.vertices[None], (rot[a:b] * scale[a:b, None, None]).transpose(0, 2, 1),
                  out=out)
        out += pos[a:b, None, :]
        np.matmul(mesh.normals[None], rot[a:b].transpose(0, 2, 1),
                  out=normals[p0[a] : p0[b]].reshape(n, -1, 3))
        if shading is not None:
            np.matmul(mesh.shading_normals[None], rot[a:b].transpose(0, 2, 1),
                      out=shading[p0[a] : p0[b]].reshape(n, -1, 3))
    return verts, normals, [(o.mesh, rot[i]) for i, o in enumerate(objs)], shading


def _cat(parts: list, empty_shape: tuple, dtype: type) -> np.ndarray:
    """Concatenate, or an empty array of the given shape when there are no parts."""
    return (
        np.concatenate(parts).astype(dtype, copy=False) if parts else np.zeros(empty_shape, dtype)
    )


def flatten(
    scene: Scene, orientations: np.ndarray | None = None, positions: np.ndarray | None = None
) -> SceneArrays:
    """Concatenate every object's polygons into one world-space list (thesis 3.2).

    Parameters
    ----------
    scene : Scene
    orientations, positions : ndarray, shape (O, 4) and (O, 3), optional
        Place the objects here instead of at their transforms (unit quaternions;
        :func:`service.scene_motion.placements`): the scene at another time without
        building it.

    Returns
    -------
    SceneArrays
    """
    static = _static_parts(scene)
    verts, normals, corners, shading = _placed(scene, static, orientations, positions)
    return SceneArrays(
        vertices=verts,
        polygons=static["polygons"],
        counts=static["counts"],
        triangles=static["triangles"],
        triangle_polygon=static["triangle_polygon"],
        polygon_object=static["polygon_object"],
        normals=normals,
        materials=static["materials"],
        polygon_closed=static["polygon_closed"],
        _corners=corners,
        _shading=shading,
    )
