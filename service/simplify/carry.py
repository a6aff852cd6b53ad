"""A full mesh's normals carried to a simplified level of it (appearance-preserving).

A coarse level lit with its own face normals changes the picture far more than its
geometric error says: the issue 31 crowd (200 bunnies, Blinn per polygon, LOD at
0.5 px) had 6.3 % of all pixels differ in colour against 0.09 % in coverage.  So a
level is lit with the normals of the surface it stands for (as appearance-preserving
simplification does, Cohen, Olano and Manocha 1998, here with normals per face and
vertex rather than normal maps):

* each coarse face takes the area-weighted mean normal of the full mesh's faces whose
  centroids lie nearest to it (among coarse faces facing the same way): under a
  directional light the diffuse term is linear in the normal, so the coarse face's
  flat colour is close to the mean of the colours of the faces it replaces; a face
  that no full face maps to takes the normal of the full face nearest its centroid;
* smooth light (per vertex, per point) keeps the level's own corner normals: the
  full mesh's smooth normal carried to each coarse vertex (at its nearest full-mesh
  point) turned more of the bunny's surface by over 7 degrees than the level's own
  (2.4-30 % against 0.3-23 % over the first five levels), and raised the bench
  crowd's per-vertex colour difference from 2.25 % to 2.99 % of all pixels.

:func:`carried_level` also measures what the selector predicts colour error from: the
share of the full mesh's area whose light normal turns by more than a given angle.
"""

from __future__ import annotations

import numpy as np

from service.render.mesh import Mesh, Shading
from service.simplify.distance_kernel import nearest_facing


def _unit(v: np.ndarray) -> np.ndarray:
    """Rows of ``v`` (N, 3) scaled to length 1; zero rows stay zero."""
    length = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, length, out=np.zeros_like(v), where=length > 0)


def _face_frames(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, ...]:
    """Corners (F, 3, 3), unit normals (F, 3), areas (F,) and centroids (F, 3)."""
    corners = np.ascontiguousarray(vertices[faces], np.float64)
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    return corners, _unit(cross), 0.5 * np.linalg.norm(cross, axis=1), corners.mean(axis=1)


def _barycentric(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Weights (N, 3) of each point's projection on its triangle, clamped into it."""
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    v0, v1, v2 = b - a, c - a, points - a
    d00, d01, d11 = (v0 * v0).sum(1), (v0 * v1).sum(1), (v1 * v1).sum(1)
    d20, d21 = (v2 * v0).sum(1), (v2 * v1).sum(1)
    den = d00 * d11 - d01 * d01
    safe = np.where(np.abs(den) > 0, den, 1.0)
    v = np.where(den != 0, (d11 * d20 - d01 * d21) / safe, 1 / 3)
    w = np.where(den != 0, (d00 * d21 - d01 * d20) / safe, 1 / 3)
    weights = np.clip(np.stack([1.0 - v - w, v, w], axis=1), 0.0, None)
    total = weights.sum(axis=1, keepdims=True)
    return np.where(total > 0, weights / np.where(total > 0, total, 1.0), 1 / 3)


def _owners(full: Mesh, vertices: np.ndarray, faces: np.ndarray) -> dict:
    """Each full triangle's coarse face (nearest, facing its way), and both meshes' frames."""
    fine_corners, _, fine_area, fine_mid = _face_frames(full.vertices, full.triangles)
    fine_n = full.normals[full.triangle_polygon]  # the polygon's, as light uses
    corners, coarse_n, _, coarse_mid = _face_frames(vertices, faces)
    return {"owner": nearest_facing(fine_mid, fine_n, corners, coarse_n),
            "fine": (fine_corners, fine_n, fine_area, fine_mid),
            "coarse": (corners, coarse_n, coarse_mid)}


def _carried_normals(owners: dict, n_faces: int) -> np.ndarray:
    """Unit normal per coarse face (F, 3): the area-weighted normals of its full faces."""
    fine_corners, fine_n, fine_area, _ = owners["fine"]
    _, coarse_n, coarse_mid = owners["coarse"]
    acc = np.zeros((n_faces, 3))
    np.add.at(acc, owners["owner"], fine_area[:, None] * fine_n)
    empty = np.linalg.norm(acc, axis=1) == 0
    if empty.any():  # a coarse face no full face maps to: the full face at its centroid
        near = nearest_facing(coarse_mid[empty], coarse_n[empty], fine_corners, fine_n)
        acc[empty] = fine_n[near]
    out = _unit(acc)
    flat = np.linalg.norm(out, axis=1) == 0  # opposite normals cancelled
    out[flat] = coarse_n[flat]
    return out


def _turned(owners: dict, level: Mesh, full: Mesh, angles: np.ndarray) -> np.ndarray:
    """Share of ``full``'s area whose light normal turns by more than each of ``angles``.

    Returns shape (A, 2), ``[flat, smooth]`` per angle (radians): per-polygon light (a
    full face's normal against its coarse face's carried one) and smooth light (the
    full mesh's corner normals against the level's, both interpolated at the full
    face's centroid).
    """
    fine_corners, fine_n, fine_area, fine_mid = owners["fine"]
    corners = owners["coarse"][0]
    own = owners["owner"]
    weight = fine_area / max(float(fine_area.sum()), np.finfo(float).tiny)
    flat = (level.shading_normals[own] * fine_n).sum(axis=1)
    bary = _barycentric(fine_mid, corners[own])
    mine = _unit(np.einsum("nk,nkx->nx", bary, level.corner_normals[own]))
    theirs = _unit(full.corner_normals.mean(axis=1))
    smooth = (mine * theirs).sum(axis=1)
    cos = np.cos(np.asarray(angles, np.float64))[:, None]
    return np.clip(np.stack([(weight * (flat < cos)).sum(axis=1),
                             (weight * (smooth < cos)).sum(axis=1)], axis=1), 0.0, 1.0)


def carried_level(full: Mesh, vertices: np.ndarray, faces: np.ndarray, name: str,
                  angles: np.ndarray) -> tuple[Mesh, np.ndarray]:
    """The level ``(vertices, faces)`` of ``full``, lit with ``full``'s normals.

    Parameters
    ----------
    full : Mesh
        The full mesh (its triangles, polygon normals and corner normals are used).
    vertices : ndarray, shape (V, 3), float64
        The level's vertices.
    faces : ndarray, shape (F, 3), int64
        The level's triangles (its polygons: one each).
    name : str
    angles : ndarray, shape (A,), float64
        Radians a light normal may turn before a pixel's colour is counted as changed
        (:data:`service.lod.settings.COLOUR_ANGLES`).

    Returns
    -------
    level : Mesh
        With :attr:`Mesh.shading` the carried normal of each face (see the module notes).
    turned : ndarray, shape (A, 2), float64
        Share of the full mesh's area whose light normal turns by more than each angle
        at this level, for per-polygon and for smooth (per-vertex, per-point) light.
    """
    plain = Mesh.from_triangles(vertices, faces, name)
    owners = _owners(full, plain.vertices, plain.triangles)
    level = Mesh(plain.vertices, plain.polygons, plain.counts, name,
                 shading=Shading(_carried_normals(owners, plain.n_polygons)))
    return level, _turned(owners, level, full, angles)
