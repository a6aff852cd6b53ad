"""Stage 5: light for every view zone (ambient + diffuse + specular, thesis chapter 4).

Light model
-----------
For a surface point ``p`` with unit normal ``N``, material ``(r, g, b, k_a, k_d, k_s,
n)`` (see :class:`service.render.scene.Material`) and the view vector ``V`` of zone ``k``
(:meth:`service.display.DisplaySettings.view_vectors`; the projection is parallel, so
``V`` is the same for every point of a zone), each colour channel ``c`` is

    I_c = rgb_c * k_a * A
        + sum_j  E_j,c * ( rgb_c * k_d * max(0, N.L_j)  +  k_s * S_j )

clamped to [0, 1], where ``A`` is the scene's ambient level, ``E_j = colour_j *
intensity_j`` is light ``j``'s colour, ``L_j`` the unit vector from ``p`` toward the
light (a ``directional`` light's ``vector``, or ``normalise(position - p)`` for a
``point`` light; no distance attenuation: the thesis sets ``I_i k_s / (r + k)`` to 1)
and the specular term ``S_j`` is taken only where ``N.L_j > 0``.  The highlight has
the light's colour, not the material's (thesis 4.2.1).  Models (:data:`MODELS`):

``ambient``
    ``I_c = rgb_c * k_a * A`` only: no diffuse, no specular, lights ignored (the dodge
    game's fast mode, thesis 5.1.1; give game objects ``k_a`` near 1 and ``A = 1``
    to keep them bright).
``phong``
    ``S = max(0, R.V)^n`` with ``R = 2 (N.L) N - L`` (thesis eq. 4.1).
``blinn``
    ``S = max(0, N.H)^n`` with ``H = normalise(L + V)`` (thesis eq. 4.2; the thesis
    writes ``(L + V) / 2`` and calls it a unit vector, so we normalise).

Evaluation (:data:`EVALUATIONS`)
--------------------------------
``polygon``
    Flat: once per polygon per zone, at the polygon's centroid with its face normal,
    as the thesis does (4.4).  A (Z, P, 3) colour table is gathered through
    ``triangle_polygon[vis.triangle]``; the fast path.
``vertex``
    Gouraud: at every triangle corner (corner position, ``corner_normals``) per zone;
    colours are interpolated across each pixel with barycentric coordinates of the
    pixel centre ``(c + 0.5, r + 0.5)`` in the zone's 2-D projected triangle.  With a
    parallel projection screen-space barycentrics equal the world-space ones, so no
    perspective correction is needed.
``point``
    Per pixel: the corner normals interpolated by the same barycentrics (and
    renormalised), at the pixel's world position from
    :func:`service.render.projection.unproject` at its visible depth.  The accuracy
    reference.

Back-facing pixels
------------------
Normals face outward and back faces are culled earlier, but the multi-view cull
keeps a polygon that faces *any* zone, so a zone may see a polygon whose face normal
points away from it.  Such a pixel is lit as the side the viewer sees: all normals of
that triangle (face and corner normals) are flipped, ``N -> -N``, whenever the face
normal satisfies ``N_face . V < 0`` in that zone.  The decision is per triangle and
zone, from the face normal, in every evaluation mode, so smooth normals near a
silhouette are never flipped piecemeal.

Cost
----
One pass marks which polygons (``polygon``) or triangles (``vertex``) each zone
actually shows (``polygon`` reuses ``Visibility.shown`` when the pipeline has it),
light is evaluated only for those, and one pass writes the pixels (straight to
uint8 for :func:`shade`, to float32 for :func:`shade_linear`; for ``polygon`` the
table is quantised first, so that pass only copies); every pass is a numba kernel,
parallel over zones x rows (the flat table over polygons, each polygon's centroid
found once for all zones).  ``point`` evaluates light once per covered pixel.
Whole shininess exponents use integer powering.  Numbers: ``holo-bench light``
(:mod:`service.bench.light_bench`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from service.base.errors import RenderError, SettingsError
from service.display import DisplaySettings
from service.numba_subroutine import subroutine
from service.render.occlusion import Visibility
from service.render.projection import unproject
from service.render.scene import Light, SceneArrays

#: Light model name -> kernel code (index into the specular-base tuple in the kernel).
MODELS: dict[str, int] = {"ambient": 0, "phong": 1, "blinn": 2}

#: Light vector kind -> 1 for a point light (vector is a position), 0 for a direction.
_LIGHT_KINDS: dict[str, int] = {"directional": 0, "point": 1}


@dataclass(frozen=True)
class LightSettings:
    """Settings of the light stage.

    Attributes
    ----------
    model : {"ambient", "phong", "blinn"}
        Light model (see the module notes).
    evaluation : {"polygon", "vertex", "point"}
        Where light is evaluated: per polygon (flat), per vertex (Gouraud) or per
        pixel (the reference).
    background : tuple of 3 ints in 0..255
        Colour of pixels where nothing is visible.
    """

    model: str = "blinn"
    evaluation: str = "polygon"
    background: tuple[int, int, int] = (0, 0, 0)

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise SettingsError(f"light model must be one of {sorted(MODELS)}, got {self.model!r}")
        if self.evaluation not in EVALUATIONS:
            raise SettingsError(
                f"light evaluation must be one of {sorted(EVALUATIONS)}, got {self.evaluation!r}"
            )
        bg = tuple(int(v) for v in self.background)
        if len(bg) != 3 or not all(0 <= v <= 255 for v in bg):
            raise SettingsError(f"background must be 3 integers 0..255, got {self.background}")
        object.__setattr__(self, "background", bg)


@dataclass(frozen=True)
class _Packed:
    """Per-call inputs packed as arrays for the kernels.

    Attributes
    ----------
    views : ndarray, shape (Z, 3)
    lights : tuple
        ``(lvec, lpoint, lrgb)`` from :func:`pack_lights`.
    ambient : float
    code : int
        Model code from :data:`MODELS`.
    background : ndarray, shape (3,), float64
        Background colour in [0, 1].
    affine : ndarray, shape (Z, 4, 3), or None
        :func:`_unproject_affine` of the display (only the ``point`` evaluation
        uses it; None otherwise).
    scale, offset : float
        Output value = float32(colour) * scale + offset: (255, 0.5) into uint8
        (the store truncates, so this rounds), (1, 0) into float32.
    """

    views: np.ndarray
    lights: tuple
    ambient: float
    code: int
    background: np.ndarray
    affine: np.ndarray | None
    scale: float
    offset: float


def pack_lights(lights: list[Light]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lights as arrays.

    Parameters
    ----------
    lights : list of Light

    Returns
    -------
    lvec : ndarray, shape (J, 3), float64
        Unit direction toward each directional light, or each point light's position.
    lpoint : ndarray, shape (J,), int64
        1 where the light is a point light.
    lrgb : ndarray, shape (J, 3), float64
        Colour times intensity.
    """
    lvec = np.zeros((len(lights), 3))
    lpoint = np.zeros(len(lights), np.int64)
    lrgb = np.zeros((len(lights), 3))
    for j, lt in enumerate(lights):
        lpoint[j] = _LIGHT_KINDS[lt.kind]
        v = np.asarray(lt.vector, np.float64)
        lvec[j] = v if lpoint[j] else v / np.linalg.norm(v)
        lrgb[j] = np.asarray(lt.colour, np.float64) * float(lt.intensity)
    return lvec, lpoint, lrgb


