"""Billboard clouds (Decoret, Durand, Sillion and Dorsey, SIGGRAPH 2003; seed 004).

A mesh becomes a few textured, alpha-tested rectangles: :mod:`.planes` chooses planes
so that every face lies within ``eps`` of one; each plane's faces are projected on
it, bounded by their minimal rectangle (:mod:`.rectangle`), and shot orthographically
into a texture of colour, alpha and the normal of the face at each texel (so the
renderer can still light it diffusely).  The file format is :mod:`.cloud_file`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from service.simplify.billboard_kernel import dilate_texture, shoot_texture, tile_grid
from service.simplify.errors import SimplifyError
from service.simplify.planes import PlaneCover, PlaneSettings, choose_planes
from service.simplify.quadric import check_triangles
from service.simplify.rectangle import min_area_rectangle

LAYERS = 2
"""Texture layers per billboard: faces on the plane normal's side, then the others."""
TILE = 8
"""Texels per side of the tiles of :attr:`BillboardCloud.tiles` (renderers skip empty ones)."""


@dataclass(frozen=True)
class BillboardCloud:
    """Textured rectangles standing in for a mesh.

    Attributes
    ----------
    corners : ndarray, shape (P, 4, 3), float64
        Each billboard's corners: origin, origin + U, origin + U + V, origin + V,
        where U runs along a texture row and V down its rows.
    planes : ndarray, shape (P, 4), float64
        Unit normal ``n`` and offset ``rho`` of ``n . x = rho``.
    tex_shape : ndarray, shape (P, 2), int64
        Texture rows and columns of each billboard.
    tex_offset : ndarray, shape (P + 1,), int64
        Where each billboard's texels start in the flat texel arrays; each billboard
        has ``LAYERS`` layers of rows x cols texels: first the faces whose normal points
        to the plane normal's side, then the faces facing the other way (so both sides
        of a thin part collapsed onto one plane keep their own texels).
    rgba : ndarray, shape (N, 4), uint8
        Colour and alpha (0 or 255) of every texel, billboard after billboard, layer
        after layer, row-major.
    normal : ndarray, shape (N, 3), int8
        Surface normal at each texel, scaled to -127..127 (0 where alpha is 0).
    eps : float
        Greatest distance of any source face corner from its billboard (world units).
    source_faces : int
        Triangles of the mesh the cloud was built from.
    build_s : float
        Seconds the build took.
    """

    corners: np.ndarray
    planes: np.ndarray
    tex_shape: np.ndarray
    tex_offset: np.ndarray
    rgba: np.ndarray
    normal: np.ndarray
    eps: float
    source_faces: int
    build_s: float = 0.0

    @cached_property
    def tiles(self) -> tuple[np.ndarray, np.ndarray]:
        """Which ``TILE`` x ``TILE`` texel tiles show anything (alpha > 0 in either layer).

        Returns the grids (G,) uint8 (1: the tile holds a texel with alpha > 0), each
        billboard's ceil(rows / TILE) x ceil(cols / TILE) tiles row-major, and where each
        billboard's grid starts, (P + 1,) int64.  Worked out once per cloud (about a
        millisecond per million texels); a renderer draws only the tiles that hold
        something, so a cloud seen close up costs what it shows, not its rectangles.
        """
        return tile_grid(np.ascontiguousarray(self.rgba[:, 3]), self.tex_shape.astype(np.int64),
                         self.tex_offset.astype(np.int64), TILE, LAYERS)

    @property
    def n_billboards(self) -> int:
        """Number of billboards P."""
        return int(self.planes.shape[0])

    def shown_points(self, alpha: int) -> np.ndarray:
        """Centres of the texels with alpha >= ``alpha`` (either layer), shape (N, 3).

        The surface the cloud shows (within ``eps`` and the dilation of the mesh),
        unlike ``corners``: the rectangles bound every face's projection plus whole
        texels, so they reach past the mesh.
        """
        out = []
        for p in range(self.n_billboards):
            rows, cols = (int(x) for x in self.tex_shape[p])
            sl = slice(self.tex_offset[p], self.tex_offset[p + 1])
            shown = (self.rgba[sl, 3].reshape(LAYERS, rows, cols) >= alpha).any(axis=0)
            r, c = np.nonzero(shown)
            o, u, v = self.corners[p, 0], self.corners[p, 1] - self.corners[p, 0], \
                self.corners[p, 3] - self.corners[p, 0]
            out.append(o + np.outer((c + 0.5) / cols, u) + np.outer((r + 0.5) / rows, v))
        return np.concatenate(out) if out else np.zeros((0, 3))

    def texture(self, p: int) -> tuple[np.ndarray, np.ndarray]:
        """Billboard ``p``'s textures (LAYERS, H, W, 4) uint8 and normals (LAYERS, H, W, 3)."""
        h, w = self.tex_shape[p]
        sl = slice(self.tex_offset[p], self.tex_offset[p + 1])
        return (self.rgba[sl].reshape(LAYERS, h, w, 4),
                self.normal[sl].reshape(LAYERS, h, w, 3))


