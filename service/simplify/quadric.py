"""Quadric edge-collapse decimation (Garland and Heckbert 1997).

For comparison with billboard clouds, and as the decimated levels of an object's
level-of-detail chain.

The collapse itself is fast-simplification's (a maintained wrapper of Sven Forstmann's
Fast-Quadric-Mesh-Simplification): writing and tuning our own priority-queue
edge collapse would add code and bugs for no gain.  What we add is the input check
and a geometric error in world units measured by us (:mod:`.distance`), so a level
of detail can predict its error on screen.
"""

from __future__ import annotations

import fast_simplification
import numpy as np

from service.simplify.distance import surface_distance
from service.simplify.errors import SimplifyError


def check_triangles(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return ``vertices`` as (V, 3) float64 and ``faces`` as (F, 3) int64, or raise.

    Raises
    ------
    SimplifyError
        No faces, wrong shapes, indices out of range or non-finite vertices.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise SimplifyError(f"vertices must have shape (V, 3), not {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0:
        raise SimplifyError(f"the mesh has no triangles (faces of shape {f.shape})")
    if not np.issubdtype(f.dtype, np.integer):
        raise SimplifyError("face indices must be integers")
    if f.min() < 0 or f.max() >= v.shape[0]:
        raise SimplifyError("a face index is out of range")
    if not np.isfinite(v).all():
        raise SimplifyError("a vertex is not finite")
    return v, f.astype(np.int64)


def decimate(vertices: np.ndarray, faces: np.ndarray, target_fraction: float,
             agg: int = 7) -> tuple[np.ndarray, np.ndarray, float]:
    """Collapse edges until about ``target_fraction`` of the triangles remain.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3), float
    faces : ndarray, shape (F, 3), int
    target_fraction : float
        In (0, 1]; 1 returns the mesh unchanged (error 0).
    agg : int
        fast-simplification's aggressiveness (its default 7; lower collapses more
        carefully: the LOD chain uses 4, see :data:`service.lod.settings.QUADRIC_AGG`).

    Returns
    -------
    vertices : ndarray, shape (V', 3), float64
    faces : ndarray, shape (F', 3), int64
    error : float
        Sampled symmetric Hausdorff distance to the input (world units,
        :func:`service.simplify.distance.surface_distance`).

    Raises
    ------
    SimplifyError
        Bad mesh (see :func:`check_triangles`) or a fraction outside (0, 1].
    """
    v, f = check_triangles(vertices, faces)
    if not 0.0 < target_fraction <= 1.0:
        raise SimplifyError(f"target fraction must be in (0, 1], not {target_fraction}")
    if target_fraction == 1.0:
        return v.copy(), f.copy(), 0.0
    vs, fs = fast_simplification.simplify(v, f.astype(np.int32),
                                          target_reduction=1.0 - target_fraction, agg=agg)
    fs = np.asarray(fs, dtype=np.int64)
    if fs.shape[0] == 0:  # collapsed to nothing: keep the coarsest thing that is a mesh
        raise SimplifyError(f"target fraction {target_fraction} leaves no triangles")
    return np.asarray(vs, dtype=np.float64), fs, surface_distance(v, f, vs, fs).max


def decimate_to_error(vertices: np.ndarray, faces: np.ndarray, eps: float,
                      steps: int = 8) -> tuple[np.ndarray, np.ndarray, float]:
    """The fewest triangles (found by bisection on the fraction) with error <= ``eps``.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3), float
    faces : ndarray, shape (F, 3), int
    eps : float
        Greatest error allowed (world units), > 0.
    steps : int
        Bisection steps on the kept fraction (each one decimation, ~0.15 s for 16k
        triangles).

    Returns
    -------
    vertices, faces, error
        As :func:`decimate`; the input itself (error 0) if no fraction tried is good.
    """
    v, f = check_triangles(vertices, faces)
    if not (eps > 0 and np.isfinite(eps)):
        raise SimplifyError(f"error EPS must be a positive number, not {eps}")
    best = (v.copy(), f.copy(), 0.0)
    lo, hi = max(4.0 / f.shape[0], 1e-6), 1.0  # fractions: lo may be too coarse, hi is fine
    for _ in range(steps):
        mid = np.sqrt(lo * hi)  # bisect in log space: errors grow fast at few triangles
        try:
            got = decimate(v, f, mid)
        except SimplifyError:  # collapsed to nothing
            lo = mid
            continue
        if got[2] <= eps:
            best, hi = got, mid
        else:
            lo = mid
    return best