@nb.njit(cache=True, nogil=True, inline="always")
def _power(base: float, n: float) -> float:
    """``base ** n``; whole exponents up to 4096 use integer powering (10x faster)."""
    if n <= 4096.0 and n == np.floor(n):
        return base ** np.int64(n)
    return base**n


@nb.njit(cache=True, nogil=True, inline="always")
def _light_rgb(
    px: float,
    py: float,
    pz: float,
    nx: float,
    ny: float,
    nz: float,
    mat: np.ndarray,
    v: np.ndarray,
    lights: tuple,
    ambient: float,
    code: int,
) -> tuple:
    """Colour (r, g, b) in [0, 1] at point (px, py, pz) with normal (nx, ny, nz).

    ``mat`` (7,) is one material row, ``v`` (3,) the unit view vector, ``lights``
    the tuple from :func:`pack_lights`; the normal is renormalised here (and must
    already be flipped toward the viewer).
    """
    lvec, lpoint, lrgb = lights
    ka = mat[3] * ambient
    cr = mat[0] * ka
    cg = mat[1] * ka
    cb = mat[2] * ka
    nn = np.sqrt(nx * nx + ny * ny + nz * nz)
    if code != 0 and nn > 0.0:
        nx /= nn
        ny /= nn
        nz /= nn
        for j in range(lvec.shape[0]):
            lx, ly, lz = lvec[j, 0], lvec[j, 1], lvec[j, 2]
            if lpoint[j] == 1:
                lx, ly, lz = lx - px, ly - py, lz - pz
                d = np.sqrt(lx * lx + ly * ly + lz * lz)
                if d <= 1e-12:
                    continue
                lx, ly, lz = lx / d, ly / d, lz / d
            ndl = nx * lx + ny * ly + nz * lz
            if ndl <= 0.0:
                continue
            # phong: R.V with R = 2 (N.L) N - L
            rdv = (2.0 * ndl * nx - lx) * v[0] + (2.0 * ndl * ny - ly) * v[1]
            rdv += (2.0 * ndl * nz - lz) * v[2]
            # blinn: N.H with H = normalise(L + V)
            hx, hy, hz = lx + v[0], ly + v[1], lz + v[2]
            hn = np.sqrt(hx * hx + hy * hy + hz * hz)
            ndh = (nx * hx + ny * hy + nz * hz) / hn if hn > 0.0 else 0.0
            base = (0.0, rdv, ndh)[code]
            spec = mat[5] * _power(base, mat[6]) if base > 0.0 else 0.0
            dif = mat[4] * ndl
            cr += lrgb[j, 0] * (mat[0] * dif + spec)
            cg += lrgb[j, 1] * (mat[1] * dif + spec)
            cb += lrgb[j, 2] * (mat[2] * dif + spec)
    return min(max(cr, 0.0), 1.0), min(max(cg, 0.0), 1.0), min(max(cb, 0.0), 1.0)


@nb.njit(cache=True, nogil=True, inline="always")
def _facing(normals: np.ndarray, p: int, v: np.ndarray) -> float:
    """+1 if face normal ``normals[p]`` faces the view vector ``v`` (3,), else -1."""
    d = normals[p, 0] * v[0] + normals[p, 1] * v[1] + normals[p, 2] * v[2]
    return 1.0 if d >= 0.0 else -1.0


@nb.njit(cache=True, nogil=True, inline="always")
def _store(
    out: np.ndarray, z: int, r: int, c: int, rgb: tuple, scale: float, offset: float
) -> None:
    """``out[z, r, c] = float32(rgb) * scale + offset`` (the cast truncates for uint8)."""
    for ch in range(3):
        out[z, r, c, ch] = np.float64(np.float32(rgb[ch])) * scale + offset


@nb.njit(cache=True, nogil=True, inline="always")
def _store_either(
    out8: np.ndarray, out32: np.ndarray, z: int, r: int, c: int, rgb: tuple, scale: float,
    offset: float,
) -> None:
    """:func:`_store` into ``out8`` (uint8) when it has zones, else into ``out32`` (float32).

    One kernel signature for both outputs of :func:`shade` and :func:`shade_linear`
    (the other array is empty, (0, 1, 1, 3)): a second signature was a whole
    compile of a parallel kernel, 3.4-4.5 s of CPU (docs/compile-time.md, render6).
    """
    if out8.shape[0] > 0:
        _store(out8, z, r, c, rgb, scale, offset)
    else:
        _store(out32, z, r, c, rgb, scale, offset)