def _basis(n: np.ndarray) -> np.ndarray:
    """Two unit vectors (2, 3) spanning the plane of normal ``n``."""
    t = np.eye(3)[int(np.argmin(np.abs(n)))]
    u = np.cross(n, t)
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(n, u)])


def _billboard(v: np.ndarray, f: np.ndarray, ids: np.ndarray, plane: np.ndarray,
               texel: float) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """One billboard: corners (4, 3), every vertex in texel coordinates (V, 2), (rows, cols)."""
    n, rho = plane[:3], plane[3]
    basis = _basis(n)
    used = np.unique(f[ids])
    origin2, axes2, size = min_area_rectangle(v[used] @ basis.T)
    axes = axes2 @ basis  # (2, 3) world directions of the rectangle's sides
    cols, rows = (max(int(np.ceil(x / texel)), 1) for x in size)
    base = origin2 @ basis + rho * n
    big = np.array([cols, rows]) * texel
    corners = np.array([base, base + big[0] * axes[0], base + big[0] * axes[0] + big[1] * axes[1],
                        base + big[1] * axes[1]])
    uv = (v - base) @ axes.T / texel
    return corners, uv, (rows, cols)


@dataclass(frozen=True)
class _Shoot:
    """What the texture shoot of every billboard needs: the faces on planes and more."""

    v: np.ndarray       # (V, 3) vertices of the faces on planes
    f: np.ndarray       # (F, 3) faces (or pieces) on planes
    fn: np.ndarray      # (F, 3) unit normals
    nrm: np.ndarray     # (F, 3) int8: the same times 127
    centroid: np.ndarray  # (F, 3)
    colour: np.ndarray  # (F, 3) uint8
    texel: float
    grow: int           # dilation, texels

    def billboard(self, ids: np.ndarray, plane: np.ndarray) -> tuple[np.ndarray, ...]:
        """Corners (4, 3), texture (LAYERS, H, W, 4) and normals of faces ``ids``' plane."""
        c, uv, (rows, cols) = _billboard(self.v, self.f, ids, plane, self.texel)
        tex = np.zeros((LAYERS, rows, cols, 4), np.uint8)
        tn = np.zeros((LAYERS, rows, cols, 3), np.int8)
        front = self.fn[ids] @ plane[:3] >= 0
        up = self.centroid @ plane[:3]  # face heights along the plane normal
        for layer, which in enumerate((ids[front], ids[~front])):
            shoot_texture(uv, self.f, which, self.nrm, self.colour, up if layer == 0 else -up,
                          tex[layer], tn[layer])
            dilate_texture(tex[layer], tn[layer], self.grow)
        return c, tex, tn


