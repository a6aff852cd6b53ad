"""Geometric error between two triangle meshes, in world units.

The error of a simplified mesh is a sampled symmetric Hausdorff distance: the
distance of every vertex and face centroid of each mesh to the other mesh's surface,
the largest of them (and their root mean square, for charts).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from service.simplify.distance_kernel import points_to_triangles


class SurfaceDistance(NamedTuple):
    """Sampled distances between two surfaces (world units)."""

    max: float
    """Largest distance of any sample of either surface to the other."""
    rms: float
    """Root mean square of all those distances."""


def surface_samples(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Vertices used by ``faces`` plus face centroids, shape (S, 3) float64."""
    used = vertices[np.unique(faces)]
    return np.concatenate([used, vertices[faces].mean(axis=1)])


def points_to_mesh(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Distance of each point (N, 3) to the surface of triangles ``faces`` (F, 3); shape (N,)."""
    corners = np.ascontiguousarray(vertices[faces], dtype=np.float64)
    return points_to_triangles(np.ascontiguousarray(points, dtype=np.float64), corners)


def surface_distance(va: np.ndarray, fa: np.ndarray, vb: np.ndarray,
                     fb: np.ndarray) -> SurfaceDistance:
    """Sampled symmetric distance between mesh ``(va, fa)`` and mesh ``(vb, fb)``.

    Parameters
    ----------
    va, vb : ndarray, shape (Va, 3) and (Vb, 3), float
    fa, fb : ndarray, shape (Fa, 3) and (Fb, 3), int; both non-empty

    Returns
    -------
    SurfaceDistance
    """
    ab = points_to_mesh(surface_samples(va, fa), vb, fb)
    ba = points_to_mesh(surface_samples(vb, fb), va, fa)
    both = np.concatenate([ab, ba])
    return SurfaceDistance(float(both.max()), float(np.sqrt(np.mean(both ** 2))))