def _outputs(out: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(out8, out32)`` for :func:`_store_either`: ``out`` and an empty one of the other dtype."""
    if out.dtype == np.uint8:
        return out, np.empty((0, 1, 1, 3), np.float32)
    return np.empty((0, 1, 1, 3), np.uint8), out


@nb.njit(cache=True, nogil=True, parallel=True)
def mark_shown(tri_map: np.ndarray, item: np.ndarray, n_items: int) -> np.ndarray:
    """Which items each zone shows.

    Parameters
    ----------
    tri_map : ndarray, shape (Z, R, C), int32
        Triangle seen at each pixel (-1 where empty), as ``Visibility.triangle``.
    item : ndarray, shape (T,)
        Item of each triangle (e.g. ``SceneArrays.triangle_polygon``), < ``n_items``.
    n_items : int

    Returns
    -------
    ndarray, shape (Z, n_items), bool
    """
    zones, rows, cols = tri_map.shape
    needed = np.zeros((zones, n_items), np.bool_)
    for i in nb.prange(zones * rows):
        z, r = i // rows, i % rows
        for c in range(cols):
            t = tri_map[z, r, c]
            if t >= 0:
                needed[z, item[t]] = True
    return needed


@nb.njit(cache=True, nogil=True, parallel=True)
def _polygon_table(
    vertices: np.ndarray,
    polygons: np.ndarray,
    counts: np.ndarray,
    normals: np.ndarray,
    shading: np.ndarray,
    materials: np.ndarray,
    views: np.ndarray,
    needed: np.ndarray,
    lights: tuple,
    ambient: float,
    code: int,
    quant: tuple,
    out: np.ndarray,
) -> None:
    """Flat colour of every needed polygon in every zone into ``out`` (Z, P, 3).

    Light is evaluated at the polygon's centroid (mean of its vertices, found once
    for all zones) with its ``shading`` normal (P, 3), flipped where the face normal
    ``normals`` (P, 3) looks away from the zone.  ``polygons`` (P, K) padded, ``counts``
    (P,), ``materials`` (P, 7), ``views`` (Z, 3), ``needed`` (Z, P) bool.  ``out``
    holds the output values (uint8 or float32), already through :func:`_store` with
    ``quant = (scale, offset)``.
    """
    n = normals.shape[0]
    zones = views.shape[0]
    for p in nb.prange(n):
        shown = False
        for z in range(zones):
            shown |= needed[z, p]
        if not shown:
            continue
        mat = materials[p]
        cx = cy = cz = 0.0
        for k in range(counts[p]):
            cx += vertices[polygons[p, k], 0]
            cy += vertices[polygons[p, k], 1]
            cz += vertices[polygons[p, k], 2]
        for z in range(zones):
            if not needed[z, p]:
                continue
            s = _facing(normals, p, views[z])
            rgb = _light_rgb(
                cx / counts[p], cy / counts[p], cz / counts[p],
                s * shading[p, 0], s * shading[p, 1], s * shading[p, 2],
                mat, views[z], lights, ambient, code,
            )
            _store(out, 0, z, p, rgb, quant[0], quant[1])


@nb.njit(cache=True, nogil=True, parallel=True)
def _corner_table(
    vertices: np.ndarray,
    triangles: np.ndarray,
    tri_poly: np.ndarray,
    normals: np.ndarray,
    corner_normals: np.ndarray,
    materials: np.ndarray,
    views: np.ndarray,
    needed: np.ndarray,
    lights: tuple,
    ambient: float,
    code: int,
    out: np.ndarray,
) -> None:
    """Colour at the corners of every needed triangle per zone into ``out`` (Z, T, 3, 3).

    ``triangles`` (T, 3), ``tri_poly`` (T,), ``normals`` (P, 3), ``corner_normals``
    (T, 3, 3), ``materials`` (P, 7), ``views`` (Z, 3), ``needed`` (Z, T) bool.
    """
    n = triangles.shape[0]
    for i in nb.prange(views.shape[0] * n):
        z, t = i // n, i % n
        if not needed[z, t]:
            continue
        p = tri_poly[t]
        s = _facing(normals, p, views[z])
        for k in range(3):
            q = triangles[t, k]
            rgb = _light_rgb(
                vertices[q, 0], vertices[q, 1], vertices[q, 2],
                s * corner_normals[t, k, 0], s * corner_normals[t, k, 1],
                s * corner_normals[t, k, 2],
                materials[p], views[z], lights, ambient, code,
            )
            for ch in range(3):
                out[z, t, k, ch] = rgb[ch]


@nb.njit(cache=True, nogil=True, inline="always")
def _barycentric(pz: np.ndarray, a: int, b: int, c: int, x: float, y: float) -> tuple:
    """Barycentric weights of (x, y) in the projected triangle of vertices a, b, c.

    ``pz`` is one zone's projection (V, 3).  Weights are clamped to >= 0 and
    renormalised (a pixel centre on an edge may fall a hair outside); a triangle
    with no area on screen gets (1/3, 1/3, 1/3).
    """
    ax, ay = pz[a, 0], pz[a, 1]
    bx, by = pz[b, 0], pz[b, 1]
    cx, cy = pz[c, 0], pz[c, 1]
    det = (bx - ax) * (cy - ay) - (cx - ax) * (by - ay)
    if det == 0.0:
        return 1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0
    w1 = max(((x - ax) * (cy - ay) - (cx - ax) * (y - ay)) / det, 0.0)
    w2 = max(((bx - ax) * (y - ay) - (x - ax) * (by - ay)) / det, 0.0)
    w0 = max(1.0 - w1 - w2, 0.0)
    tot = w0 + w1 + w2
    return w0 / tot, w1 / tot, w2 / tot


@nb.njit(cache=True, nogil=True, parallel=True)
def _gather(
    tri_map: np.ndarray, tri_poly: np.ndarray, table: np.ndarray, bg: np.ndarray, out: np.ndarray
) -> None:
    """``out[z, r, c] = table[z, tri_poly[tri_map[z, r, c]]]`` (``bg`` where empty).

    ``tri_map`` (Z, R, C) int32, ``table`` (Z, P, 3) and ``bg`` (3,) hold output
    values (same dtype as ``out`` (Z, R, C, 3)): this is a copy.
    """
    zones, rows, cols = tri_map.shape
    for i in nb.prange(zones * rows):
        z, r = i // rows, i % rows
        for c in range(cols):
            t = tri_map[z, r, c]
            if t < 0:  # scalar indexing: a view per pixel would cost a refcount each
                out[z, r, c, 0] = bg[0]
                out[z, r, c, 1] = bg[1]
                out[z, r, c, 2] = bg[2]
            else:
                p = tri_poly[t]
                out[z, r, c, 0] = table[z, p, 0]
                out[z, r, c, 1] = table[z, p, 1]
                out[z, r, c, 2] = table[z, p, 2]


@nb.njit(cache=True, nogil=True)
def _store_background(bg: np.ndarray, scale: float, offset: float, out: np.ndarray) -> None:
    """``out`` (1, 1, 1, 3) = ``bg`` (3,) in [0, 1] through :func:`_store`."""
    _store(out, 0, 0, 0, (bg[0], bg[1], bg[2]), scale, offset)


@nb.njit(cache=True, nogil=True, parallel=True)
def _gouraud_pixels(
    tri_map: np.ndarray,
    proj: np.ndarray,
    triangles: np.ndarray,
    corner: np.ndarray,
    bg: np.ndarray,
    scale: float,
    offset: float,
    out: np.ndarray,
) -> None:
    """Interpolate corner colours (Z, T, 3, 3) across pixels into ``out`` (Z, R, C, 3)."""
    zones, rows, cols = tri_map.shape
    for i in nb.prange(zones * rows):
        z, r = i // rows, i % rows
        for c in range(cols):
            t = tri_map[z, r, c]
            if t < 0:
                _store(out, z, r, c, (bg[0], bg[1], bg[2]), scale, offset)
                continue
            w0, w1, w2 = _barycentric(
                proj[z], triangles[t, 0], triangles[t, 1], triangles[t, 2], c + 0.5, r + 0.5
            )
            rgb = (
                w0 * corner[z, t, 0, 0] + w1 * corner[z, t, 1, 0] + w2 * corner[z, t, 2, 0],
                w0 * corner[z, t, 0, 1] + w1 * corner[z, t, 1, 1] + w2 * corner[z, t, 2, 1],
                w0 * corner[z, t, 0, 2] + w1 * corner[z, t, 1, 2] + w2 * corner[z, t, 2, 2],
            )
            _store(out, z, r, c, rgb, scale, offset)


@nb.njit(cache=True, nogil=True, parallel=True)
def _point_pixels(
    tri_map: np.ndarray,
    depth: np.ndarray,
    proj: np.ndarray,
    affine: np.ndarray,
    geometry: tuple,
    materials: np.ndarray,
    views: np.ndarray,
    lights: tuple,
    ambient: float,
    code: int,
    bg: np.ndarray,
    scale: float,
    offset: float,
    out8: np.ndarray,
    out32: np.ndarray,
) -> None:
    """Light every covered pixel at its own world point and interpolated normal.

    The output (Z, R, C, 3) is ``out8`` (uint8) when it has zones, else ``out32``
    (float32) (:func:`_store_either`).

    ``affine`` (Z, 4, 3) gives the world point at pixel (c, r) and depth d as
    ``affine[z, 0] + c * affine[z, 1] + r * affine[z, 2] + d * affine[z, 3]`` (see
    :func:`_unproject_affine`); ``geometry`` is ``(triangles (T, 3), tri_poly (T,),
    normals (P, 3), corner_normals (T, 3, 3))``.
    """
    triangles, tri_poly, normals, cn = geometry
    zones, rows, cols = tri_map.shape
    for i in nb.prange(zones * rows):
        z, r = i // rows, i % rows
        a = affine[z]
        for c in range(cols):
            t = tri_map[z, r, c]
            if t < 0:
                _store_either(out8, out32, z, r, c, (bg[0], bg[1], bg[2]), scale, offset)
                continue
            d = np.float64(depth[z, r, c])
            px = a[0, 0] + c * a[1, 0] + r * a[2, 0] + d * a[3, 0]
            py = a[0, 1] + c * a[1, 1] + r * a[2, 1] + d * a[3, 1]
            pz = a[0, 2] + c * a[1, 2] + r * a[2, 2] + d * a[3, 2]
            w0, w1, w2 = _barycentric(
                proj[z], triangles[t, 0], triangles[t, 1], triangles[t, 2], c + 0.5, r + 0.5
            )
            p = tri_poly[t]
            s = _facing(normals, p, views[z])
            nx = s * (w0 * cn[t, 0, 0] + w1 * cn[t, 1, 0] + w2 * cn[t, 2, 0])
            ny = s * (w0 * cn[t, 0, 1] + w1 * cn[t, 1, 1] + w2 * cn[t, 2, 1])
            nz = s * (w0 * cn[t, 0, 2] + w1 * cn[t, 1, 2] + w2 * cn[t, 2, 2])
            rgb = _light_rgb(px, py, pz, nx, ny, nz, materials[p], views[z], lights, ambient, code)
            _store_either(out8, out32, z, r, c, rgb, scale, offset)


@nb.njit(cache=True, nogil=True, inline="always")
def _centroid(i: int, p: int, vertices: np.ndarray, polygons: np.ndarray,
              counts: np.ndarray) -> tuple:
    """Mean of polygon ``p``'s vertices at time ``i``, summed in :func:`_polygon_table`'s order.

    ``vertices`` (K, V, 3) holds the K times; returns ``(x, y, z)``.
    """
    cx = cy = cz = 0.0
    for k in range(counts[p]):
        q = polygons[p, k]
        cx += vertices[i, q, 0]
        cy += vertices[i, q, 1]
        cz += vertices[i, q, 2]
    return cx / counts[p], cy / counts[p], cz / counts[p]


@nb.njit(cache=True, nogil=True, inline="always")
def _lit_at(
    i: int, p: int, z: int, centre: tuple, normals: tuple, materials: np.ndarray,
    views: np.ndarray, lights: tuple, ambient: float, code: int,
) -> tuple:
    """:func:`_polygon_table`'s colour of polygon ``p`` in zone ``z`` at time ``i``.

    ``centre`` is the polygon's :func:`_centroid` at time ``i`` (zones share it);
    ``normals`` is ``(face (K, P, 3), shading (K, P, 3))``: which side the zone sees,
    and the normal light uses; they and the light vectors ``lights[0]`` (K, J, 3)
    hold the K times; the arithmetic is :func:`_polygon_table`'s, in its order.
    """
    face, shading = normals
    s = _facing(face[i], p, views[z])
    return _light_rgb(
        centre[0], centre[1], centre[2],
        s * shading[i, p, 0], s * shading[i, p, 1], s * shading[i, p, 2],
        materials[p], views[z], (lights[0][i], lights[1], lights[2]), ambient, code,
    )


# Truncated Taylor arithmetic: a quantity and its first two time derivatives, (f, f', f'').
# Subroutines, not numba's inlining: :func:`_table_chunk` makes about a hundred such
# calls, and numba copied, renamed and typed each callee's IR at every one of them
# (its inlining pass alone took 0.95 s of the kernel's 3.7 s cold compile; 2.3 s now).
# Compiled once each, they are small enough that LLVM inlines every call.

@subroutine()
def _tmul(a: tuple, b: tuple) -> tuple:
    """Leibniz: ``(ab, a'b + ab', a''b + 2a'b' + ab'')``."""
    return a[0] * b[0], a[1] * b[0] + a[0] * b[1], a[2] * b[0] + 2.0 * a[1] * b[1] + a[0] * b[2]


@subroutine()
def _tdiv(a: tuple, b: tuple) -> tuple:
    """``a / b`` (``b[0]`` nonzero)."""
    q0 = a[0] / b[0]
    q1 = (a[1] - q0 * b[1]) / b[0]
    return q0, q1, (a[2] - 2.0 * q1 * b[1] - q0 * b[2]) / b[0]


@subroutine()
def _tsqrt(a: tuple) -> tuple:
    """``sqrt(a)`` (``a[0]`` > 0)."""
    s0 = np.sqrt(a[0])
    s1 = a[1] / (2.0 * s0)
    return s0, s1, (a[2] - 2.0 * s1 * s1) / (2.0 * s0)


@subroutine()
def _tadd(a: tuple, b: tuple, k: float) -> tuple:
    """``a + k b``."""
    return a[0] + k * b[0], a[1] + k * b[1], a[2] + k * b[2]


@subroutine()
def _tdot(a: tuple, b: tuple) -> tuple:
    """Dot product of two vectors of three Taylor scalars."""
    return _tadd(_tadd(_tmul(a[0], b[0]), _tmul(a[1], b[1]), 1.0), _tmul(a[2], b[2]), 1.0)


@nb.njit(cache=True, nogil=True, inline="always")
def _tunit(a: tuple) -> tuple:
    """``a / |a|`` for a vector of Taylor scalars, and ``|a|``'s value."""
    n = _tsqrt(_tdot(a, a))
    if n[0] <= 0.0:
        return a, n[0]
    return (_tdiv(a[0], n), _tdiv(a[1], n), _tdiv(a[2], n)), n[0]


