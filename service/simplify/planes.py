"""Greedy choice of billboard planes (Decoret et al. 2003, section 4; seed 004).

Plane space is discretised into Hough bins: the normal by its polar angle ``theta``
(0 to 90 degrees: a plane and its flip are one plane) and azimuth ``phi``, the offset
``rho`` (``n . x = rho``, from the mesh's bounding-box centre) into bins ``EPS`` wide.
A face is *valid* for a plane when all its corners lie within ``EPS`` of it.  A bin's
density is the area, projected on the bin's centre plane, of the faces valid for it,
less ``penalty`` times that of faces the plane misses by under another ``EPS``
(near-tangent faces: a plane that grazes them would leave them to a nearly parallel
second plane).

Greedy loop: take the densest bin; refine it (halve the angular step around it, over
the bin and its eight neighbours, taking the best offset for each normal exactly by a
sweep, as a bin subdivided without end would) until the step is below
``min_step``; refit the plane to the faces it collapses by least squares (area
weighted) while that raises the density; collapse its valid faces (remove them and
their contributions from the bins).  Repeat until every face lies on some plane: a
face is always valid for its own plane, so the loop ends.  Last, planes whose faces
are all valid for other planes are dropped (merge), smallest first.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from service.simplify.billboard_kernel import (
    best_offset,
    face_distance,
    hough_accumulate,
)
from service.simplify.clip import cut_faces
from service.simplify.errors import SimplifyError


@dataclass(frozen=True)
class PlaneSettings:
    """Knobs of the greedy plane choice.

    Attributes
    ----------
    eps : float
        Greatest distance of a face's corner to its plane (world units), > 0.
    n_theta, n_phi : int
        Hough bins of the normal's polar angle (0-90 degrees) and azimuth (0-360).
    penalty : float
        Weight of near-tangent faces a plane misses (0 turns the penalty off).
    min_step : float
        Refinement stops when the angular step is below this (radians).
    refits : int
        Least-squares refits tried per plane.
    merge : bool
        Drop planes whose faces other planes can hold (tilting them).
    cut : bool
        Cut the faces on the rim of each plane's slab, giving it the part inside
        (:mod:`.clip`), instead of leaving them whole to later planes.
    merge_tries : int
        Nearby planes tried for each plane dropped.
    absorb_step : float
        First angular step (radians) of the tilt that makes a plane take more faces.
    max_tilt : float
        Greatest angle (radians) between a face's normal and a plane that may take it
        or cut it: a face standing near upright on a plane would show there as a
        sliver, leaving a gap where it was seen edge-on (the bunny's feet on the
        horizontal billboard).
    """

    eps: float
    n_theta: int = 12
    n_phi: int = 48
    penalty: float = 0.5
    min_step: float = 0.002
    refits: int = 3
    merge: bool = True
    cut: bool = True
    merge_tries: int = 8
    absorb_step: float = 0.13
    max_tilt: float = float(np.radians(60.0))

    def __post_init__(self) -> None:
        if not self.eps > 0 or not np.isfinite(self.eps):
            raise SimplifyError(f"error EPS must be a positive number, not {self.eps}")
        if self.n_theta < 1 or self.n_phi < 1:
            raise SimplifyError("Hough bins must be at least 1 per angle")
        if not 0 < self.max_tilt <= np.pi / 2:
            raise SimplifyError(f"max_tilt must be in (0, pi/2] radians, not {self.max_tilt}")


@dataclass
class _Mesh:
    """The centred mesh and what every step needs of it."""

    v: np.ndarray       # (V, 3) centred vertices
    f: np.ndarray       # (F, 3) int64
    area: np.ndarray    # (F, 3) area vectors
    radius: float


def _aligned(m: _Mesh, ids: np.ndarray, d: np.ndarray, s: PlaneSettings) -> np.ndarray:
    """Which faces ``ids`` (K,) lean at most ``s.max_tilt`` from normal ``d`` (3,): (K,).

    A zero-area face has no normal and goes anywhere.
    """
    a = m.area[ids]
    return np.abs(a @ d) >= np.cos(s.max_tilt) * np.linalg.norm(a, axis=1) - 1e-300


def _holds(m: _Mesh, ids: np.ndarray, d: np.ndarray, rho: float,
           s: PlaneSettings) -> np.ndarray:
    """Which faces ``ids`` (K,) plane ``d . x = rho`` may take: within EPS and aligned."""
    return (face_distance(m.v, m.f, ids, d, rho) <= s.eps) & _aligned(m, ids, d, s)


def _direction(theta: float, phi: float) -> np.ndarray:
    st = np.sin(theta)
    return np.array([st * np.cos(phi), st * np.sin(phi), np.cos(theta)])


def _bin_directions(s: PlaneSettings) -> tuple[np.ndarray, np.ndarray]:
    """Bin-centre normals (D, 3) and their (theta, phi) (D, 2)."""
    th = (np.arange(s.n_theta) + 0.5) * (np.pi / 2) / s.n_theta
    ph = (np.arange(s.n_phi) + 0.5) * (2 * np.pi) / s.n_phi
    tt, pp = np.meshgrid(th, ph, indexing="ij")
    angles = np.stack([tt.ravel(), pp.ravel()], axis=1)
    st = np.sin(angles[:, 0])
    dirs = np.stack([st * np.cos(angles[:, 1]), st * np.sin(angles[:, 1]),
                     np.cos(angles[:, 0])], axis=1)
    return np.ascontiguousarray(dirs), angles


def _refine(m: _Mesh, ids: np.ndarray, theta: float, phi: float, step: float,
            s: PlaneSettings, fixed: np.ndarray | None = None,
            penalty: float | None = None) -> tuple[float, np.ndarray, float]:
    """Local search around a bin: (density, normal, rho) of the best plane found.

    ``fixed`` (len(ids),) weighs faces by number instead of projected area (merge).
    """
    pen = s.penalty if penalty is None else penalty
    w = np.zeros(ids.shape[0]) if fixed is None else fixed
    d = _direction(theta, phi)
    best, rho = best_offset(m.v, m.f, m.area, ids, d, s.eps, pen, w)
    while step >= s.min_step:
        if fixed is None:  # faces that a plane within a few steps of this one can hold
            near = face_distance(m.v, m.f, ids, d, rho) <= 3 * s.eps + 4 * m.radius * step
            ids, w = ids[near], w[near]
        moved = True
        while moved:
            moved = False
            sphi = step / max(np.sin(theta), 0.05)
            for dt in (-step, 0.0, step):
                for dp in (-sphi, 0.0, sphi):
                    if dt == 0.0 and dp == 0.0:
                        continue
                    c = _direction(theta + dt, phi + dp)
                    dens, r = best_offset(m.v, m.f, m.area, ids, c, s.eps, pen, w)
                    if dens > best * (1 + 1e-9):
                        best, rho, d = dens, r, c
                        theta, phi, moved = theta + dt, phi + dp, True
        step *= 0.5
    return best, d, rho


def _refit(m: _Mesh, ids: np.ndarray, best: float, d: np.ndarray, rho: float,
           s: PlaneSettings) -> tuple[float, np.ndarray, float]:
    """Least-squares refits of the plane to the faces it collapses, while they help."""
    for _ in range(s.refits):
        held = ids[_holds(m, ids, d, rho, s)]
        if held.shape[0] < 2:
            break
        pts = m.v[m.f[held]].reshape(-1, 3)
        w = np.repeat(np.linalg.norm(m.area[held], axis=1), 3) + 1e-300
        c = (pts * w[:, None]).sum(0) / w.sum()
        _, _, vt = np.linalg.svd((pts - c) * np.sqrt(w)[:, None], full_matrices=False)
        n = vt[2] * (1.0 if vt[2] @ d >= 0 else -1.0)
        dens, r = best_offset(m.v, m.f, m.area, ids, n, s.eps, s.penalty,
                              np.zeros(ids.shape[0]))
        if dens <= best * (1 + 1e-9):
            break
        best, d, rho = dens, n, r
    return best, d, rho


def _own_plane(m: _Mesh, face: int) -> tuple[np.ndarray, float]:
    """The plane of one face (its own normal), for a face no bin found."""
    a = m.area[face]
    n = a / np.linalg.norm(a) if np.linalg.norm(a) > 0 else np.array([0.0, 0.0, 1.0])
    return n, float(m.v[m.f[face]].mean(0) @ n)


def _choose(m: _Mesh, acc: np.ndarray, angles: np.ndarray, remaining: np.ndarray,
            drho: float, rho0: float, s: PlaneSettings) -> tuple[np.ndarray, float]:
    """Refine the densest bin into one plane (normal, rho)."""
    j, k = np.unravel_index(int(np.argmax(acc)), acc.shape)
    cell = (np.pi / 2) / s.n_theta
    d0 = _direction(*angles[j])
    rho_c = rho0 + (k + 0.5) * drho
    near = face_distance(m.v, m.f, remaining, d0, rho_c) <= 3 * s.eps + 2 * m.radius * cell
    ids = remaining[near]
    best, d, rho = _refine(m, ids, angles[j, 0], angles[j, 1], cell, s)
    return _refit(m, ids, best, d, rho, s)[1:]


class PlaneCover(NamedTuple):
    """The planes a greedy run chose and the faces (or pieces of faces) on each."""

    planes: np.ndarray
    """(P, 4) float64: unit ``n`` and ``rho`` of ``n . x = rho`` (mesh coordinates)."""
    vertices: np.ndarray
    """(V', 3) float64: the mesh's vertices, then those of the pieces cut."""
    faces: np.ndarray
    """(F', 3) int64: the faces on planes, whole or cut (every piece within EPS)."""
    owner: np.ndarray
    """(F',) int64: the plane each face lies on."""
    parent: np.ndarray
    """(F',) int64: the input face each one is (or is a piece of)."""


class _Greedy:
    """The mesh as the greedy loop cuts it: faces, their owners and the Hough bins."""

    def __init__(self, m: _Mesh, s: PlaneSettings) -> None:
        self.m, self.s = m, s
        self.dirs, self.angles = _bin_directions(s)
        self.drho = s.eps
        nrho = int(np.ceil(2 * m.radius / self.drho)) + 3
        self.rho0 = -0.5 * nrho * self.drho
        self.acc = np.zeros((self.dirs.shape[0], nrho))
        n = m.f.shape[0]
        self.owner = np.full(n, -1, np.int64)  # -2: replaced by its pieces
        self.parent = np.arange(n)
        self.remaining = np.arange(n)
        self._bins(self.remaining, 1.0)

    def _bins(self, ids: np.ndarray, sign: float) -> None:
        m, s = self.m, self.s
        hough_accumulate(m.v, m.f, m.area, ids, self.dirs, self.rho0, self.drho, s.eps,
                         s.penalty, sign, self.acc)

    def collapse(self, p: int, d: np.ndarray, rho: float, held: np.ndarray) -> None:
        """Give plane ``p`` the faces ``held`` (mask over remaining), cutting its rim."""
        s = self.s
        ids = self.remaining[held]
        self.owner[ids] = p
        self._bins(ids, -1.0)
        rest = self.remaining[~held]
        if s.cut and rest.shape[0]:
            rest = self._cut_rim(p, d, rho, ids, rest)
        self.remaining = rest

    def _cut_rim(self, p: int, d: np.ndarray, rho: float, ids: np.ndarray,
                 rest: np.ndarray) -> np.ndarray:
        """Cut the faces next to the collapsed ones that the slab holds in part."""
        m, s = self.m, self.s
        touched = np.zeros(m.v.shape[0], bool)
        touched[m.f[ids].ravel()] = True
        dist = m.v[m.f[rest]] @ d - rho
        partial = (np.abs(dist) <= s.eps).any(1) | ((dist.min(1) < -s.eps)
                                                     & (dist.max(1) > s.eps))
        rim = rest[partial & touched[m.f[rest]].any(1) & _aligned(m, rest, d, s)]
        if rim.shape[0] == 0:
            return rest
        corners, inside, parent, cut = cut_faces(m.v, m.f, rim, d, rho, s.eps,
                                                 1e-12 * m.radius ** 2)
        if not cut.any():
            return rest
        self._bins(rim[cut], -1.0)
        self.owner[rim[cut]] = -2
        first = m.f.shape[0]
        k = corners.shape[0]
        # a piece's corner that is a corner of its face keeps that vertex (so pieces
        # stay connected to their neighbours); the cut points are new vertices
        orig = m.f[parent]  # (K, 3)
        same = (corners[:, :, None, :] == m.v[orig][:, None, :, :]).all(-1)  # (K, 3, 3)
        fresh = ~same.any(-1)
        ids = np.where(fresh, -1, orig[np.arange(k)[:, None], same.argmax(-1)])
        ids[fresh] = m.v.shape[0] + np.arange(int(fresh.sum()))
        v = np.concatenate([m.v, corners[fresh]])
        f = np.concatenate([m.f, ids])
        area = np.concatenate([m.area, 0.5 * np.cross(corners[:, 1] - corners[:, 0],
                                                      corners[:, 2] - corners[:, 0])])
        self.m = _Mesh(v, f, area, m.radius)
        self.parent = np.concatenate([self.parent, self.parent[parent]])
        new = first + np.arange(k)
        self.owner = np.concatenate([self.owner, np.where(inside, p, -1)])
        self._bins(new[~inside], 1.0)
        keep = np.ones(rest.shape[0], bool)
        keep[np.isin(rest, rim[cut])] = False
        return np.concatenate([rest[keep], new[~inside]])


def choose_planes(vertices: np.ndarray, faces: np.ndarray, s: PlaneSettings) -> PlaneCover:
    """Greedy billboard planes for a triangle mesh.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3), float64
    faces : ndarray, shape (F, 3), int64; F >= 1
    s : PlaneSettings

    Returns
    -------
    PlaneCover
        With ``s.cut`` false, ``faces`` are the input faces and ``parent`` is
        ``arange(F)``; with it, faces on a plane's rim are replaced by their pieces.
    """
    centre = 0.5 * (vertices.min(0) + vertices.max(0))
    v = np.ascontiguousarray(vertices - centre)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    a = v[f]
    g = _Greedy(_Mesh(v, f, 0.5 * np.cross(a[:, 1] - a[:, 0], a[:, 2] - a[:, 0]),
                      float(np.linalg.norm(v, axis=1).max())), s)
    planes: list[tuple[np.ndarray, float]] = []
    while g.remaining.shape[0]:
        m, rem = g.m, g.remaining
        d, rho = _choose(m, g.acc, g.angles, rem, g.drho, g.rho0, s)
        held = _holds(m, rem, d, rho, s)
        if not held.any():
            big = rem[np.argmax(np.linalg.norm(m.area[rem], axis=1))]
            d, rho = _own_plane(m, big)
            held = rem == big
        g.collapse(len(planes), d, rho, held)
        planes.append((d, rho))
    out = np.array([[*d, rho] for d, rho in planes])
    on = np.flatnonzero(g.owner >= 0)
    m = _Mesh(g.m.v, g.m.f[on], g.m.area[on], g.m.radius)
    owner = g.owner[on]
    if s.merge:
        out, owner = merge_planes(m, out, owner, s)
    out[:, 3] += out[:, :3] @ centre
    return PlaneCover(out, g.m.v + centre, m.f, owner, g.parent[on])


def _angles(d: np.ndarray) -> tuple[float, float]:
    """(theta, phi) of a unit normal, flipped into the upper hemisphere."""
    d = d if d[2] >= 0 else -d
    return float(np.arccos(np.clip(d[2], -1, 1))), float(np.arctan2(d[1], d[0]))


def _absorb(m: _Mesh, plane: np.ndarray, mine: np.ndarray, orphans: np.ndarray,
            s: PlaneSettings) -> tuple[np.ndarray, np.ndarray] | None:
    """Tilt ``plane`` to hold the orphan faces it can while keeping all of ``mine``.

    Returns the new plane (4,) and the orphans it holds, or None if it holds none.
    """
    ids = np.concatenate([mine, orphans])
    fixed = np.concatenate([np.full(mine.shape[0], 1.0 + orphans.shape[0]),
                            np.ones(orphans.shape[0])])
    need = mine.shape[0] * (1.0 + orphans.shape[0])
    dens, d, rho = _refine(m, ids, *_angles(plane[:3]), s.absorb_step, s, fixed, 0.0)
    if dens < need + 0.5:
        return None
    held = _holds(m, orphans, d, rho, s)
    if mine.shape[0] and not face_distance(m.v, m.f, mine, d, rho).max() <= s.eps:
        return None
    return np.array([*d, rho]), orphans[held]


def _valid(m: _Mesh, plane: np.ndarray, s: PlaneSettings) -> np.ndarray:
    """Which faces (F,) plane (4,) holds."""
    return _holds(m, np.arange(m.f.shape[0]), plane[:3].copy(), float(plane[3]), s)


class _Cover:
    """Planes, which faces each holds, and which plane each face is drawn on."""

    def __init__(self, m: _Mesh, planes: np.ndarray, owner: np.ndarray,
                 s: PlaneSettings) -> None:
        self.planes, self.owner = planes.copy(), owner.copy()
        self.valid = np.stack([_valid(m, p, s) for p in planes])
        self.keep = np.ones(planes.shape[0], bool)

    def copy(self) -> _Cover:
        c = object.__new__(_Cover)
        c.planes, c.owner = self.planes.copy(), self.owner.copy()
        c.valid, c.keep = self.valid.copy(), self.keep.copy()
        return c

    def exclusive(self, q: int, drop: int) -> tuple[np.ndarray, np.ndarray]:
        """Faces owned by ``q``: those no other kept plane (nor ``drop``) holds, the rest."""
        mine = np.flatnonzero(self.owner == q)
        others = self.keep.copy()
        others[[q, drop]] = False
        shared = self.valid[others][:, mine].any(axis=0)
        return mine[~shared], mine[shared]

    def move(self, m: _Mesh, q: int, plane: np.ndarray, held: np.ndarray,
             loose: np.ndarray, s: PlaneSettings) -> None:
        """Replace plane ``q``; it takes ``held``; ``loose`` faces it lost go elsewhere."""
        self.planes[q] = plane
        self.valid[q] = _valid(m, plane, s)
        self.owner[held] = q
        lost = loose[~self.valid[q, loose]]
        if lost.shape[0] == 0:
            return
        rows = np.flatnonzero(self.keep & (np.arange(self.keep.size) != q))
        self.owner[lost] = rows[np.argmax(self.valid[rows][:, lost], axis=0)]


def merge_planes(m: _Mesh, planes: np.ndarray, face_plane: np.ndarray,
                 s: PlaneSettings) -> tuple[np.ndarray, np.ndarray]:
    """Drop planes, fewest faces first, whose faces nearby planes can take.

    Each nearby plane (by the distance of the orphans to it) is tilted and shifted to
    hold as many of the dropped plane's faces as it can while keeping the faces that
    only it holds (a face another plane also holds is handed to that plane if the
    tilt loses it).
    """
    cover = _Cover(m, planes, face_plane, s)
    for p in np.argsort(np.bincount(face_plane, minlength=planes.shape[0])):
        orphans = np.flatnonzero(cover.owner == p)
        elsewhere = cover.valid[cover.keep & (np.arange(cover.keep.size) != p)][:, orphans]
        trial = cover.copy()
        trial.keep[p] = False
        if elsewhere.shape[0]:
            rows = np.flatnonzero(trial.keep)
            ok = elsewhere.any(axis=0)
            trial.owner[orphans[ok]] = rows[np.argmax(elsewhere[:, ok], axis=0)]
            orphans = orphans[~ok]
        others = np.flatnonzero(trial.keep) if orphans.shape[0] else np.zeros(0, np.int64)
        reach = [float(np.median(face_distance(m.v, m.f, orphans, trial.planes[q, :3].copy(),
                                               trial.planes[q, 3]))) for q in others]
        for q in others[np.argsort(reach)[:s.merge_tries]]:
            mine, loose = trial.exclusive(q, p)
            got = _absorb(m, trial.planes[q], mine, orphans, s)
            if got is None:
                continue
            trial.move(m, q, got[0], got[1], loose, s)
            orphans = np.setdiff1d(orphans, got[1])
            if orphans.shape[0] == 0:
                break
        if orphans.shape[0] == 0:
            cover = trial
    new_index = np.cumsum(cover.keep) - 1
    return cover.planes[cover.keep], new_index[cover.owner]
