"""Billboard clouds in the render pipeline: textured, alpha-tested quads in every zone.

A scene's ``billboards`` (:class:`BillboardObject`: a
:class:`~service.simplify.billboard.BillboardCloud` with a material and a placement)
are drawn after the occlusion stage, into the same depth buffer, for every view zone:
each pixel's ray (the zone's sheared orthographic ray, :mod:`service.render.projection`) is
intersected with each quad's plane inside the quad's screen box (nearest quads first,
each row clipped to the quad's span; close up, only over the texture tiles that show
something: :attr:`~service.simplify.billboard.BillboardCloud.tiles`), the depth test
comes first, then the texel is alpha-tested (opaque from 128), and the nearer of quad
and mesh wins.  Cracks along the seams between billboards are closed after the
quads: a back-facing texel, or a neighbour's texel, stands in where front-facing
texels show on both sides (:func:`_fill_back`).  Lighting is deferred: the draw
leaves the winning quad and texel per pixel, and
:meth:`BillboardPass.paint` lights each shown pixel once, inside the box the quads
touched (not once per quad drawn over it, nor over the whole frame).  That is a
z-buffer of quads with ray casting per pixel, so the ``zbuffer`` and ``raycast``
methods hold billboards exactly.  Run-length and BSP occlusion cannot (a quad's
alpha-tested outline is no polygon edge list, and it crosses other objects'
polygons freely), so for those methods billboards take the same z-buffered pass
over the method's own depth buffer, and the stats say so
(``stats["billboards"]["drawn_with"]``).

Light per shown pixel (its texel) uses the object's material, the texel's colour and the normal of
the face shot into the texel, with the same Phong / Blinn model per zone as meshes
(:func:`service.render.light._light_rgb`).  **What a billboard loses** (``docs/simplify.md``):

* the point lit is on the billboard, up to EPS from the true surface, so point
  lights and specular highlights shift by that much;
* one normal per texel, quantised to 8 bits: a highlight narrower than a texel
  (high shininess, or low ``--texture-res``) is blurred or lost, and the specular
  response changes by texel rather than smoothly across zones;
* where faces from both sides of a thin part were collapsed onto one plane, a texel
  keeps only the face shot last, so from the other side it shows that face's normal
  (wrong diffuse and highlight on that side);
* light is always evaluated per texel (the ``--specular polygon|vertex`` choices do
  not apply), and parallax inside the EPS slab is gone: close up or at grazing
  angles the silhouette and depth are off by up to EPS / cos(angle).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba as nb
import numpy as np

from service.display import DisplaySettings
from service.numba_subroutine import subroutine
from service.render.light import MODELS, LightSettings, _light_rgb, pack_lights
from service.render.occlusion import Visibility
from service.render.scene import Light, Material, Transform, quaternion_matrices
from service.simplify.billboard import TILE, BillboardCloud

ALPHA_OPAQUE = 128
"""Texels with alpha at or above this are drawn (alpha test)."""
#: Occlusion method -> how billboards are drawn with it.
#: A quad is drawn tile by tile (only its texture's tiles that show something) when its
#: screen box holds at least this many pixels per tile; below that a rectangle's set-up
#: costs more than the empty pixels it skips, and the quad is drawn whole.
TILE_MIN_PIXELS = 2
#: A back-facing texel stands in for a hole (:func:`_fill_back`) only where front-facing
#: texels show within this many pixels on both sides of it, across a row or a column: a
#: crack along a seam (up to 2 x FILL_REACH - 1 px wide) inside the cloud's picture, not
#: its silhouette.
FILL_REACH = 8
DRAWN_WITH = {"zbuffer": "zbuffer", "raycast": "raycast", "runlength": "zbuffer",
              "bsp": "zbuffer"}


@dataclass(frozen=True)
class BillboardObject:
    """A billboard cloud placed in a scene: world point = position + R (scale p)."""

    cloud: BillboardCloud
    material: Material = field(default_factory=Material)
    transform: Transform = field(default_factory=Transform)
    name: str = ""


@dataclass(frozen=True)
class _Quads:
    """Every billboard of a scene in world coordinates, packed for the kernels."""

    origin: np.ndarray   # (Q, 3)
    u: np.ndarray        # (Q, 3) full edge along texture rows
    v: np.ndarray        # (Q, 3) full edge down the rows
    normal: np.ndarray   # (Q, 3) unit plane normal
    rot: np.ndarray      # (Q, 3, 3) object rotation, for texel normals
    material: np.ndarray  # (Q, 7)
    tex: np.ndarray      # (Q, 3) int64: texel offset, rows, cols
    rgba: np.ndarray     # (N, 4) uint8
    tnormal: np.ndarray  # (N, 3) int8
    grid: np.ndarray     # (G,) uint8: tiles that show something (BillboardCloud.tiles)
    gofs: np.ndarray     # (Q,) int64: where each quad's tiles start in grid


def _textures(objects: list[BillboardObject]) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                       dict[int, tuple[int, int]]]:
    """Texels and tile grids of every distinct cloud (each once), and each cloud's first ones.

    Returns ``rgba`` (N, 4), ``normal`` (N, 3), the tile grids (G,) and, per cloud's
    ``id``, its first texel and first tile.  One distinct cloud (a crowd of copies,
    or one object) is used as it is, without a copy: the textures are megabytes and a
    frame needs them only to read.
    """
    clouds = list({id(o.cloud): o.cloud for o in objects}.values())
    if len(clouds) == 1:
        c = clouds[0]
        return (np.ascontiguousarray(c.rgba, np.uint8), np.ascontiguousarray(c.normal, np.int8),
                c.tiles[0], {id(c): (0, 0)})
    base, tbase, offsets = 0, 0, {}
    for c in clouds:
        offsets[id(c)] = (base, tbase)
        base += int(c.tex_offset[-1])
        tbase += int(c.tiles[1][-1])
    if not clouds:
        return (np.zeros((0, 4), np.uint8), np.zeros((0, 3), np.int8), np.zeros(0, np.uint8),
                offsets)
    return (np.concatenate([c.rgba for c in clouds]).astype(np.uint8, copy=False),
            np.concatenate([c.normal for c in clouds]).astype(np.int8, copy=False),
            np.concatenate([c.tiles[0] for c in clouds]), offsets)


def pack_quads(objects: list[BillboardObject]) -> _Quads:
    """World-space quads of every billboard object (see :class:`_Quads`).

    Quads are numbered object after object, each cloud's billboards in order.  The
    objects sharing a cloud (a crowd) are transformed together, a few array
    operations per cloud rather than per object.
    """
    rgba, tnormal, grid, first = _textures(objects)
    counts = np.array([o.cloud.n_billboards for o in objects], np.int64)
    start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    total = int(start[-1])
    corners = np.empty((total, 4, 3))
    normal = np.empty((total, 3))
    rot = np.empty((total, 3, 3))
    material = np.empty((total, 7))
    tex = np.empty((total, 3), np.int64)
    gofs = np.empty(total, np.int64)
    rots = quaternion_matrices(np.array([o.transform.orientation for o in objects]))
    groups: dict[int, list[int]] = {}
    for k, o in enumerate(objects):
        groups.setdefault(id(o.cloud), []).append(k)
    for ks in groups.values():
        c = objects[ks[0]].cloud
        ids = np.array(ks)
        scale = np.array([objects[k].transform.scale for k in ks], np.float64)
        pos = np.array([objects[k].transform.position for k in ks], np.float64).reshape(-1, 3)
        r = rots[ids]
        # matmul, not einsum: einsum's loops took 9 ms for a crowd of 200 bunny clouds
        rs = (r * scale[:, None, None]).transpose(0, 2, 1)
        w = (c.corners.reshape(-1, 3) @ rs).reshape(len(ks), -1, 4, 3) + pos[:, None, None]
        n = c.planes[:, :3] @ r.transpose(0, 2, 1)
        n /= np.linalg.norm(n, axis=2, keepdims=True)
        t0, g0 = first[id(c)]
        t = np.stack([c.tex_offset[:-1] + t0, c.tex_shape[:, 0], c.tex_shape[:, 1]], 1)
        g = c.tiles[1][:-1] + g0
        at = (start[ids][:, None] + np.arange(c.n_billboards)).ravel()  # their quads
        corners[at], normal[at] = w.reshape(-1, 4, 3), n.reshape(-1, 3)
        rot[at] = np.repeat(r, c.n_billboards, axis=0)
        tex[at], gofs[at] = np.tile(t, (len(ks), 1)), np.tile(g, len(ks))
        mats = np.array([(*objects[k].material.colour, objects[k].material.ambient,
                          objects[k].material.diffuse, objects[k].material.specular,
                          objects[k].material.shininess) for k in ks], np.float64)
        material[at] = np.repeat(mats, c.n_billboards, axis=0)
    return _Quads(origin=np.ascontiguousarray(corners[:, 0]),
                  u=corners[:, 1] - corners[:, 0], v=corners[:, 3] - corners[:, 0],
                  normal=normal, rot=rot, material=material, tex=tex, rgba=rgba, tnormal=tnormal,
                  grid=grid, gofs=gofs)


def quad_points(objects: list[BillboardObject]) -> np.ndarray:
    """Each quad's origin, origin + U and origin + V in the world, (3Q, 3), quad order.

    The motion of a billboard pixel is affine over its (rigid, planar) quad, so the
    derivatives of these three points give every pixel's (:meth:`BillboardPass.write_motion`).
    """
    if not objects:
        return np.zeros((0, 3))
    rots = quaternion_matrices(np.array([o.transform.orientation for o in objects]))
    out = [o.cloud.corners[:, (0, 1, 3)].reshape(-1, 3) @ (r * o.transform.scale).T
           + o.transform.position for o, r in zip(objects, rots, strict=True)]
    return np.ascontiguousarray(np.concatenate(out))


@nb.njit(cache=True, nogil=True)
def quad_motion_kernel(quad: np.ndarray, depth: np.ndarray, boxes: np.ndarray,
                       origin: np.ndarray, u: np.ndarray, v: np.ndarray, shears: np.ndarray,
                       s: float, hw: float, hh: float, cd: np.ndarray, der: np.ndarray) -> None:
    """Motion derivatives of the pixels quads won, from their quads' points' derivatives.

    ``cd`` (3, Z, 3Q, 3): derivatives 1..3 of x, y (px) and depth of each quad's
    :func:`quad_points` per zone; a pixel at quad coordinates (a, b) gets
    ``d0 + a (dU - d0) + b (dV - d0)`` in ``der`` (3, 3, Z, R, C) float32.
    """
    for k in range(quad.shape[0]):
        sh = shears[k]
        for i in range(boxes[k, 0], boxes[k, 1]):
            y = hh - (i + 0.5) * s
            for j in range(boxes[k, 2], boxes[k, 3]):
                q = quad[k, i, j] - 1
                if q < 0:
                    continue
                z = -np.float64(depth[k, i, j])
                ex, ey, ez = (j + 0.5) * s - hw + z * sh - origin[q, 0], y - origin[q, 1], \
                    z - origin[q, 2]
                uq, vq = u[q], v[q]
                a = (ex * uq[0] + ey * uq[1] + ez * uq[2]) / (uq[0] ** 2 + uq[1] ** 2 + uq[2] ** 2)
                b = (ex * vq[0] + ey * vq[1] + ez * vq[2]) / (vq[0] ** 2 + vq[1] ** 2 + vq[2] ** 2)
                for n in range(3):
                    for d in range(3):
                        c0 = cd[n, k, 3 * q, d]
                        der[n, d, k, i, j] = c0 + a * (cd[n, k, 3 * q + 1, d] - c0) + \
                            b * (cd[n, k, 3 * q + 2, d] - c0)


@subroutine(nrt=True)
def _screen_box(o: np.ndarray, u: np.ndarray, v: np.ndarray, ab: tuple, sh: float, s: float,
                hw: float, hh: float, cols: int, rows: int) -> tuple[int, int, int, int]:
    """Pixel rows and columns [r0, r1) x [c0, c1) whose centres a part of a quad can hold.

    The part is quad coordinates ``ab`` = (a0, a1, b0, b1): a in [a0, a1], b in [b0, b1]
    ((0, 1, 0, 1): the whole quad).  Only pixel centres are sampled, so a quad a pixel
    or two across gets the one or two rows whose centres it spans (with 1e-6 pixel of
    slack), not four.
    """
    x0, x1, y0, y1 = np.inf, -np.inf, np.inf, -np.inf
    for ca in (ab[0], ab[1]):
        for cb in (ab[2], ab[3]):
            px = o[0] + ca * u[0] + cb * v[0]
            py = o[1] + ca * u[1] + cb * v[1]
            pz = o[2] + ca * u[2] + cb * v[2]
            sx = (px - pz * sh + hw) / s
            sy = (hh - py) / s
            x0, x1, y0, y1 = min(x0, sx), max(x1, sx), min(y0, sy), max(y1, sy)
    return (max(int(np.ceil(y0 - 0.5 - 1e-6)), 0), min(int(np.floor(y1 - 0.5 + 1e-6)) + 1, rows),
            max(int(np.ceil(x0 - 0.5 - 1e-6)), 0), min(int(np.floor(x1 - 0.5 + 1e-6)) + 1, cols))


@subroutine(nrt=True)
def _span(a0: float, da: float, b0: float, db: float, ab: tuple, s: float, hw: float, c0: int,
          c1: int) -> tuple[int, int]:
    """Columns [j0, j1) of a row where ``ab[0] <= a0 + da x < ab[1]`` and likewise b in ``ab[2:]``.

    ``x = (j + 0.5) s - hw``; one column of slack each side (the caller re-tests).
    """
    lo, hi = -np.inf, np.inf
    for c0_, d_, l_, h_ in ((a0, da, ab[0], ab[1]), (b0, db, ab[2], ab[3])):
        if d_ == 0.0:
            if not (l_ - 1e-9 <= c0_ < h_ + 1e-9):
                return 0, 0
            continue
        e0, e1 = (l_ - c0_) / d_, (h_ - c0_) / d_
        lo = max(lo, min(e0, e1))
        hi = min(hi, max(e0, e1))
    if not hi >= lo:  # also NaN
        return 0, 0
    j0 = max(int(np.floor((lo + hw) / s - 0.5)), c0)
    j1 = min(int(np.ceil((hi + hw) / s - 0.5)) + 1, c1)
    return j0, max(j1, j0)


@subroutine(nrt=True)
def _tile_runs(q: int, tex: np.ndarray, grid: np.ndarray, gofs: np.ndarray, tile: int,
               runs: np.ndarray) -> int:
    """The texel rectangles of quad ``q`` that hold its shown tiles, into ``runs``.

    Each tile row's runs of non-empty tiles, a run merged into the one above when
    their columns match: ``runs`` (>= tiles, 4) int64 receives texel rows and
    columns [i0, i1) x [j0, j1) per rectangle; returns how many.
    """
    rows, cols = tex[q, 1], tex[q, 2]
    tcols = (cols + tile - 1) // tile
    # runs so far; the first run of the tile row above (typed: a literal 0 passed to
    # _runs_reaching compiled a second signature of it)
    n, above = np.int64(0), np.int64(0)
    for ti in range(0, (rows + tile - 1) // tile):
        here = n
        i0, i1 = ti * tile, min(ti * tile + tile, rows)
        tj = 0
        while tj < tcols:
            if grid[gofs[q] + ti * tcols + tj] == 0:
                tj += 1
                continue
            t0 = tj
            while tj < tcols and grid[gofs[q] + ti * tcols + tj] != 0:
                tj += 1
            j0, j1 = t0 * tile, min(tj * tile, cols)
            merged = False
            for m in range(above, here):
                if runs[m, 1] == i0 and runs[m, 2] == j0 and runs[m, 3] == j1:
                    runs[m, 1] = i1
                    merged = True
                    break
            if not merged:
                runs[n, 0], runs[n, 1], runs[n, 2], runs[n, 3] = i0, i1, j0, j1
                n += 1
        above = _runs_reaching(runs, above, n, i1)
    return n


@subroutine(nrt=True)
def _runs_reaching(runs: np.ndarray, first: int, n: int, i1: int) -> int:
    """Index of the first run from ``first`` on whose rows reach ``i1`` (runs [first, n)).

    Runs that stop above a tile row never grow again, so the next row's merges only
    look from there; ones that end above it but sit after it are skipped by the
    column test (their row end differs).
    """
    for m in range(first, n):
        if runs[m, 1] == i1:
            return m
    return n


@subroutine(nrt=True)
def _nearest_first(origin: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Quad indices (Q,) by their nearest corner's z, nearest first (early depth rejects)."""
    key = np.empty(origin.shape[0])
    for q in range(origin.shape[0]):
        z = origin[q, 2] + max(u[q, 2], 0.0) + max(v[q, 2], 0.0)
        key[q] = -z
    return np.argsort(key)