@nb.njit(cache=True, nogil=True, inline="always")
def _light_paths(pos: tuple, nrm: tuple, lights: tuple, lrate: np.ndarray,
                 out: np.ndarray) -> float:
    """What :func:`_light_rates` needs of a polygon in every zone: its light vectors.

    ``pos`` and ``nrm`` (as the polygon faces, unflipped) are 3-tuples of Taylor
    scalars ``(f, f', f'')``; ``lrate`` (2, J, 3) holds the light vectors' first
    and second derivatives.  Writes ``out`` (J, 4, 3): the unit vector toward each
    light (rows 0-2, each a Taylor scalar) and ``N.L`` with the unit normal (row 3;
    ``out[j, 3, 0]`` is -1 for a point light at the point).  Returns ``|N|``.
    """
    lvec, lpoint, _ = lights
    unit, nn = _tunit(nrm)
    for j in range(lvec.shape[0]):
        lt = ((lvec[j, 0], lrate[0, j, 0], lrate[1, j, 0]),
              (lvec[j, 1], lrate[0, j, 1], lrate[1, j, 1]),
              (lvec[j, 2], lrate[0, j, 2], lrate[1, j, 2]))
        if lpoint[j] == 1:
            lt, d = _tunit((_tadd(lt[0], pos[0], -1.0), _tadd(lt[1], pos[1], -1.0),
                            _tadd(lt[2], pos[2], -1.0)))
            if d <= 1e-12:
                out[j, 3, 0] = -1.0
                continue
        ndl = _tdot(unit, lt)
        for d in range(3):
            for m in range(3):
                out[j, d, m] = lt[d][m]
            out[j, 3, d] = ndl[d]
    return nn