def build_cloud(vertices: np.ndarray, faces: np.ndarray, eps: float, texture_res: int = 256,
                colours: np.ndarray | None = None,
                settings: PlaneSettings | None = None, dilate: float = 0.5) -> BillboardCloud:
    """Build a billboard cloud of a triangle mesh.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3), float
    faces : ndarray, shape (F, 3), int; F >= 1
    eps : float
        Greatest distance of a face corner from its billboard (world units), > 0.
    texture_res : int
        Texels across the mesh's bounding-box diagonal (the same texel size on
        every billboard), >= 1.
    colours : ndarray, shape (F, 3), uint8, optional
        Face colours (default white: the object's material gives the colour).
    settings : PlaneSettings, optional
        Plane-choice knobs (``eps`` is taken from the argument).
    dilate : float
        Grow each texture's opaque texels by this many ``eps`` (closes the cracks
        between neighbouring billboards seen off their normals; widens silhouettes).

    Raises
    ------
    SimplifyError
        No faces, eps <= 0, texture_res < 1, bad colours.
    """
    t0 = time.perf_counter()
    v, f = check_triangles(vertices, faces)
    if int(texture_res) < 1:
        raise SimplifyError(f"texture resolution must be at least 1, not {texture_res}")
    s = PlaneSettings(eps=eps) if settings is None else PlaneSettings(
        **{**settings.__dict__, "eps": eps})
    col = _face_colours(colours, f.shape[0])
    n_source = int(f.shape[0])
    cover = choose_planes(v, f, s)
    diag = float(np.linalg.norm(v.max(0) - v.min(0))) or 1.0
    texel = diag / int(texture_res)
    # from here on, the faces on planes (pieces of cut faces keep their face's normal)
    fn = _unit_normals(v, f)[cover.parent]
    shoot = _Shoot(cover.vertices, cover.faces, fn, np.round(fn * 127).astype(np.int8),
                   cover.vertices[cover.faces].mean(axis=1), col[cover.parent].astype(np.uint8),
                   texel, int(np.ceil(dilate * eps / texel)))
    return _shoot_cloud(shoot, cover, eps, n_source, t0)


def _face_colours(colours: np.ndarray | None, n_faces: int) -> np.ndarray:
    """The faces' colours, shape (F, 3): white when ``colours`` is None, else checked."""
    col = np.full((n_faces, 3), 255, np.uint8) if colours is None else np.asarray(colours)
    if col.shape != (n_faces, 3):
        raise SimplifyError(f"colours must have shape ({n_faces}, 3), not {col.shape}")
    return col


def _unit_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Unit normals of the triangles ``f`` (F, 3) of ``v`` (V, 3): shape (F, 3).

    A zero-area triangle's normal stays (near) zero instead of dividing by zero.
    """
    a = v[f]
    fn = np.cross(a[:, 1] - a[:, 0], a[:, 2] - a[:, 0])
    fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
    return fn


def _shoot_cloud(shoot: _Shoot, cover: PlaneCover, eps: float, n_source: int,
                 t0: float) -> BillboardCloud:
    """Shoot every plane's texture and pack the billboards into one cloud.

    ``cover`` is :func:`~service.simplify.planes.choose_planes`' answer: ``planes``
    (B, 4) and ``owner`` (F',), the plane of each face on a plane.  The textures'
    texels are packed one billboard after another (``tex_offset``, shape (B + 1,)).
    """
    planes = cover.planes
    corners, shapes, rgba, normal = [], [], [], []
    for p in range(planes.shape[0]):
        c, tex, tn = shoot.billboard(np.flatnonzero(cover.owner == p), planes[p])
        corners.append(c)
        shapes.append(tex.shape[1:3])
        rgba.append(tex.reshape(-1, 4))
        normal.append(tn.reshape(-1, 3))
    sizes = np.array([LAYERS * r * c for r, c in shapes], np.int64)
    return BillboardCloud(
        corners=np.array(corners), planes=planes, tex_shape=np.array(shapes, np.int64),
        tex_offset=np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
        rgba=np.concatenate(rgba), normal=np.concatenate(normal), eps=float(eps),
        source_faces=n_source, build_s=time.perf_counter() - t0)
