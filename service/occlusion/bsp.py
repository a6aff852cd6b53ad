"""Occlusion by a binary space partitioning tree (Fuchs, Kedem and Naylor; seed 003).

The tree is built once over the world-space triangles of static geometry; every
zone then gets a correct back-to-front painter's order by walking it.  The view
zones are parallel projections, so zone ``k``'s viewer sits at infinity in the
direction ``v_k = (sin theta_k, 0, cos theta_k)`` and is on the front side of a
node's plane exactly when ``v_k . n > 0``.  Triangles that straddle a node's plane
are split into fragments, which is what lets the BSP order resolve cyclic overlap
and interpenetrating triangles where an average-z sort cannot.

Building costs far more than a frame (it is plain Python over numpy, about a
second for ten thousand triangles), so callers keep a :class:`BspCache`, which
rebuilds only when the geometry or the candidate list changes.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass, field

import numba as nb
import numpy as np

from service.display import DisplaySettings
from service.occlusion import Visibility
from service.projection import project
from service.raster import painter_kernel
from service.scene import SceneArrays

EPS_REL = 1e-7
"""On-plane tolerance as a fraction of the geometry's extent."""
CANDIDATES = 5
"""Splitting planes tried per node (the seed's "choose five candidates")."""
SAMPLE = 128
"""Fragments a candidate plane is scored against."""
SPLIT_WEIGHT = 8
"""Score of one split, in units of front/back imbalance."""


@dataclass
class BspTree:
    """A BSP tree flattened into arrays.

    Attributes
    ----------
    key : bytes
        Fingerprint of the geometry it was built from (:func:`fingerprint`).
    front, back : ndarray, shape (M,), int64
        Child node indices, -1 for none; node 0 is the root.
    normal : ndarray, shape (M, 3), float64
        Unit normal of each node's plane (front side is where it points).
    node_start : ndarray, shape (M + 1,), int64
        Node ``i`` holds fragments ``node_start[i]:node_start[i + 1]``, the ones
        lying in its plane, ordered so the earliest in ``order`` is painted last.
    frag_vertices : ndarray, shape (F, 3, 3), float64
        World-space corners of each fragment.
    frag_ids : ndarray, shape (F,), int64
        Scene triangle each fragment came from.
    stats : dict
        ``nodes``, ``fragments``, ``splits``, ``depth``, ``build_ms``.
    """

    key: bytes
    front: np.ndarray
    back: np.ndarray
    normal: np.ndarray
    node_start: np.ndarray
    frag_vertices: np.ndarray
    frag_ids: np.ndarray
    stats: dict = field(default_factory=dict)


@dataclass
class BspCache:
    """Holds the tree of the current geometry; rebuild only when it changes.

    Attributes
    ----------
    tree : BspTree or None
    builds : int
        How many trees this cache has built.
    """

    tree: BspTree | None = None
    builds: int = 0

    def get(self, scene: SceneArrays, order: np.ndarray) -> tuple[BspTree, bool]:
        """The tree for ``scene`` restricted to ``order``, and whether it was (re)built."""
        key = fingerprint(scene.vertices, scene.triangles, order)
        if self.tree is not None and self.tree.key == key:
            return self.tree, False
        self.tree = build_bsp(scene.vertices, scene.triangles, order)
        self.builds += 1
        return self.tree, True


def fingerprint(vertices: np.ndarray, triangles: np.ndarray, tri_ids: np.ndarray) -> bytes:
    """A 16-byte digest of the geometry a tree is built from.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
    triangles : ndarray, shape (T, 3)
    tri_ids : ndarray, shape (N,)
        The triangles (indices into ``triangles``) in the tree, in order.
    """
    h = hashlib.blake2b(digest_size=16)
    for a in (vertices, triangles, tri_ids):
        a = np.ascontiguousarray(a)
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    return h.digest()