@nb.njit(cache=True, nogil=True, inline="always")
def _light_rates(
    sign: float, nrm: tuple, paths: np.ndarray, mat: np.ndarray, v: np.ndarray,
    lrgb: np.ndarray, ambient: float, code: int,
) -> tuple:
    """First and second time derivatives of :func:`_light_rgb`'s (r, g, b) in one zone.

    ``nrm`` is the polygon's unit normal (Taylor scalars, unflipped), ``sign`` its
    flip toward the zone's view vector ``v``; ``paths`` is :func:`_light_paths`'.
    The branches (light behind, no highlight, clamping) are taken as
    :func:`_light_rgb` takes them at the value; a clamped channel does not change.
    Returns ``((r', g', b'), (r'', g'', b''))``.
    """
    ka = mat[3] * ambient
    cr, cg, cb = (mat[0] * ka, 0.0, 0.0), (mat[1] * ka, 0.0, 0.0), (mat[2] * ka, 0.0, 0.0)
    for j in range(paths.shape[0] if code != 0 else 0):
        ndl = (sign * paths[j, 3, 0], sign * paths[j, 3, 1], sign * paths[j, 3, 2])
        if ndl[0] <= 0.0:  # behind, or a point light at the point (-1 either way)
            continue
        base = (0.0, 0.0, 0.0)
        if code == 1:  # R.V, R = 2 (N.L) N - L; V is still
            for d in range(3):
                nd = (sign * nrm[d][0], sign * nrm[d][1], sign * nrm[d][2])
                r = _tadd(_tmul(ndl, nd), (paths[j, d, 0], paths[j, d, 1], paths[j, d, 2]),
                          -0.5)
                base = _tadd(base, r, 2.0 * v[d])
        else:  # N.H, H = normalise(L + V)
            hv = ((paths[j, 0, 0] + v[0], paths[j, 0, 1], paths[j, 0, 2]),
                  (paths[j, 1, 0] + v[1], paths[j, 1, 1], paths[j, 1, 2]),
                  (paths[j, 2, 0] + v[2], paths[j, 2, 1], paths[j, 2, 2]))
            hn = _tsqrt(_tdot(hv, hv))
            if hn[0] > 0.0:
                base = _tdiv(_tdot(nrm, hv), hn)
                base = (sign * base[0], sign * base[1], sign * base[2])
        spec = (0.0, 0.0, 0.0)
        if base[0] > 0.0:
            p0 = _power(base[0], mat[6])
            g = mat[6] * p0 / base[0]  # n b^(n-1)
            g2 = (mat[6] - 1.0) * g / base[0]  # n (n-1) b^(n-2)
            spec = (mat[5] * p0, mat[5] * g * base[1],
                    mat[5] * (g * base[2] + g2 * base[1] * base[1]))
        cr = _tadd(cr, _tadd(spec, ndl, mat[0] * mat[4]), lrgb[j, 0])
        cg = _tadd(cg, _tadd(spec, ndl, mat[1] * mat[4]), lrgb[j, 1])
        cb = _tadd(cb, _tadd(spec, ndl, mat[2] * mat[4]), lrgb[j, 2])
    # a clamped channel stays where it is
    kr = 1.0 if 0.0 < cr[0] < 1.0 else 0.0
    kg = 1.0 if 0.0 < cg[0] < 1.0 else 0.0
    kb = 1.0 if 0.0 < cb[0] < 1.0 else 0.0
    return (kr * cr[1], kg * cg[1], kb * cb[1]), (kr * cr[2], kg * cg[2], kb * cb[2])


