"""Stage 2: back-face culling, the thesis's modified cull and the plain one.

The plain cull (thesis section 2.1.1) drops a polygon whose normal points away from
the straight-on viewer (n_z <= 0).  With look-around that removes polygons some
zones should see, so the *modified* cull keeps a polygon if and only if it faces at
least one view zone: ``n . v_k > 0`` for some zone direction ``v_k``.  Under the
parallel projection each zone uses, that test is exact for the zone's direction.
What a kept polygon hides in a zone it does not face is left to occlusion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from service.base.errors import SettingsError
from service.display import DisplaySettings


@dataclass(frozen=True)
class CullSettings:
    """Which cull to run.

    Attributes
    ----------
    mode : {"modified", "plain", "none"}
        The polygon-list cull shared by every zone.
    per_zone : bool
        Also skip, in each zone, the polygons of *closed* meshes that face away from
        that zone (see :func:`zone_mask`). Exact, and it roughly halves the raster
        work; off reproduces the thesis, which draws every kept polygon in every zone.
    """

    mode: str = "modified"
    per_zone: bool = True

    def __post_init__(self) -> None:
        if self.mode not in CULLS:
            raise SettingsError(f"cull must be one of {sorted(CULLS)}, got {self.mode!r}")


@nb.njit(cache=True, nogil=True)
def _rows_any(a: np.ndarray) -> np.ndarray:
    """``np.any(a, axis=1)`` for a (N, K) bool array (numpy's is slow for small K)."""
    out = np.zeros(a.shape[0], np.bool_)
    for i in range(a.shape[0]):
        for k in range(a.shape[1]):
            if a[i, k]:
                out[i] = True
                break
    return out


@nb.njit(cache=True, nogil=True)
def _zone_mask_kernel(
    triangle_polygon: np.ndarray, faces: np.ndarray, closed: np.ndarray, out: np.ndarray
) -> None:
    """``out[t, z] = faces[p, z] or not closed[p]`` with ``p = triangle_polygon[t]``."""
    for t in range(triangle_polygon.shape[0]):
        p = triangle_polygon[t]
        for z in range(out.shape[1]):
            out[t, z] = faces[p, z] or not closed[p]


def facing(normals: np.ndarray, display: DisplaySettings) -> np.ndarray:
    """Which zones each polygon faces: ``n . v_k > 0``.

    Both :func:`cull` (the modified cull) and :func:`zone_mask` need this table; a
    caller that runs both computes it once and passes it to each.

    Parameters
    ----------
    normals : ndarray, shape (P, 3)
    display : DisplaySettings

    Returns
    -------
    ndarray, shape (P, Z), bool
        ``n_x v_x + n_y v_y + n_z v_z > 0`` summed in that order, as
        :func:`cull_zones` and the light (:mod:`service.render.light`) evaluate it.
    """
    out = np.empty((normals.shape[0], display.zones), np.bool_)
    _facing_kernel(np.ascontiguousarray(normals, np.float64), display.view_vectors(), out)
    return out


@nb.njit(cache=True, nogil=True, inline="always")
def _faces(normals: np.ndarray, p: int, views: np.ndarray, z: int) -> bool:
    """Whether polygon ``p`` faces zone ``z``: ``n . v_z > 0``, summed x, y, z."""
    n = normals
    return n[p, 0] * views[z, 0] + n[p, 1] * views[z, 1] + n[p, 2] * views[z, 2] > 0.0


@nb.njit(cache=True, nogil=True)
def _facing_kernel(normals: np.ndarray, views: np.ndarray, out: np.ndarray) -> None:
    """``out[p, z]`` = :func:`_faces` for every polygon and zone."""
    for p in range(normals.shape[0]):
        for z in range(views.shape[0]):
            out[p, z] = _faces(normals, p, views, z)


def _modified(normals: np.ndarray, display: DisplaySettings, faces: np.ndarray) -> np.ndarray:
    return _rows_any(faces)


def _plain(normals: np.ndarray, display: DisplaySettings, faces: np.ndarray) -> np.ndarray:
    return normals[:, 2] > 0.0


def _none(normals: np.ndarray, display: DisplaySettings, faces: np.ndarray) -> np.ndarray:
    return np.ones(normals.shape[0], dtype=bool)


CULLS = {"modified": _modified, "plain": _plain, "none": _none}


def cull(
    normals: np.ndarray,
    display: DisplaySettings,
    settings: CullSettings | None = None,
    faces: np.ndarray | None = None,
) -> tuple[np.ndarray, dict]:
    """Decide which polygons to keep.

    Parameters
    ----------
    normals : ndarray, shape (P, 3)
        Unit polygon normals in world coordinates (zero for degenerate polygons,
        which are always culled).
    display : DisplaySettings
    settings : CullSettings, optional
    faces : ndarray, shape (P, Z), bool, optional
        :func:`facing` of these normals, if the caller has it already.

    Returns
    -------
    keep : ndarray, shape (P,), bool
    counts : dict
        ``{"in": P, "culled": ..., "kept": ...}``.
    """
    settings = settings or CullSettings()
    if faces is None and settings.mode == "modified":
        faces = facing(normals, display)
    keep = CULLS[settings.mode](normals, display, faces) & _rows_any(normals != 0.0)
    kept = int(keep.sum())
    return keep, {"in": int(normals.shape[0]), "culled": int(normals.shape[0] - kept), "kept": kept}


def zone_mask(
    triangle_polygon: np.ndarray,
    normals: np.ndarray,
    closed: np.ndarray,
    display: DisplaySettings,
    settings: CullSettings | None = None,
    faces: np.ndarray | None = None,
    by_triangle: bool = False,
) -> np.ndarray:
    """Per zone, which triangles may be drawn.

    A polygon of a closed, consistently wound mesh that faces away from a zone
    (``n . v_k <= 0``) is always hidden there behind the mesh's own front faces, so
    skipping it changes no pixel (it can only remove errors of a painter's order).
    Polygons of open meshes are always drawn: their back side may be what is seen.

    Parameters
    ----------
    triangle_polygon : ndarray, shape (T,)
    normals : ndarray, shape (P, 3)
    closed : ndarray, shape (P,), bool
    display : DisplaySettings
    settings : CullSettings, optional
    faces : ndarray, shape (P, Z), bool, optional
        :func:`facing` of these normals, if the caller has it already.
    by_triangle : bool
        Return the mask by triangle, (T, Z), the layout the one-pass z-buffer reads
        (:func:`service.render.occlusion.zbuffer.zbuffer`'s ``draw_t``): transposing a
        5-zone mask of the game scene cost 0.05 ms.

    Returns
    -------
    ndarray, shape (Z, T) (or (T, Z) by triangle), bool, C-contiguous
    """
    settings = settings or CullSettings()
    shape = (triangle_polygon.shape[0], display.zones)
    if not settings.per_zone:
        return np.ones(shape if by_triangle else shape[::-1], dtype=bool)
    if faces is None:
        faces = facing(normals, display)
    out = np.empty(shape, np.bool_)
    _zone_mask_kernel(
        np.ascontiguousarray(triangle_polygon),
        faces,
        np.ascontiguousarray(closed, np.bool_),
        out,
    )
    return out if by_triangle else np.ascontiguousarray(out.T)


#: :func:`cull_zones`'s code for each cull mode (the kernel's table).
CULL_CODES = {"modified": 0, "plain": 1, "none": 2}


@nb.njit(cache=True, nogil=True)
def _cull_zones_kernel(
    normals: np.ndarray,
    views: np.ndarray,
    triangle_polygon: np.ndarray,
    closed: np.ndarray,
    mode: int,
    per_zone: bool,
    keep: np.ndarray,
    draw_t: np.ndarray,
) -> int:
    """Fill ``keep`` (P,) and ``draw_t`` (T, Z) in one pass; return the polygons kept.

    Each polygon's facing row (:func:`_faces` per zone) is found once and serves
    both: ``mode`` is a :data:`CULL_CODES` value.
    """
    zones = views.shape[0]
    faces = np.empty((normals.shape[0], zones), np.bool_)  # or not closed, with per_zone
    vx, vy, vz = views[:, 0].copy(), views[:, 1].copy(), views[:, 2].copy()
    kept = 0
    for p in range(normals.shape[0]):
        nx, ny, nz = normals[p, 0], normals[p, 1], normals[p, 2]
        open_or_all = (not closed[p]) | (not per_zone)
        any_zone = False
        for z in range(zones):  # | not `or`, the view by component: no branch per zone
            f = nx * vx[z] + ny * vy[z] + nz * vz[z] > 0.0  # as _faces sums it
            faces[p, z] = f | open_or_all
            any_zone |= f
        nonzero = (nx != 0.0) | (ny != 0.0) | (nz != 0.0)
        if mode == 0:
            k = nonzero & any_zone
        elif mode == 1:
            k = nonzero & (nz > 0.0)
        else:
            k = nonzero
        keep[p] = k
        kept += k
    for t in range(triangle_polygon.shape[0]):
        p = triangle_polygon[t]
        for z in range(zones):
            draw_t[t, z] = faces[p, z]
    return kept


def cull_zones(
    normals: np.ndarray,
    triangle_polygon: np.ndarray,
    closed: np.ndarray,
    display: DisplaySettings,
    settings: CullSettings | None = None,
) -> tuple[np.ndarray, dict, np.ndarray]:
    """:func:`cull` and :func:`zone_mask` (by triangle) in one numba pass.

    What the pipeline runs: the two need the same facing table, and at 5 zones
    numpy's table, the two masks and the transposes cost as much as the kernel's
    whole pass several times over.  Equal to the two functions' results.

    Parameters
    ----------
    normals : ndarray, shape (P, 3)
    triangle_polygon : ndarray, shape (T,)
    closed : ndarray, shape (P,), bool
    display : DisplaySettings
    settings : CullSettings, optional

    Returns
    -------
    keep : ndarray, shape (P,), bool
    counts : dict
        As :func:`cull` gives.
    draw_t : ndarray, shape (T, Z), bool, C-contiguous
        :func:`zone_mask` with ``by_triangle``.
    """
    settings = settings or CullSettings()
    keep = np.empty(normals.shape[0], np.bool_)
    draw_t = np.empty((triangle_polygon.shape[0], display.zones), np.bool_)
    kept = _cull_zones_kernel(
        np.ascontiguousarray(normals, np.float64),
        display.view_vectors(),
        np.ascontiguousarray(triangle_polygon, np.int64),
        np.ascontiguousarray(closed, np.bool_),
        CULL_CODES[settings.mode],
        settings.per_zone,
        keep,
        draw_t,
    )
    p = int(normals.shape[0])
    return keep, {"in": p, "culled": p - int(kept), "kept": int(kept)}, draw_t