class _Pool:
    """Growing store of fragments: corners (n, 3, 3), scene id (n,), rank in order (n,)."""

    def __init__(self, verts: np.ndarray, ids: np.ndarray) -> None:
        self.v = verts.copy()
        self.id = ids.copy()
        self.rank = np.arange(ids.size, dtype=np.int64)
        self.n = ids.size

    def add(self, tris: list, tri_id: int, rank: int) -> list[int]:
        """Append fragments (each a (3, 3) array) of one parent; return their indices."""
        if self.n + len(tris) > self.id.size:
            cap = max(2 * self.id.size, self.n + len(tris), 16)
            self.v = np.resize(self.v, (cap, 3, 3))
            self.id = np.resize(self.id, cap)
            self.rank = np.resize(self.rank, cap)
        idx = list(range(self.n, self.n + len(tris)))
        for i, t in zip(idx, tris, strict=True):
            self.v[i] = t
        self.id[idx] = tri_id
        self.rank[idx] = rank
        self.n += len(tris)
        return idx


def _planes(tv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit normals (n, 3), offsets (n,) and areas x2 (n,) of triangles (n, 3, 3)."""
    nrm = np.cross(tv[:, 1] - tv[:, 0], tv[:, 2] - tv[:, 0])
    length = np.linalg.norm(nrm, axis=1)
    unit = nrm / np.where(length > 0, length, 1.0)[:, None]
    return unit, np.einsum("ij,ij->i", unit, tv[:, 0]), length


def _sides(dist: np.ndarray, eps: float) -> tuple[np.ndarray, np.ndarray]:
    """Per triangle: has a vertex in front, has a vertex behind; dist (..., 3)."""
    return (dist > eps).any(axis=-1), (dist < -eps).any(axis=-1)


def _choose(pool: _Pool, s: np.ndarray, rng: np.random.Generator, eps: float) -> int:
    """Pick the splitter among a few random fragments of ``s``: fewest splits, then balance."""
    cand = s if s.size <= CANDIDATES else rng.choice(s, CANDIDATES, replace=False)
    sample = s if s.size <= SAMPLE else rng.choice(s, SAMPLE, replace=False)
    n, d, _ = _planes(pool.v[cand])
    dist = np.einsum("kj,mvj->kmv", n, pool.v[sample]) - d[:, None, None]
    pos, neg = _sides(dist, eps)
    splits = (pos & neg).sum(axis=1)
    imbalance = np.abs((pos & ~neg).sum(axis=1) - (neg & ~pos).sum(axis=1))
    return int(cand[np.argmin(SPLIT_WEIGHT * splits + imbalance)])


def _fan(poly: list) -> list:
    """Fan-triangulate a convex polygon given as a list of (3,) corners."""
    return [np.array([poly[0], poly[k], poly[k + 1]]) for k in range(1, len(poly) - 1)]


def split_triangle(tri: np.ndarray, dist: np.ndarray, eps: float) -> tuple[list, list]:
    """Split a triangle by a plane.

    Parameters
    ----------
    tri : ndarray, shape (3, 3)
        Corners, in winding order (kept by the fragments).
    dist : ndarray, shape (3,)
        Signed distance of each corner from the plane.
    eps : float
        Corners within ``eps`` of the plane lie on it (go to both sides).

    Returns
    -------
    tuple of two lists
        Front and back fragments, each a (3, 3) array.
    """
    side = np.where(dist > eps, 1, np.where(dist < -eps, -1, 0))
    front, back = [], []
    for i in range(3):
        j = (i + 1) % 3
        if side[i] >= 0:
            front.append(tri[i])
        if side[i] <= 0:
            back.append(tri[i])
        if side[i] * side[j] < 0:
            x = tri[i] + dist[i] / (dist[i] - dist[j]) * (tri[j] - tri[i])
            front.append(x)
            back.append(x)
    return _fan(front), _fan(back)


def _nonzero(tris: list, eps: float) -> list:
    """Drop fragments (each (3, 3)) whose area is negligible (no method can show them)."""
    return [t for t in tris if np.linalg.norm(np.cross(t[1] - t[0], t[2] - t[0])) > eps * eps]


def _partition(pool: _Pool, s: np.ndarray, n: np.ndarray, d: float, eps: float) -> tuple:
    """Classify fragments ``s`` against plane ``n . x = d``, splitting straddlers.

    Returns
    -------
    tuple
        ``(on, front, back, splits)``: pool index arrays and the number split.
    """
    dist = pool.v[s] @ n - d  # (|s|, 3)
    pos, neg = _sides(dist, eps)
    front, back = list(s[pos & ~neg]), list(s[neg & ~pos])
    straddle = np.nonzero(pos & neg)[0]
    for k in straddle:
        f, b = (_nonzero(x, eps) for x in split_triangle(pool.v[s[k]], dist[k], eps))
        tid, rank = int(pool.id[s[k]]), int(pool.rank[s[k]])
        front += pool.add(f, tid, rank)
        back += pool.add(b, tid, rank)
    on = s[~pos & ~neg]
    return on, np.array(front, np.int64), np.array(back, np.int64), straddle.size


def build_bsp(
    vertices: np.ndarray, triangles: np.ndarray, tri_ids: np.ndarray, seed: int = 0
) -> BspTree:
    """Build a BSP tree over world-space triangles.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
        World coordinates.
    triangles : ndarray, shape (T, 3)
    tri_ids : ndarray, shape (N,), int
        Triangles to put in the tree, nearest first (the earlier of two coplanar,
        overlapping triangles is painted last, so it wins, as in the z-buffer).
    seed : int
        Seed of the splitter sampling (the build is deterministic for a seed).

    Returns
    -------
    BspTree
        Zero-area triangles are left out (no method can show them).
    """
    t0 = time.perf_counter()
    ids = np.asarray(tri_ids, np.int64).reshape(-1)
    key = fingerprint(vertices, triangles, ids)
    tv = vertices[triangles[ids]] if ids.size else np.zeros((0, 3, 3))
    extent = float(np.ptp(tv.reshape(-1, 3), axis=0).max()) if ids.size else 1.0
    eps = EPS_REL * max(extent, 1e-12)
    pool = _Pool(tv, ids)
    keep = np.nonzero(_planes(tv)[2] > eps * eps)[0]
    nodes: list = []  # per node: [normal, frags, front, back, depth]
    stack = [(-1, 0, keep)] if keep.size else []
    rng = np.random.default_rng(seed)
    splits = 0
    while stack:
        parent, side, s = stack.pop()
        me = len(nodes)
        if parent >= 0:
            nodes[parent][2 + side] = me
        n, d, _ = _planes(pool.v[[_choose(pool, s, rng, eps)]])
        on, fr, bk, k = _partition(pool, s, n[0], float(d[0]), eps)
        splits += k
        depth = nodes[parent][4] + 1 if parent >= 0 else 1
        nodes.append([n[0], on, -1, -1, depth])
        stack += [(me, i, c) for i, c in enumerate((fr, bk)) if c.size]
    return _flatten(nodes, pool, key, splits, t0)


def _flatten(nodes: list, pool: _Pool, key: bytes, splits: int, t0: float) -> BspTree:
    """Turn the node list into a :class:`BspTree` with fragments grouped by node."""
    m = len(nodes)
    # within a node paint later-in-order first, so the earliest ends on top
    groups = [on[np.argsort(-pool.rank[on], kind="stable")] for _, on, _, _, _ in nodes]
    counts = np.array([g.size for g in groups], np.int64)
    frags = np.concatenate(groups) if m else np.zeros(0, np.int64)
    tree = BspTree(
        key=key,
        front=np.array([nd[2] for nd in nodes], np.int64).reshape(m),
        back=np.array([nd[3] for nd in nodes], np.int64).reshape(m),
        normal=np.array([nd[0] for nd in nodes], np.float64).reshape(m, 3),
        node_start=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
        frag_vertices=np.ascontiguousarray(pool.v[frags]),
        frag_ids=np.ascontiguousarray(pool.id[frags]),
    )
    tree.stats = {
        "nodes": m,
        "fragments": int(frags.size),
        "splits": int(splits),
        "depth": max((nd[4] for nd in nodes), default=0),
        "build_ms": (time.perf_counter() - t0) * 1e3,
    }
    return tree


@nb.njit(cache=True, parallel=True)
def traverse_kernel(
    front: np.ndarray,
    back: np.ndarray,
    normal: np.ndarray,
    node_start: np.ndarray,
    views: np.ndarray,
    orders: np.ndarray,
) -> None:
    """Back-to-front fragment order of every zone (zones in parallel).

    Parameters
    ----------
    front, back : ndarray, shape (M,)
    normal : ndarray, shape (M, 3)
    node_start : ndarray, shape (M + 1,)
    views : ndarray, shape (Z, 3)
        Unit vectors toward each zone's viewer.
    orders : ndarray, shape (Z, F), int64
        Filled with fragment indices, farthest first.
    """
    m = front.shape[0]
    for z in nb.prange(views.shape[0]):
        v = views[z]
        stack = np.empty(2 * m + 3, np.int64)  # node i, or ~i meaning "paint node i"
        sp, k = 0, 0
        if m > 0:
            stack[0] = 0
            sp = 1
        while sp > 0:
            sp -= 1
            item = stack[sp]
            if item < 0:
                for f in range(node_start[~item], node_start[~item + 1]):
                    orders[z, k] = f
                    k += 1
                continue
            facing = v[0] * normal[item, 0] + v[1] * normal[item, 1] + v[2] * normal[item, 2]
            near, far = (front[item], back[item]) if facing > 0 else (back[item], front[item])
            if near >= 0:
                stack[sp] = near
                sp += 1
            stack[sp] = ~item
            sp += 1
            if far >= 0:
                stack[sp] = far
                sp += 1


def bsp(
    scene: SceneArrays,
    proj: np.ndarray,
    display: DisplaySettings,
    order: np.ndarray,
    tree: BspCache | BspTree | None = None,
) -> Visibility:
    """BSP-tree painter's algorithm for every zone.

    Parameters
    ----------
    scene : SceneArrays
    proj : ndarray, shape (Z, V, 3)
        Unused (fragments are projected afresh); kept for the common signature.
    display : DisplaySettings
    order : ndarray, shape (N,), int
        Triangles to draw, nearest first.
    tree : BspCache or BspTree, optional
        A cache is consulted and refreshed; a tree is used if it was built from
        this geometry and ``order`` (else a new one is built and not kept).

    Returns
    -------
    Visibility
        ``triangle`` holds the scene triangle each painted fragment came from;
        ``stats``: ``nodes``, ``fragments``, ``splits``, ``depth``, ``build_ms``,
        ``rebuilt``, ``traverse_ms``, ``raster_ms``.
    """
    order = np.asarray(order, np.int64).reshape(-1)
    if isinstance(tree, BspCache):
        t, rebuilt = tree.get(scene, order)
    elif isinstance(tree, BspTree) and tree.key == fingerprint(
        scene.vertices, scene.triangles, order
    ):
        t, rebuilt = tree, False
    else:
        t, rebuilt = build_bsp(scene.vertices, scene.triangles, order), True
    t0 = time.perf_counter()
    f = t.frag_ids.size
    orders = np.empty((display.zones, f), np.int64)
    traverse_kernel(t.front, t.back, t.normal, t.node_start, display.view_vectors(), orders)
    t1 = time.perf_counter()
    vis = Visibility.empty(display.zones, display.rows, display.cols)
    fproj = project(t.frag_vertices.reshape(-1, 3), display)
    tris = np.arange(3 * f, dtype=np.int64).reshape(f, 3)
    painter_kernel(fproj, tris, t.frag_ids, orders, vis.triangle, vis.depth)
    vis.stats = dict(t.stats, rebuilt=rebuilt, traverse_ms=(t1 - t0) * 1e3,
                     raster_ms=(time.perf_counter() - t1) * 1e3)
    return vis
