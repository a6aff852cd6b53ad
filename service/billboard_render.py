"""Billboard clouds in the render pipeline: textured, alpha-tested quads in every zone.

A scene's ``billboards`` (:class:`BillboardObject`: a
:class:`~service.simplify.billboard.BillboardCloud` with a material and a placement)
are drawn after the occlusion stage, into the same depth buffer, for every view zone:
each pixel's ray (the zone's sheared orthographic ray, :mod:`service.projection`) is
intersected with each quad's plane inside the quad's screen box, the texel there is
alpha-tested (opaque from 128), and the nearer of quad and mesh wins.  That is a
z-buffer of quads with ray casting per pixel, so the ``zbuffer`` and ``raycast``
methods hold billboards exactly.  Run-length and BSP occlusion cannot (a quad's
alpha-tested outline is no polygon edge list, and it crosses other objects'
polygons freely), so for those methods billboards take the same z-buffered pass
over the method's own depth buffer, and the stats say so
(``stats["billboards"]["drawn_with"]``).

Light per texel uses the object's material, the texel's colour and the normal of
the face shot into the texel, with the same Phong / Blinn model per zone as meshes
(:func:`service.light._light_rgb`).  **What a billboard loses** (``docs/simplify.md``):

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
from service.light import MODELS, LightSettings, _light_rgb, pack_lights
from service.occlusion import Visibility
from service.scene import Light, Material, Transform, quaternion_matrix
from service.simplify.billboard import BillboardCloud

ALPHA_OPAQUE = 128
"""Texels with alpha at or above this are drawn (alpha test)."""
#: Occlusion method -> how billboards are drawn with it.
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
    """Every billboard of a scene in world coordinates, packed for the kernel."""

    origin: np.ndarray   # (Q, 3)
    u: np.ndarray        # (Q, 3) full edge along texture rows
    v: np.ndarray        # (Q, 3) full edge down the rows
    normal: np.ndarray   # (Q, 3) unit plane normal
    rot: np.ndarray      # (Q, 3, 3) object rotation, for texel normals
    material: np.ndarray  # (Q, 7)
    tex: np.ndarray      # (Q, 3) int64: texel offset, rows, cols
    rgba: np.ndarray     # (N, 4) uint8
    tnormal: np.ndarray  # (N, 3) int8


def pack_quads(objects: list[BillboardObject]) -> _Quads:
    """World-space quads of every billboard object (see :class:`_Quads`)."""
    parts: dict[str, list] = {k: [] for k in _Quads.__dataclass_fields__}
    base = 0
    for obj in objects:
        c, t = obj.cloud, obj.transform
        rot = quaternion_matrix(t.orientation)
        w = c.corners.reshape(-1, 3) @ (rot * t.scale).T + t.position
        w = w.reshape(-1, 4, 3)
        n = c.planes[:, :3] @ rot.T
        m = obj.material
        q = c.n_billboards
        parts["origin"].append(w[:, 0])
        parts["u"].append(w[:, 1] - w[:, 0])
        parts["v"].append(w[:, 3] - w[:, 0])
        parts["normal"].append(n / np.linalg.norm(n, axis=1, keepdims=True))
        parts["rot"].append(np.broadcast_to(rot, (q, 3, 3)))
        row = [*m.colour, m.ambient, m.diffuse, m.specular, m.shininess]
        parts["material"].append(np.tile(np.array(row, np.float64), (q, 1)))
        parts["tex"].append(np.stack([c.tex_offset[:-1] + base, c.tex_shape[:, 0],
                                      c.tex_shape[:, 1]], axis=1))
        parts["rgba"].append(c.rgba)
        parts["tnormal"].append(c.normal)
        base += int(c.tex_offset[-1])
    shapes = {"origin": (0, 3), "u": (0, 3), "v": (0, 3), "normal": (0, 3), "rot": (0, 3, 3),
              "material": (0, 7), "tex": (0, 3), "rgba": (0, 4), "tnormal": (0, 3)}
    out = {}
    for k, items in parts.items():
        ref = items[0] if items else np.zeros(shapes[k])
        out[k] = np.ascontiguousarray(np.concatenate(items) if items else ref,
                                      dtype=ref.dtype if items else np.float64)
    out["tex"] = out["tex"].astype(np.int64)
    out["rgba"] = out["rgba"].astype(np.uint8)
    out["tnormal"] = out["tnormal"].astype(np.int8)
    return _Quads(**out)


@nb.njit(cache=True, nogil=True)
def _texel(q: int, a: float, b: float, tex: np.ndarray, layer: int) -> int:
    """Flat index of the texel at quad coordinates (a, b) in [0, 1)^2 of quad ``q``."""
    rows, cols = tex[q, 1], tex[q, 2]
    i = min(int(b * rows), rows - 1)
    j = min(int(a * cols), cols - 1)
    return tex[q, 0] + layer * rows * cols + i * cols + j


@nb.njit(cache=True, nogil=True)
def _screen_box(o: np.ndarray, u: np.ndarray, v: np.ndarray, sh: float, s: float,
                hw: float, hh: float, cols: int, rows: int) -> tuple[int, int, int, int]:
    """Pixel rows and columns [r0, r1) x [c0, c1) the quad's projection can touch."""
    x0, x1, y0, y1 = np.inf, -np.inf, np.inf, -np.inf
    for ca in range(2):
        for cb in range(2):
            px = o[0] + ca * u[0] + cb * v[0]
            py = o[1] + ca * u[1] + cb * v[1]
            pz = o[2] + ca * u[2] + cb * v[2]
            sx = (px - pz * sh + hw) / s
            sy = (hh - py) / s
            x0, x1, y0, y1 = min(x0, sx), max(x1, sx), min(y0, sy), max(y1, sy)
    return (max(int(np.floor(y0)), 0), min(int(np.ceil(y1)) + 1, rows),
            max(int(np.floor(x0)), 0), min(int(np.ceil(x1)) + 1, cols))


