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

import numpy as np

from service.display import DisplaySettings
from service.errors import SettingsError


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


def _modified(normals: np.ndarray, display: DisplaySettings) -> np.ndarray:
    return np.any(normals @ display.view_vectors().T > 0.0, axis=1)


def _plain(normals: np.ndarray, display: DisplaySettings) -> np.ndarray:
    return normals[:, 2] > 0.0


def _none(normals: np.ndarray, display: DisplaySettings) -> np.ndarray:
    return np.ones(normals.shape[0], dtype=bool)


CULLS = {"modified": _modified, "plain": _plain, "none": _none}


def cull(
    normals: np.ndarray, display: DisplaySettings, settings: CullSettings | None = None
) -> tuple[np.ndarray, dict]:
    """Decide which polygons to keep.

    Parameters
    ----------
    normals : ndarray, shape (P, 3)
        Unit polygon normals in world coordinates (zero for degenerate polygons,
        which are always culled).
    display : DisplaySettings
    settings : CullSettings, optional

    Returns
    -------
    keep : ndarray, shape (P,), bool
    counts : dict
        ``{"in": P, "culled": ..., "kept": ...}``.
    """
    settings = settings or CullSettings()
    keep = CULLS[settings.mode](normals, display) & np.any(normals != 0.0, axis=1)
    kept = int(keep.sum())
    return keep, {"in": int(normals.shape[0]), "culled": int(normals.shape[0] - kept), "kept": kept}


def zone_mask(
    triangle_polygon: np.ndarray,
    normals: np.ndarray,
    closed: np.ndarray,
    display: DisplaySettings,
    settings: CullSettings | None = None,
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

    Returns
    -------
    ndarray, shape (Z, T), bool
    """
    settings = settings or CullSettings()
    if not settings.per_zone:
        return np.ones((display.zones, triangle_polygon.shape[0]), dtype=bool)
    faces = normals @ display.view_vectors().T > 0.0  # (P, Z)
    poly_ok = faces | ~closed[:, None]
    return np.ascontiguousarray(poly_ok[triangle_polygon].T)