@nb.njit(cache=True, nogil=True)
def draw_quads_kernel(origin: np.ndarray, u: np.ndarray, v: np.ndarray, normal: np.ndarray,
                      rot: np.ndarray, tex: np.ndarray, rgba: np.ndarray, tnormal: np.ndarray,
                      grid: np.ndarray, gofs: np.ndarray, tile: int,
                      shears: np.ndarray, s: float, hw: float, hh: float,
                      views: np.ndarray, cull_back: bool, depth: np.ndarray, tri: np.ndarray,
                      quad: np.ndarray, texel: np.ndarray, boxes: np.ndarray,
                      bquad: np.ndarray, btexel: np.ndarray,
                      bdepth: np.ndarray) -> tuple[int, int, int]:
    """Draw every quad into every zone (z-test against ``depth``, alpha test); see module.

    Nearest quads first, so farther ones mostly fail the depth test before any texel
    is read.  A quad whose screen box holds at least ``TILE_MIN_PIXELS`` pixels per
    texture tile is drawn only over its tiles that show something (``grid`` (G,)
    uint8, quad ``q``'s ``tile`` x ``tile`` texel tiles from ``gofs[q]``,
    :attr:`~service.simplify.billboard.BillboardCloud.tiles`), rectangle by
    rectangle (:func:`_tile_runs`); the pixels drawn are the same.  ``rot`` (Q, 3, 3)
    is each quad's object rotation (texel normals are in the object's frame: the
    back-face test takes the view into it).  ``depth`` (Z, R, C) float32 and ``tri``
    (Z, R, C) int32 are updated where a quad wins (``tri`` set to -1: no mesh
    triangle); ``quad`` (Z, R, C) int32 receives the quad's index + 1 and ``texel``
    the texel's flat index there (both only where a quad won; zero elsewhere on
    entry).  ``boxes`` (Z, 4) int64 receives each zone's rows and columns
    ``[r0, r1) x [c0, c1)`` holding every write.  ``bquad``, ``btexel`` (Z, R, C)
    int32 (zero on entry) and ``bdepth`` (Z, R, C) float32 keep the nearest
    back-facing texel per pixel, drawn only where no front-facing one won
    (:func:`_fill_back`; with ``cull_back`` False every texel counts as facing).
    Returns the number of pixel writes, of pixels a quad won (each counted once) and
    of pixels visited (span pixels).
    """
    zones, rows, cols = depth.shape
    writes, covered, visited = 0, 0, 0
    order = _nearest_first(origin, u, v)
    most = 1
    for q in range(origin.shape[0]):
        most = max(most, ((tex[q, 1] + tile - 1) // tile) * ((tex[q, 2] + tile - 1) // tile))
    runs = np.empty((most, 4), np.int64)
    for k in range(zones):
        sh = shears[k]
        boxes[k, 0], boxes[k, 1], boxes[k, 2], boxes[k, 3] = rows, 0, cols, 0
        for q in order:
            n = normal[q]
            den = n[0] * sh + n[2]
            if abs(den) < 1e-9:
                continue  # seen edge-on in this zone
            o, uq, vq = origin[q], u[q], v[q]
            uu = uq[0] * uq[0] + uq[1] * uq[1] + uq[2] * uq[2]
            vv = vq[0] * vq[0] + vq[1] * vq[1] + vq[2] * vq[2]
            rho = n[0] * o[0] + n[1] * o[1] + n[2] * o[2]
            view = views[k]
            near = 0 if n[0] * view[0] + n[1] * view[1] + n[2] * view[2] >= 0.0 else 1
            vx = rot[q, 0, 0] * view[0] + rot[q, 1, 0] * view[1] + rot[q, 2, 0] * view[2]
            vy = rot[q, 0, 1] * view[0] + rot[q, 1, 1] * view[1] + rot[q, 2, 1] * view[2]
            vz = rot[q, 0, 2] * view[0] + rot[q, 1, 2] * view[1] + rot[q, 2, 2] * view[2]
            r0, r1, c0, c1 = _screen_box(o, uq, vq, (0.0, 1.0, 0.0, 1.0), sh, s, hw, hh, cols, rows)
            dzx = -n[0] / den  # z, and so a and b, are linear in x along a row
            da = ((1.0 + dzx * sh) * uq[0] + dzx * uq[2]) / uu
            db = ((1.0 + dzx * sh) * vq[0] + dzx * vq[2]) / vv
            trows, tcols, t0 = tex[q, 1], tex[q, 2], tex[q, 0]
            tiles = ((trows + tile - 1) // tile) * ((tcols + tile - 1) // tile)
            whole = (r1 - r0) * (c1 - c0) < TILE_MIN_PIXELS * tiles
            if whole:
                n_runs = 1
                runs[0, 0], runs[0, 1], runs[0, 2], runs[0, 3] = 0, trows, 0, tcols
            else:
                n_runs = _tile_runs(q, tex, grid, gofs, tile, runs)
            g0, gcols = gofs[q], (tcols + tile - 1) // tile
            for m in range(n_runs):
                i0t, i1t, j0t, j1t = runs[m, 0], runs[m, 1], runs[m, 2], runs[m, 3]
                ab = (j0t / tcols, j1t / tcols, i0t / trows, i1t / trows)
                rr0, rr1, cc0, cc1 = r0, r1, c0, c1  # the whole quad's
                if n_runs > 1 or i1t - i0t < trows or j1t - j0t < tcols:
                    rr0, rr1, cc0, cc1 = _screen_box(o, uq, vq, ab, sh, s, hw, hh, cols, rows)
                for i in range(max(rr0, r0), min(rr1, r1)):
                    y = hh - (i + 0.5) * s
                    z0 = (rho - n[1] * y) / den  # at x = 0
                    ex, ey, ez = z0 * sh - o[0], y - o[1], z0 - o[2]
                    a0 = (ex * uq[0] + ey * uq[1] + ez * uq[2]) / uu
                    b0 = (ex * vq[0] + ey * vq[1] + ez * vq[2]) / vv
                    j0, j1 = _span(a0, da, b0, db, ab, s, hw, max(cc0, c0), min(cc1, c1))
                    visited += j1 - j0
                    for j in range(j0, j1):
                        x0 = (j + 0.5) * s - hw
                        z = z0 + dzx * x0
                        if -z >= depth[k, i, j]:
                            continue
                        a = a0 + da * x0
                        b = b0 + db * x0
                        if not (0.0 <= a < 1.0 and 0.0 <= b < 1.0):  # NaN too
                            continue
                        ti = min(int(b * trows), trows - 1)
                        tj = min(int(a * tcols), tcols - 1)
                        if not (i0t <= ti < i1t and j0t <= tj < j1t):
                            continue  # another rectangle's texel
                        if whole and grid[g0 + (ti // tile) * gcols + tj // tile] == 0:
                            continue  # an empty tile: no texel read (a small, far quad)
                        # the texel choice stays written out here: as a helper function
                        # (even inline="always") the kernel measured 1.4-1.5x slower
                        t, back = -1, -1
                        for layer in (near, 1 - near):  # the layer facing the viewer first
                            c = t0 + layer * trows * tcols + ti * tcols + tj
                            if rgba[c, 3] < ALPHA_OPAQUE:
                                continue
                            if not cull_back or (tnormal[c, 0] * vx + tnormal[c, 1] * vy
                                                 + tnormal[c, 2] * vz) >= 0.0:
                                t = c
                                break
                            if back < 0:
                                back = c
                        if t < 0:
                            if back >= 0 and (bquad[k, i, j] == 0 or -z < bdepth[k, i, j]):
                                bquad[k, i, j], btexel[k, i, j] = q + 1, back
                                bdepth[k, i, j] = -z  # a stand-in, if no front texel comes
                                boxes[k, 0] = min(boxes[k, 0], i)
                                boxes[k, 1] = max(boxes[k, 1], i + 1)
                                boxes[k, 2] = min(boxes[k, 2], j)
                                boxes[k, 3] = max(boxes[k, 3], j + 1)
                            continue
                        depth[k, i, j] = -z
                        tri[k, i, j] = -1
                        covered += quad[k, i, j] == 0
                        quad[k, i, j] = q + 1
                        texel[k, i, j] = t
                        writes += 1
                        boxes[k, 0], boxes[k, 1] = min(boxes[k, 0], i), max(boxes[k, 1], i + 1)
                        boxes[k, 2], boxes[k, 3] = min(boxes[k, 2], j), max(boxes[k, 3], j + 1)
        w, c = _fill_back(k, boxes, bquad, btexel, bdepth, depth, tri, quad, texel)
        writes, covered = writes + w, covered + c
    return writes, covered, visited


@subroutine(nrt=True)
def _front_near(quad: np.ndarray, bquad: np.ndarray, k: int, i: int, j: int, di: int,
                dj: int, reach: int) -> bool:
    """Whether front-facing texels show on both sides of ``(i, j)`` along ``(di, dj)``.

    Within ``reach`` pixels: a crack across that line, not the silhouette.
    """
    rows, cols = quad.shape[1], quad.shape[2]
    for side in (-1, 1):
        seen = False
        for d in range(1, reach + 1):
            a, b = i + side * d * di, j + side * d * dj
            if 0 <= a < rows and 0 <= b < cols and quad[k, a, b] > 0 and bquad[k, a, b] >= 0:
                seen = True
                break
        if not seen:
            return False
    return True


@subroutine(nrt=True)
def _fill_back(k: int, boxes: np.ndarray, bquad: np.ndarray, btexel: np.ndarray,
               bdepth: np.ndarray, depth: np.ndarray, tri: np.ndarray, quad: np.ndarray,
               texel: np.ndarray) -> tuple[int, int]:
    """Close zone ``k``'s cracks: pixels no texel won with front-facing texels around.

    Where both layers' texels at a ray's point face away from the view, the ray is near
    a seam between billboards seen off their normals (the texel holds the face nearest
    the plane along its normal, not the one the ray meets): a hole there showed what
    lies behind (speckle along the seams).  The nearest back-facing texel stands in
    where front-facing ones show on both sides within :data:`FILL_REACH` pixels (its
    light uses its normal turned to the viewer).  A pixel between two front-facing
    ones, across a row or a column, that no texel covers at all takes the nearer
    neighbour's texel at the pair's mean depth.  Neither is drawn behind the mesh's
    depth.  Returns pixel writes and pixels covered.
    """
    writes = 0
    zero, one = np.int64(0), np.int64(1)  # typed: literals would compile a twin of _front_near
    for _ in range(2):  # again: a pixel whose neighbour was filled after it was looked at
        for i in range(boxes[k, 0], boxes[k, 1]):
            for j in range(boxes[k, 2], boxes[k, 3]):
                if quad[k, i, j] != 0:
                    continue
                q, t, d = 0, 0, np.inf
                if bquad[k, i, j] > 0 and bdepth[k, i, j] < depth[k, i, j] and (
                        _front_near(quad, bquad, k, i, j, zero, one, FILL_REACH)
                        or _front_near(quad, bquad, k, i, j, one, zero, FILL_REACH)):
                    d, q, t = np.float64(bdepth[k, i, j]), bquad[k, i, j], btexel[k, i, j]
                if q == 0:
                    d, q, t = _between(quad, depth, texel, k, i, j)
                if q == 0 or d >= depth[k, i, j]:
                    continue
                depth[k, i, j] = d
                tri[k, i, j] = -1
                quad[k, i, j], texel[k, i, j] = q, t
                bquad[k, i, j] = -1  # filled: not a front texel for its neighbours
                writes += 1
    return writes, writes


@subroutine(nrt=True)
def _between(quad: np.ndarray, depth: np.ndarray, texel: np.ndarray, k: int, i: int,
             j: int) -> tuple[float, int, int]:
    """The nearer of two drawn neighbours across ``(i, j)``: mean depth, quad, texel.

    ``(inf, 0, 0)`` when no row or column pair around it shows texels.
    """
    rows, cols = quad.shape[1], quad.shape[2]
    for di, dj in ((0, 1), (1, 0)):
        a0, b0, a1, b1 = i - di, j - dj, i + di, j + dj
        if a0 >= 0 and b0 >= 0 and a1 < rows and b1 < cols and quad[k, a0, b0] > 0 \
                and quad[k, a1, b1] > 0:
            near = (a0, b0) if depth[k, a0, b0] <= depth[k, a1, b1] else (a1, b1)
            mean = (np.float64(depth[k, a0, b0]) + np.float64(depth[k, a1, b1])) / 2
            return mean, quad[k, near[0], near[1]], texel[k, near[0], near[1]]
    return np.inf, 0, 0


@nb.njit(cache=True, nogil=True)
def shade_quads_kernel(quad: np.ndarray, texel: np.ndarray, depth: np.ndarray,
                       boxes: np.ndarray, rot: np.ndarray, material: np.ndarray,
                       rgba: np.ndarray, tnormal: np.ndarray, shears: np.ndarray, s: float,
                       hw: float, hh: float, views: np.ndarray, lights: tuple,
                       ambient: float, code: int, colour: np.ndarray) -> int:
    """Light every pixel a quad won, once, into ``colour`` (Z, R, C, 3) uint8.

    Deferred: :func:`draw_quads_kernel` leaves the winning quad and texel per pixel;
    the lit point is the pixel's ray at its depth.  Returns the pixels lit.
    """
    mat = np.empty(7)
    lit = 0
    for k in range(quad.shape[0]):
        sh, view = shears[k], views[k]
        for i in range(boxes[k, 0], boxes[k, 1]):
            y = hh - (i + 0.5) * s
            for j in range(boxes[k, 2], boxes[k, 3]):
                q = quad[k, i, j] - 1
                if q < 0:
                    continue
                t = texel[k, i, j]
                z = -np.float64(depth[k, i, j])
                for c in range(7):
                    mat[c] = material[q, c]
                for c in range(3):
                    mat[c] *= rgba[t, c] / 255.0
                nx, ny, nz = _texel_normal(q, t, rot, tnormal, view)
                rgb = _light_rgb((j + 0.5) * s - hw + z * sh, y, z, nx, ny, nz, mat, view,
                                 lights, ambient, code)
                for c in range(3):
                    colour[k, i, j, c] = np.uint8(np.float64(np.float32(rgb[c])) * 255.0 + 0.5)
                lit += 1
    return lit


@nb.njit(cache=True, nogil=True, inline="always")
def _texel_normal(q: int, t: int, rot: np.ndarray, tnormal: np.ndarray,
                  view: np.ndarray) -> tuple[float, float, float]:
    """Texel ``t``'s normal in the world (unnormalised), turned toward the viewer."""
    a, b, c = np.float64(tnormal[t, 0]), np.float64(tnormal[t, 1]), np.float64(tnormal[t, 2])
    nx = rot[q, 0, 0] * a + rot[q, 0, 1] * b + rot[q, 0, 2] * c
    ny = rot[q, 1, 0] * a + rot[q, 1, 1] * b + rot[q, 1, 2] * c
    nz = rot[q, 2, 0] * a + rot[q, 2, 1] * b + rot[q, 2, 2] * c
    if nx * view[0] + ny * view[1] + nz * view[2] < 0.0:
        return -nx, -ny, -nz
    return nx, ny, nz


@dataclass
class BillboardPass:
    """What :func:`draw_billboards` drew; :meth:`paint` lights it into the shaded frame.

    Lighting is deferred to :meth:`paint`, so each pixel a billboard shows is lit once
    (not once per quad drawn over it), and only inside the zones' ``boxes``.
    """

    quad: np.ndarray     # (Z, R, C) int32: index + 1 of the quad seen, 0 for none
    texel: np.ndarray    # (Z, R, C) int32: the texel seen (where quad > 0)
    depth: np.ndarray    # (Z, R, C) float32: the visibility pass's depth buffer
    boxes: np.ndarray    # (Z, 4) int64: rows r0, r1 and columns c0, c1 holding the quads
    quads: _Quads
    light: tuple         # display, lights, ambient, light settings
    stats: dict

    @property
    def mask(self) -> np.ndarray:
        """Where a billboard won, (Z, R, C) bool."""
        return self.quad > 0

    def paint(self, frame_colour: np.ndarray) -> None:
        """Light the billboards' pixels into ``frame_colour`` (Z, R, C, 3) uint8."""
        display, lights, ambient, settings = self.light
        qd = self.quads
        shade_quads_kernel(self.quad, self.texel, self.depth, self.boxes, qd.rot, qd.material,
                           qd.rgba, qd.tnormal, display.shears(), display.pixel_size,
                           display.width / 2, display.height / 2, display.view_vectors(),
                           pack_lights(lights), float(ambient), MODELS[settings.model],
                           frame_colour)


    def write_motion(self, point_derivs: np.ndarray, der: np.ndarray) -> None:
        """Fill the motion derivatives ``der`` (3, 3, Z, R, C) at the pixels quads won.

        ``point_derivs`` (3, Z, 3Q, 3) are the derivatives of :func:`quad_points`
        (x, y in px and depth, per refresh^n), as ``vertex_derivatives`` gives them.
        """
        display, qd = self.light[0], self.quads
        quad_motion_kernel(self.quad, self.depth, self.boxes, qd.origin, qd.u, qd.v,
                           display.shears(), display.pixel_size, display.width / 2,
                           display.height / 2, np.ascontiguousarray(point_derivs, np.float64),
                           der)


def draw_billboards(objects: list[BillboardObject], display: DisplaySettings,
                    vis: Visibility, method: str, lights: list[Light], ambient: float,
                    light: LightSettings, cull_back: bool = True) -> BillboardPass:
    """Draw billboard objects into ``vis`` (depth and triangle, in place) for every zone.

    Returns
    -------
    BillboardPass
        Where they won (lit by its :meth:`~BillboardPass.paint`); ``stats``:
        ``objects``, ``quads``, ``pixels`` (writes), ``covered_pixels`` (pixels they
        show), ``span_pixels`` (pixels visited: ray, depth test and texel lookup) and
        ``drawn_with``.
    """
    quads = pack_quads(objects)
    zrc = vis.depth.shape
    quad = np.zeros(zrc, np.int32)  # calloc: pages outside the quads are never touched
    texel = np.zeros(zrc, np.int32)
    boxes = np.zeros((zrc[0], 4), np.int64)
    back = (np.zeros(zrc, np.int32), np.zeros(zrc, np.int32), np.zeros(zrc, np.float32))
    writes, covered, visited = draw_quads_kernel(
        quads.origin, quads.u, quads.v, quads.normal, quads.rot, quads.tex, quads.rgba,
        quads.tnormal, quads.grid, quads.gofs, TILE, display.shears(), display.pixel_size,
        display.width / 2, display.height / 2, display.view_vectors(), cull_back, vis.depth,
        vis.triangle, quad, texel, boxes, *back)
    stats = {"objects": len(objects), "quads": int(quads.origin.shape[0]), "pixels": int(writes),
             "covered_pixels": int(covered), "span_pixels": int(visited),
             "drawn_with": DRAWN_WITH.get(method, "zbuffer")}
    if DRAWN_WITH.get(method, "zbuffer") != method:
        stats["note"] = f"{method} cannot hold alpha-tested quads: billboards z-buffered"
    return BillboardPass(quad, texel, vis.depth, boxes, quads, (display, lights, ambient, light),
                         stats)