@subroutine()
def _moved(k: np.ndarray, e: np.ndarray, n: int, o: int, x: tuple, shift: float) -> tuple:
    """``K[n, o] @ x + shift e[n, o]``: the n+1-th derivative of a point (shift 1) or direction."""
    return (k[n, o, 0, 0] * x[0] + k[n, o, 0, 1] * x[1] + k[n, o, 0, 2] * x[2] + shift * e[n, o, 0],
            k[n, o, 1, 0] * x[0] + k[n, o, 1, 1] * x[1] + k[n, o, 1, 2] * x[2] + shift * e[n, o, 1],
            k[n, o, 2, 0] * x[0] + k[n, o, 2, 1] * x[1] + k[n, o, 2, 2] * x[2] + shift * e[n, o, 2])


#: Polygons per task of :func:`_polygon_motion_table`.
_CHUNK = 256


@nb.njit(cache=True, nogil=True, parallel=True)
def _polygon_motion_table(
    geometry: tuple, materials: np.ndarray, views: np.ndarray, needed: np.ndarray,
    lights: tuple, ambient: float, code: int, rates: tuple, weights: np.ndarray,
    table: np.ndarray, dtable: np.ndarray,
) -> None:
    """Flat colour per needed polygon and zone, and its time derivatives by the chain rule.

    ``geometry`` is ``(vertices (1, V, 3), polygons (P, M), counts (P,), normals (1, P,
    3), shading normals (1, P, 3), polygon_object (P,))`` (the face normals decide
    which side a zone sees, light uses the shading normals, as :func:`_polygon_table`
    does); ``lights`` is :func:`pack_lights`' ``(lvec (1, J, 3),
    lpoint, lrgb)``.  ``table`` (1, Z, P, 3) uint8 gets the colour as :func:`shade`
    stores it.  ``rates`` is ``(K (3, O, 3, 3), e (3, O, 3), lrate (2, J, 3), scale)``
    (:func:`service.scene_motion.motion_derivatives` and the lights' derivatives);
    when ``dtable`` (Z, P, 4) has rows it gets ``scale * weights @ c'`` (channels 0-2)
    and ``scale * weights[0] @ c''`` (channel 3), ``c`` the unclamped colour, in
    float64 (:func:`_light_rates`).  Runs of :data:`_CHUNK` polygons in parallel,
    each through :func:`_table_chunk` (a call, not inlined: numba's parfor array
    analysis takes the Taylor arithmetic's nested tuples for shapes and fails).
    """
    n = geometry[3].shape[1]
    for b in nb.prange((n + _CHUNK - 1) // _CHUNK):
        lo = np.int64(b) * _CHUNK  # int64 in both typings of the body: compiled once
        _table_chunk(lo, min(n, lo + _CHUNK), geometry, materials, views, needed,
                     lights, ambient, code, rates, weights, table, dtable)


@subroutine(nrt=True)
def _table_chunk(
    lo: int, hi: int, geometry: tuple, materials: np.ndarray, views: np.ndarray,
    needed: np.ndarray, lights: tuple, ambient: float, code: int, rates: tuple,
    weights: np.ndarray, table: np.ndarray, dtable: np.ndarray,
) -> None:
    """:func:`_polygon_motion_table` for polygons ``lo .. hi - 1``."""
    vertices, polygons, counts, normals, shading, poly_obj = geometry
    big_k, e, lrate, scale = rates
    zones = views.shape[0]
    w = weights
    paths = np.empty((lights[0].shape[1], 4, 3))
    for p in range(lo, hi):
        shown = False
        for z in range(zones):
            shown |= needed[z, p]
        if not shown:
            continue
        cm = _centroid(0, p, vertices, polygons, counts)
        rated, nn = dtable.shape[0] > 0, 0.0
        nrm = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
        if rated:  # the polygon's light paths, shared by the zones
            o = poly_obj[p]
            n0 = (shading[0, p, 0], shading[0, p, 1], shading[0, p, 2])
            c1, c2 = _moved(big_k, e, 0, o, cm, 1.0), _moved(big_k, e, 1, o, cm, 1.0)
            n1, n2 = _moved(big_k, e, 0, o, n0, 0.0), _moved(big_k, e, 1, o, n0, 0.0)
            nrm = ((n0[0], n1[0], n2[0]), (n0[1], n1[1], n2[1]), (n0[2], n1[2], n2[2]))
            nn = _light_paths(((cm[0], c1[0], c2[0]), (cm[1], c1[1], c2[1]),
                               (cm[2], c1[2], c2[2])), nrm, (lights[0][0], lights[1], lights[2]),
                              lrate, paths)
            nrm = _tunit(nrm)[0]
        for z in range(zones):
            if not needed[z, p]:
                continue
            c = _lit_at(0, p, z, cm, (normals, shading), materials, views, lights, ambient,
                        code)
            _store(table, 0, z, p, c, 255.0, 0.5)
            if not rated:
                continue
            d1, d2 = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
            if nn > 0.0:
                d1, d2 = _light_rates(_facing(normals[0], p, views[z]), nrm, paths,
                                      materials[p], views[z], lights[2], ambient, code)
            for j in range(3):
                dtable[z, p, j] = scale * (w[j, 0] * d1[0] + w[j, 1] * d1[1] + w[j, 2] * d1[2])
            dtable[z, p, 3] = scale * (w[0, 0] * d2[0] + w[0, 1] * d2[1] + w[0, 2] * d2[2])


def light_rates(lights: list[Light], rates: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """First and second time derivatives of :func:`pack_lights`' light vectors.

    Parameters
    ----------
    lights : list of Light
        As seen at the time (the viewer's frame).
    rates : (K (3, O, 3, 3), e (3, O, 3))
        :func:`service.scene_motion.motion_derivatives`; its last row, the world's, moves
        the lights (a direction by ``K``, a point light's position by ``K`` and ``e``).

    Returns
    -------
    ndarray, shape (2, J, 3)
    """
    lvec, lpoint, _ = pack_lights(lights)
    big_k, e = rates[0][:2, -1], rates[1][:2, -1]
    out = np.einsum("nij,lj->nli", big_k, lvec)
    out += lpoint[None, :, None] * e[:, None, :]
    return out.reshape(2, len(lights), 3)


def polygon_motion_tables(
    scene: SceneArrays, vis: Visibility, display: DisplaySettings, lights: list[Light],
    ambient_level: float, settings: LightSettings,
    rates: tuple[np.ndarray, np.ndarray] | None, scale: float, weights: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flat (``polygon``) light at ``t`` and its time derivatives, as tables per polygon.

    One pass over the polygons each zone shows gives what :func:`shade` gives their
    pixels, and the colour's first and second time derivatives by the chain rule
    from the motion of each polygon's centroid and normal and of the lights
    (:func:`_light_rates`): light per polygon is the same at every pixel of it, so
    its derivatives are too.

    Parameters
    ----------
    scene : SceneArrays
        The flattened scene at ``t``.
    vis : Visibility
        Triangle seen at each pixel at ``t``, shape (Z, R, C).
    display : DisplaySettings
    lights : list of Light
        The scene's lights at ``t`` (as the viewer sees them).
    ambient_level : float
    settings : LightSettings
        Its ``evaluation`` must be ``"polygon"``.
    rates : (K (3, O + 1, 3, 3), e (3, O + 1, 3)) or None
        :func:`service.scene_motion.motion_derivatives` (None: no derivatives).
    scale : float
        Factor of the derivatives (255: colour units 0..255).
    weights : ndarray, shape (3, 3)
        RGB to the derivative's three channels (the second derivative takes row 0).

    Returns
    -------
    table : ndarray, shape (Z, P, 3), uint8
        Colour at ``t`` of each polygon shown (others undefined).
    dtable : ndarray, shape (Z, P, 4), float32
        The first derivative's three channels and the second's first (shape (0, 0,
        4) without ``rates``).
    background : ndarray, shape (3,), uint8
    """
    if settings.evaluation != "polygon":
        raise RenderError("polygon_motion_tables needs polygon light")
    zrc = (display.zones, display.rows, display.cols)
    if vis.triangle.shape != zrc:
        raise RenderError(f"visibility buffers are {vis.triangle.shape}, display needs {zrc}")
    needed = vis.shown
    if needed is None or needed.shape != (display.zones, scene.n_polygons):
        needed = mark_shown(np.ascontiguousarray(vis.triangle, np.int32),
                            scene.triangle_polygon, scene.n_polygons)
    lvec, lpoint, lrgb = pack_lights(lights)
    zp = (display.zones, scene.n_polygons)
    table = np.empty((1, *zp, 3), np.uint8)
    if rates is None:
        dtable = np.empty((0, 0, 4), np.float32)
        rates = (np.zeros((3, 1, 3, 3)), np.zeros((3, 1, 3)))
    else:
        dtable = np.empty((*zp, 4), np.float32)
    geometry = (scene.vertices[None], scene.polygons, scene.counts, scene.normals[None],
                np.ascontiguousarray(scene.shading_normals, np.float64)[None],
                scene.polygon_object)
    _polygon_motion_table(geometry, scene.materials, display.view_vectors(), needed,
                          (lvec.reshape(1, -1, 3), lpoint, lrgb), float(ambient_level),
                          MODELS[settings.model],
                          (rates[0], rates[1], light_rates(lights, rates), float(scale)),
                          np.ascontiguousarray(weights, np.float64), table, dtable)
    bg = np.empty((1, 1, 1, 3), np.uint8)
    _store_background(np.asarray(settings.background, np.float64) / 255.0, 255.0, 0.5, bg)
    return table[0], dtable, bg[0, 0, 0]


def to_uint8(x: np.ndarray) -> np.ndarray:
    """Colours in [0, 1] to uint8 ``floor(255 * x + 0.5)`` (x rounded to float32 first).

    This is exactly the quantisation :func:`shade` applies to :func:`shade_linear`.
    """
    v = np.clip(np.asarray(x, np.float32), 0.0, 1.0).astype(np.float64)
    return (v * 255.0 + 0.5).astype(np.uint8)


def _unproject_affine(display: DisplaySettings) -> np.ndarray:
    """Coefficients of :func:`unproject`, which is affine in (col, row, depth).

    Returns
    -------
    ndarray, shape (Z, 4, 3)
        Per zone: the world point at (0, 0, 0) and its derivatives by col, row, depth.
    """
    cols = np.array([0, 1, 0, 0])
    rows = np.array([0, 0, 1, 0])
    dep = np.array([0.0, 0.0, 0.0, 1.0])
    out = np.empty((display.zones, 4, 3))
    for z in range(display.zones):
        w = unproject(z, cols, rows, dep, display)
        out[z, 0] = w[0]
        out[z, 1:] = w[1:] - w[0]
    return out


def _eval_polygon(
    scene: SceneArrays, proj: np.ndarray, vis: Visibility, k: _Packed, out: np.ndarray
) -> None:
    """Flat light: a (Z, P, 3) table for the polygons each zone shows, gathered per pixel.

    The table and the background are quantised once (:func:`_store`), so the pixel
    pass only copies values.
    """
    needed = vis.shown
    if needed is None or needed.shape != (k.views.shape[0], scene.n_polygons):
        needed = mark_shown(vis.triangle, scene.triangle_polygon, scene.n_polygons)
    table = np.zeros((1, k.views.shape[0], scene.n_polygons, 3), out.dtype)
    _polygon_table(
        scene.vertices, scene.polygons, scene.counts, scene.normals, scene.shading_normals,
        scene.materials, k.views, needed, k.lights, k.ambient, k.code, (k.scale, k.offset),
        table,
    )
    bg = np.empty((1, 1, 1, 3), out.dtype)
    _store_background(k.background, k.scale, k.offset, bg)
    _gather(vis.triangle, scene.triangle_polygon, table[0], bg[0, 0, 0], out)


def _eval_vertex(
    scene: SceneArrays, proj: np.ndarray, vis: Visibility, k: _Packed, out: np.ndarray
) -> None:
    """Gouraud light: corner colours of the triangles each zone shows, interpolated."""
    n_tri = scene.triangles.shape[0]
    needed = mark_shown(vis.triangle, np.arange(n_tri), n_tri)
    corner = np.zeros((k.views.shape[0], n_tri, 3, 3), np.float32)
    _corner_table(
        scene.vertices, scene.triangles, scene.triangle_polygon, scene.normals,
        scene.corner_normals, scene.materials, k.views, needed, k.lights, k.ambient,
        k.code, corner,
    )
    _gouraud_pixels(
        vis.triangle, proj, scene.triangles, corner, k.background, k.scale, k.offset, out
    )


def _eval_point(
    scene: SceneArrays, proj: np.ndarray, vis: Visibility, k: _Packed, out: np.ndarray
) -> None:
    """Per-pixel light at the unprojected point with the interpolated normal."""
    geometry = (scene.triangles, scene.triangle_polygon, scene.normals, scene.corner_normals)
    _point_pixels(
        vis.triangle, vis.depth, proj, k.affine, geometry, scene.materials, k.views,
        k.lights, k.ambient, k.code, k.background, k.scale, k.offset, *_outputs(out),
    )


#: Evaluation name -> function(scene, proj, vis, packed, out (Z, R, C, 3)) filling out.
EVALUATIONS = {"polygon": _eval_polygon, "vertex": _eval_vertex, "point": _eval_point}


def _check(scene: SceneArrays, proj: np.ndarray, vis: Visibility, display: DisplaySettings) -> None:
    """Raise :class:`RenderError` when the inputs' shapes disagree."""
    zrc = (display.zones, display.rows, display.cols)
    if vis.triangle.shape != zrc or vis.depth.shape != zrc:
        raise RenderError(f"visibility buffers are {vis.triangle.shape}, display needs {zrc}")
    if proj.shape != (display.zones, scene.vertices.shape[0], 3):
        raise RenderError(
            f"projection is {proj.shape}, expected {(display.zones, scene.vertices.shape[0], 3)}"
        )


def _render(
    scene: SceneArrays,
    proj: np.ndarray,
    vis: Visibility,
    display: DisplaySettings,
    lights: list[Light],
    ambient_level: float,
    settings: LightSettings,
    quantise: bool,
) -> np.ndarray:
    """Shared body of :func:`shade` (``quantise``: uint8) and :func:`shade_linear`."""
    _check(scene, proj, vis, display)
    packed = _Packed(
        views=display.view_vectors(),
        lights=pack_lights(lights),
        ambient=float(ambient_level),
        code=MODELS[settings.model],
        background=np.asarray(settings.background, np.float64) / 255.0,
        affine=_unproject_affine(display) if settings.evaluation == "point" else None,
        scale=255.0 if quantise else 1.0,
        offset=0.5 if quantise else 0.0,
    )
    vis = Visibility(
        np.ascontiguousarray(vis.triangle, np.int32),
        np.ascontiguousarray(vis.depth, np.float32),
        shown=vis.shown,
    )
    out = np.empty((*vis.triangle.shape, 3), np.uint8 if quantise else np.float32)
    proj = np.ascontiguousarray(proj, np.float64)
    EVALUATIONS[settings.evaluation](scene, proj, vis, packed, out)
    return out


def shade(
    scene: SceneArrays,
    proj: np.ndarray,
    vis: Visibility,
    display: DisplaySettings,
    lights: list[Light],
    ambient_level: float,
    settings: LightSettings | None = None,
) -> np.ndarray:
    """Colour every pixel of every zone.

    Parameters
    ----------
    scene : SceneArrays
        The flattened scene (world coordinates).
    proj : ndarray, shape (Z, V, 3)
        :func:`service.render.projection.project` of ``scene.vertices``.
    vis : Visibility
        Triangle and depth seen at each pixel, shapes (Z, R, C).
    display : DisplaySettings
    lights : list of Light
    ambient_level : float
        The scene's ambient light level ``A``.
    settings : LightSettings, optional
        Model, evaluation and background (default: Blinn per polygon, black).

    Returns
    -------
    ndarray, shape (Z, R, C, 3), uint8
        ``round(255 * shade_linear(...))``.

    Raises
    ------
    RenderError
        If the shapes of ``proj`` or ``vis`` do not match ``scene`` and ``display``.
    """
    settings = settings or LightSettings()
    return _render(scene, proj, vis, display, lights, ambient_level, settings, True)


def shade_linear(
    scene: SceneArrays,
    proj: np.ndarray,
    vis: Visibility,
    display: DisplaySettings,
    lights: list[Light],
    ambient_level: float,
    settings: LightSettings | None = None,
) -> np.ndarray:
    """Like :func:`shade` but unquantised: shape (Z, R, C, 3), float32 in [0, 1]."""
    settings = settings or LightSettings()
    return _render(scene, proj, vis, display, lights, ambient_level, settings, False)


def intensity(
    scene: SceneArrays,
    proj: np.ndarray,
    vis: Visibility,
    display: DisplaySettings,
    lights: list[Light],
    ambient_level: float,
    settings: LightSettings | None = None,
) -> np.ndarray:
    """Per-pixel intensity: the mean of the three channels of :func:`shade_linear`.

    Returns
    -------
    ndarray, shape (Z, R, C), float32 in [0, 1]
        The background's intensity where ``vis.triangle`` is -1.
    """
    lin = shade_linear(scene, proj, vis, display, lights, ambient_level, settings)
    return lin.mean(axis=-1, dtype=np.float32)


def intensity_error(test: np.ndarray, reference: np.ndarray, covered: np.ndarray) -> float:
    """Mean absolute intensity difference over covered pixels.

    Parameters
    ----------
    test, reference : ndarray, shape (Z, R, C)
        Intensities from :func:`intensity` on the same visibility buffer.
    covered : ndarray, shape (Z, R, C), bool
        Pixels to compare (e.g. ``vis.triangle >= 0``).

    Returns
    -------
    float
        0.0 when no pixel is covered.
    """
    if not np.any(covered):
        return 0.0
    return float(np.mean(np.abs(test[covered] - reference[covered])))