@nb.njit(cache=True, nogil=True)
def _span(a0: float, da: float, b0: float, db: float, s: float, hw: float, c0: int,
          c1: int) -> tuple[int, int]:
    """Columns [j0, j1) of a row where ``0 <= a0 + da x < 1`` and ``0 <= b0 + db x < 1``.

    ``x = (j + 0.5) s - hw``; one column of slack each side (the caller re-tests).
    """
    lo, hi = -np.inf, np.inf
    for c0_, d_ in ((a0, da), (b0, db)):
        if d_ == 0.0:
            if c0_ < 0.0 or c0_ >= 1.0:
                return 0, 0
            continue
        e0, e1 = -c0_ / d_, (1.0 - c0_) / d_
        lo = max(lo, min(e0, e1))
        hi = min(hi, max(e0, e1))
    if hi < lo:
        return 0, 0
    j0 = max(int(np.floor((lo + hw) / s - 0.5)), c0)
    j1 = min(int(np.ceil((hi + hw) / s - 0.5)) + 1, c1)
    return j0, max(j1, j0)


@nb.njit(cache=True, nogil=True)
def draw_quads_kernel(origin: np.ndarray, u: np.ndarray, v: np.ndarray, normal: np.ndarray,
                      rot: np.ndarray, material: np.ndarray, tex: np.ndarray,
                      rgba: np.ndarray, tnormal: np.ndarray, shears: np.ndarray, s: float,
                      hw: float, hh: float, views: np.ndarray, lights: tuple,
                      ambient: float, code: int, cull_back: bool, depth: np.ndarray,
                      tri: np.ndarray, colour: np.ndarray, quad: np.ndarray) -> int:
    """Draw every quad into every zone (z-test against ``depth``, alpha test); see module.

    ``depth`` (Z, R, C) float32 and ``tri`` (Z, R, C) int32 are updated where a quad
    wins (``tri`` set to -1: no mesh triangle); ``colour`` (Z, R, C, 3) uint8 receives
    the billboard's lit colour and ``quad`` (Z, R, C) int32 the quad's index + 1 (0
    where no quad won).  Returns the number of pixel writes.
    """
    zones, rows, cols = depth.shape
    writes = 0
    mat = np.empty(7)
    for k in range(zones):
        sh = shears[k]
        for q in range(origin.shape[0]):
            n = normal[q]
            den = n[0] * sh + n[2]
            if abs(den) < 1e-9:
                continue  # seen edge-on in this zone
            o, uq, vq = origin[q], u[q], v[q]
            uu = uq[0] * uq[0] + uq[1] * uq[1] + uq[2] * uq[2]
            vv = vq[0] * vq[0] + vq[1] * vq[1] + vq[2] * vq[2]
            rho = n[0] * o[0] + n[1] * o[1] + n[2] * o[2]
            near = 0 if _facing(q, rot, normal, views[k]) else 1
            r0, r1, c0, c1 = _screen_box(o, uq, vq, sh, s, hw, hh, cols, rows)
            dzx = -n[0] / den  # z, and so a and b, are linear in x along a row
            da = ((1.0 + dzx * sh) * uq[0] + dzx * uq[2]) / uu
            db = ((1.0 + dzx * sh) * vq[0] + dzx * vq[2]) / vv
            for i in range(r0, r1):
                y = hh - (i + 0.5) * s
                z0 = (rho - n[1] * y) / den  # at x = 0
                ex, ey, ez = z0 * sh - o[0], y - o[1], z0 - o[2]
                a0 = (ex * uq[0] + ey * uq[1] + ez * uq[2]) / uu
                b0 = (ex * vq[0] + ey * vq[1] + ez * vq[2]) / vv
                j0, j1 = _span(a0, da, b0, db, s, hw, c0, c1)
                for j in range(j0, j1):
                    x0 = (j + 0.5) * s - hw
                    z = z0 + dzx * x0
                    if -z >= depth[k, i, j]:
                        continue
                    a = a0 + da * x0
                    b = b0 + db * x0
                    if a < 0.0 or a >= 1.0 or b < 0.0 or b >= 1.0:
                        continue
                    # the texel choice stays written out here: as a helper function
                    # (even inline="always") the kernel measured 1.4-1.5x slower
                    t = -1
                    for layer in (near, 1 - near):  # the layer facing the viewer first
                        c = _texel(q, a, b, tex, layer)
                        if rgba[c, 3] >= ALPHA_OPAQUE and not (
                                cull_back and _back(q, c, rot, tnormal, views[k])):
                            t = c
                            break
                    if t < 0:
                        continue
                    depth[k, i, j] = -z
                    tri[k, i, j] = -1
                    quad[k, i, j] = q + 1
                    writes += 1
                    _shade_texel(q, t, x0 + z * sh, y, z, rot, material, rgba, tnormal,
                                 views[k], lights, ambient, code, mat, colour[k, i, j])
    return writes


