"""Numba kernel for crease-aware corner normals (see :func:`service.render.mesh.corner_normals`)."""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True, nogil=True)
def corner_normals_kernel(
    vertices: np.ndarray,
    triangles: np.ndarray,
    weld: np.ndarray,
    face_normals: np.ndarray,
    cos_crease: float,
) -> np.ndarray:
    """Crease-aware smooth normals, shape (T, 3, 3).

    ``vertices`` (V, 3), ``triangles`` (T, 3), ``weld`` (V,) welded vertex id,
    ``face_normals`` (T, 3) unit normal of each triangle's polygon.
    """
    t_count = triangles.shape[0]
    # scalars and loops, no array expressions (``weld.max()``, ``b - a``, ``acc / ln``,
    # ``.copy()``): numba compiles each as code of its own, most of this kernel's compile
    n_weld = 0
    for i in range(weld.shape[0]):
        n_weld = max(n_weld, weld[i] + 1)
    # CSR list of triangle corners per welded vertex
    deg = np.zeros(n_weld + 1, np.int64)
    for t in range(t_count):
        for c in range(3):
            deg[weld[triangles[t, c]] + 1] += 1
    fill = np.empty(n_weld, np.int64)
    for i in range(n_weld):
        fill[i] = deg[i]
        deg[i + 1] += deg[i]
    adj = np.empty(t_count * 3, np.int64)
    for t in range(t_count):
        for c in range(3):
            w = weld[triangles[t, c]]
            adj[fill[w]] = t
            fill[w] += 1
    area_n = np.empty((t_count, 3))
    for t in range(t_count):
        a, b, c = triangles[t, 0], triangles[t, 1], triangles[t, 2]
        e10, e11, e12 = (vertices[b, 0] - vertices[a, 0], vertices[b, 1] - vertices[a, 1],
                         vertices[b, 2] - vertices[a, 2])
        e20, e21, e22 = (vertices[c, 0] - vertices[a, 0], vertices[c, 1] - vertices[a, 1],
                         vertices[c, 2] - vertices[a, 2])
        area = 0.5 * np.sqrt(
            (e11 * e22 - e12 * e21) ** 2
            + (e12 * e20 - e10 * e22) ** 2
            + (e10 * e21 - e11 * e20) ** 2
        )
        for k in range(3):
            area_n[t, k] = face_normals[t, k] * (area + 1e-30)
    out = np.empty((t_count, 3, 3))
    for t in range(t_count):
        for c in range(3):
            w = weld[triangles[t, c]]
            acc0, acc1, acc2 = 0.0, 0.0, 0.0
            for j in range(deg[w], deg[w + 1]):
                u = adj[j]
                d = (
                    face_normals[u, 0] * face_normals[t, 0]
                    + face_normals[u, 1] * face_normals[t, 1]
                    + face_normals[u, 2] * face_normals[t, 2]
                )
                if d >= cos_crease:
                    acc0 += area_n[u, 0]
                    acc1 += area_n[u, 1]
                    acc2 += area_n[u, 2]
            ln = np.sqrt(acc0 ** 2 + acc1 ** 2 + acc2 ** 2)
            if ln > 0:
                out[t, c, 0], out[t, c, 1], out[t, c, 2] = acc0 / ln, acc1 / ln, acc2 / ln
            else:
                out[t, c, 0], out[t, c, 1], out[t, c, 2] = (face_normals[t, 0],
                                                            face_normals[t, 1],
                                                            face_normals[t, 2])
    return out


@nb.njit(cache=True, nogil=True)
def newell_normals_kernel(
    vertices: np.ndarray, polygons: np.ndarray, counts: np.ndarray
) -> np.ndarray:
    """Unit Newell normals of polygons, shape (P, 3); zero for degenerate ones.

    ``vertices`` (V, 3) float64, ``polygons`` (P, K) int64 padded with -1, ``counts`` (P,).
    """
    out = np.zeros((polygons.shape[0], 3))
    for p in range(polygons.shape[0]):
        nx = ny = nz = 0.0
        c = counts[p]
        for i in range(c):
            a = polygons[p, i]
            b = polygons[p, i + 1] if i + 1 < c else polygons[p, 0]
            ax, ay, az = vertices[a, 0], vertices[a, 1], vertices[a, 2]
            bx, by, bz = vertices[b, 0], vertices[b, 1], vertices[b, 2]
            nx += (ay - by) * (az + bz)
            ny += (az - bz) * (ax + bx)
            nz += (ax - bx) * (ay + by)
        length = np.sqrt(nx * nx + ny * ny + nz * nz)
        if length > 1e-300:
            out[p, 0], out[p, 1], out[p, 2] = nx / length, ny / length, nz / length
    return out


@nb.njit(cache=True, nogil=True)
def edges_closed_kernel(polygons: np.ndarray, counts: np.ndarray, n_vertices: int) -> bool:
    """Whether every directed edge occurs once and its reverse once (see ``edges_closed``).

    Edges are bucketed by their first vertex (a counting sort), then each edge looks
    for a twin of itself and for its reverse among its end vertex's few edges.
    """
    start = np.zeros(n_vertices + 1, np.int64)
    for p in range(polygons.shape[0]):
        for i in range(counts[p]):
            start[polygons[p, i] + 1] += 1
    for v in range(n_vertices):
        start[v + 1] += start[v]
    fill = start[:-1].copy()
    ends = np.empty(start[n_vertices], np.int64)
    for p in range(polygons.shape[0]):
        c = counts[p]
        for i in range(c):
            a = polygons[p, i]
            ends[fill[a]] = polygons[p, i + 1] if i + 1 < c else polygons[p, 0]
            fill[a] += 1
    for a in range(n_vertices):
        for e in range(start[a], start[a + 1]):
            b = ends[e]
            if b == a:
                return False
            for f in range(e + 1, start[a + 1]):  # the same directed edge twice
                if ends[f] == b:
                    return False
            back = 0
            for f in range(start[b], start[b + 1]):
                if ends[f] == a:
                    back += 1
            if back != 1:
                return False
    return True