@nb.njit(cache=True, nogil=True)
def _facing(q: int, rot: np.ndarray, normal: np.ndarray, view: np.ndarray) -> bool:
    """Whether the zone's viewer is on the side quad ``q``'s layer 0 faces.

    Layer 0 holds faces whose normal points to the cloud's plane normal side; that
    normal in the world is the object's rotation of it, which ``normal`` holds.
    """
    return normal[q, 0] * view[0] + normal[q, 1] * view[1] + normal[q, 2] * view[2] >= 0.0


@nb.njit(cache=True, nogil=True)
def _back(q: int, t: int, rot: np.ndarray, tnormal: np.ndarray, view: np.ndarray) -> bool:
    """Whether texel ``t``'s face looks away from the zone's viewer (a back face)."""
    d = 0.0
    for r in range(3):
        w = 0.0
        for c in range(3):
            w += rot[q, r, c] * tnormal[t, c]
        d += w * view[r]
    return d < 0.0


@nb.njit(cache=True, nogil=True)
def _shade_texel(q: int, t: int, px: float, py: float, pz: float, rot: np.ndarray,
                 material: np.ndarray, rgba: np.ndarray, tnormal: np.ndarray,
                 view: np.ndarray, lights: tuple, ambient: float, code: int,
                 mat: np.ndarray, out: np.ndarray) -> None:
    """Light one texel seen at world point p into ``out`` (3,) uint8."""
    for c in range(7):
        mat[c] = material[q, c]
    for c in range(3):
        mat[c] *= rgba[t, c] / 255.0
    nx = rot[q, 0, 0] * tnormal[t, 0] + rot[q, 0, 1] * tnormal[t, 1] + rot[q, 0, 2] * tnormal[t, 2]
    ny = rot[q, 1, 0] * tnormal[t, 0] + rot[q, 1, 1] * tnormal[t, 1] + rot[q, 1, 2] * tnormal[t, 2]
    nz = rot[q, 2, 0] * tnormal[t, 0] + rot[q, 2, 1] * tnormal[t, 1] + rot[q, 2, 2] * tnormal[t, 2]
    if nx * view[0] + ny * view[1] + nz * view[2] < 0.0:
        nx, ny, nz = -nx, -ny, -nz
    rgb = _light_rgb(px, py, pz, nx, ny, nz, mat, view, lights, ambient, code)
    for c in range(3):
        out[c] = np.uint8(np.float64(np.float32(rgb[c])) * 255.0 + 0.5)


@dataclass
class BillboardPass:
    """What :func:`draw_billboards` drew: paint it over the shaded frame."""

    colour: np.ndarray  # (Z, R, C, 3) uint8
    quad: np.ndarray    # (Z, R, C) int32: index + 1 of the quad seen, 0 for none
    stats: dict

    @property
    def mask(self) -> np.ndarray:
        """Where a billboard won, (Z, R, C) bool."""
        return self.quad > 0

    def paint(self, frame_colour: np.ndarray) -> None:
        """Write the billboards' colour into ``frame_colour`` (Z, R, C, 3) where they won."""
        mask = self.mask
        frame_colour[mask] = self.colour[mask]


def draw_billboards(objects: list[BillboardObject], display: DisplaySettings,
                    vis: Visibility, method: str, lights: list[Light], ambient: float,
                    light: LightSettings, cull_back: bool = True) -> BillboardPass:
    """Draw billboard objects into ``vis`` (depth and triangle, in place) for every zone.

    Returns
    -------
    BillboardPass
        Their lit colour and where they won; ``stats``: ``objects``, ``quads``,
        ``pixels`` (writes), ``covered_pixels`` (pixels they show) and ``drawn_with``.
    """
    quads = pack_quads(objects)
    zrc = vis.depth.shape
    colour = np.zeros((*zrc, 3), np.uint8)
    quad = np.zeros(zrc, np.int32)
    writes = draw_quads_kernel(
        quads.origin, quads.u, quads.v, quads.normal, quads.rot, quads.material, quads.tex,
        quads.rgba, quads.tnormal, display.shears(), display.pixel_size, display.width / 2,
        display.height / 2, display.view_vectors(), pack_lights(lights), float(ambient),
        MODELS[light.model], cull_back, vis.depth, vis.triangle, colour, quad)
    stats = {"objects": len(objects), "quads": int(quads.origin.shape[0]), "pixels": int(writes),
             "covered_pixels": int((quad > 0).sum()),
             "drawn_with": DRAWN_WITH.get(method, "zbuffer")}
    if DRAWN_WITH.get(method, "zbuffer") != method:
        stats["note"] = f"{method} cannot hold alpha-tested quads: billboards z-buffered"
    return BillboardPass(colour, quad, stats)
