"""Occlusion by a binary space partitioning tree (Fuchs, Kedem and Naylor; seed 003).

The tree is built once over the world-space triangles of static geometry; every
zone then gets a correct back-to-front painter's order by walking it.  The view
zones are parallel projections, so zone ``k``'s viewer sits at infinity in the
direction ``v_k = (sin theta_k, 0, cos theta_k)`` and is on the front side of a
node's plane exactly when ``v_k . n > 0``.  Triangles that straddle a node's plane
are split into fragments, which is what lets the BSP order resolve cyclic overlap
and interpenetrating triangles where an average-z sort cannot.

Building costs several frames (a numba kernel; tens to a couple of hundred
milliseconds for ten thousand triangles, depending on how many splits the scene
forces), so callers keep a :class:`BspCache`, which rebuilds only when the
geometry or the candidate list changes; a frame is then one walk per zone (about
a millisecond) plus painting the fragments with :func:`service.render.raster.painter_kernel`.

Splitters are chosen as the seed suggests: a few random candidate planes, each
scored on a sample of the node's fragments by ``SPLIT_WEIGHT * splits + |front -
back|``.  Corners within ``EPS_REL`` of the geometry's extent from a plane count
as lying on it.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass, field

import numba as nb
import numpy as np

from service.display import DisplaySettings
from service.render.occlusion import Visibility
from service.render.projection import project
from service.render.raster import painter_kernel
from service.render.scene import SceneArrays

EPS_REL = 1e-9
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


@nb.njit(cache=True, nogil=True)
def _rand(state: np.ndarray, n: int) -> int:
    """Next xorshift64 draw in ``0..n-1``; ``state`` (1,) uint64 is advanced."""
    x = state[0]
    x ^= x << np.uint64(13)
    x ^= x >> np.uint64(7)
    x ^= x << np.uint64(17)
    state[0] = x
    return int(x % np.uint64(n))


@nb.njit(cache=True, nogil=True)
def _plane(t: np.ndarray) -> tuple:
    """Unit normal (3,), offset and twice the area of a triangle (3, 3)."""
    e1x, e1y, e1z = t[1, 0] - t[0, 0], t[1, 1] - t[0, 1], t[1, 2] - t[0, 2]
    e2x, e2y, e2z = t[2, 0] - t[0, 0], t[2, 1] - t[0, 1], t[2, 2] - t[0, 2]
    n = np.empty(3)
    n[0], n[1], n[2] = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
    length = np.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
    if length > 0:
        n /= length
    return n, n[0] * t[0, 0] + n[1] * t[0, 1] + n[2] * t[0, 2], length


@nb.njit(cache=True, nogil=True)
def _side(t: np.ndarray, n: np.ndarray, d: float, eps: float) -> int:
    """0 on the plane, 1 in front, 2 behind, 3 straddling (a corner each side)."""
    pos = neg = False
    for k in range(3):
        x = n[0] * t[k, 0] + n[1] * t[k, 1] + n[2] * t[k, 2] - d
        pos |= x > eps
        neg |= x < -eps
    return (1 if pos else 0) + (2 if neg else 0)


@nb.njit(cache=True, nogil=True)
def _choose(pv: np.ndarray, seg: np.ndarray, eps: float, state: np.ndarray) -> int:
    """Splitter among a few random fragments of ``seg``: fewest splits, then balance."""
    m = seg.size
    best, best_score = seg[0], np.inf
    for _ in range(min(CANDIDATES, m)):
        c = seg[_rand(state, m)]
        n, d, area = _plane(pv[c])
        if area <= eps * eps:
            continue
        counts = np.zeros(4, np.int64)
        for j in range(min(SAMPLE, m)):
            f = seg[j] if m <= SAMPLE else seg[_rand(state, m)]
            counts[_side(pv[f], n, d, eps)] += 1
        score = SPLIT_WEIGHT * counts[3] + abs(counts[1] - counts[2])
        if score < best_score:
            best, best_score = c, score
    return best


@nb.njit(cache=True, nogil=True)
def _clip(t: np.ndarray, n: np.ndarray, d: float, eps: float) -> tuple:
    """Split a triangle (3, 3) by a plane into front and back convex polygons.

    Returns ``front (4, 3), n_front, back (4, 3), n_back``; corners within ``eps``
    of the plane go to both, and the winding is kept.
    """
    dist = np.empty(3)
    side = np.empty(3, np.int64)
    for k in range(3):
        dist[k] = n[0] * t[k, 0] + n[1] * t[k, 1] + n[2] * t[k, 2] - d
        side[k] = 1 if dist[k] > eps else (-1 if dist[k] < -eps else 0)
    fr, bk = np.empty((4, 3)), np.empty((4, 3))
    nf = nb_ = 0
    for i in range(3):
        j = (i + 1) % 3
        if side[i] >= 0:
            fr[nf] = t[i]
            nf += 1
        if side[i] <= 0:
            bk[nb_] = t[i]
            nb_ += 1
        if side[i] * side[j] < 0:
            a = dist[i] / (dist[i] - dist[j])
            for q in range(3):
                fr[nf, q] = t[i, q] + a * (t[j, q] - t[i, q])
                bk[nb_, q] = fr[nf, q]
            nf += 1
            nb_ += 1
    return fr, nf, bk, nb_


@nb.njit(cache=True, nogil=True)
def _grow_i(a: np.ndarray, need: int) -> np.ndarray:
    """Int array (n,) with room for ``need`` entries (capacity doubles)."""
    if need <= a.shape[0]:
        return a
    out = np.empty((max(need, 2 * a.shape[0], 16),), np.int64)
    for i in range(a.shape[0]):
        out[i] = a[i]
    return out


@nb.njit(cache=True, nogil=True)
def _grow_f(a: np.ndarray, need: int) -> np.ndarray:
    """Float array (n, 3) with room for ``need`` rows (capacity doubles)."""
    if need <= a.shape[0]:
        return a
    out = np.empty((max(need, 2 * a.shape[0], 16), 3))
    flat, src = out.reshape(-1), a.reshape(-1)
    for i in range(src.size):
        flat[i] = src[i]
    return out


@nb.njit(cache=True, nogil=True)
def _grow_t(a: np.ndarray, need: int) -> np.ndarray:
    """Float array (n, 3, 3) with room for ``need`` rows (capacity doubles)."""
    if need <= a.shape[0]:
        return a
    out = np.empty((max(need, 2 * a.shape[0], 16), 3, 3))
    flat, src = out.reshape(-1), a.reshape(-1)
    for i in range(src.size):
        flat[i] = src[i]
    return out


@nb.njit(cache=True, nogil=True)
def _emit(
    poly: np.ndarray,
    k: int,
    rank: int,
    pv: np.ndarray,
    prank: np.ndarray,
    n_pool: int,
    out: np.ndarray,
    n_out: int,
    eps: float,
) -> tuple:
    """Fan a clipped polygon into the pool (dropping zero-area pieces); list them in ``out``.

    The pool must have room for ``k - 2`` more fragments.  Returns the new
    ``n_pool, n_out``.
    """
    for j in range(1, k - 1):
        pv[n_pool, 0], pv[n_pool, 1], pv[n_pool, 2] = poly[0], poly[j], poly[j + 1]
        if _plane(pv[n_pool])[2] <= eps * eps:
            continue
        prank[n_pool] = rank
        out[n_out] = n_pool
        n_pool += 1
        n_out += 1
    return n_pool, n_out


@nb.njit(cache=True, nogil=True)
def _partition(
    seg: np.ndarray,
    pv: np.ndarray,
    prank: np.ndarray,
    n_pool: int,
    n: np.ndarray,
    d: float,
    eps: float,
) -> tuple:
    """Classify fragments ``seg`` against a plane, splitting the ones that straddle it.

    The pool ``pv (P, 3, 3), prank (P,)`` must have room for ``4 * seg.size`` more
    fragments.  Returns ``on, front, back`` (pool index arrays), the new
    ``n_pool`` and the number of fragments split.
    """
    on = np.empty(seg.size, np.int64)
    fr = np.empty(2 * seg.size, np.int64)
    bk = np.empty(2 * seg.size, np.int64)
    n_on = n_fr = n_bk = splits = np.int64(0)  # typed: one signature of _emit
    for f in seg:
        s = _side(pv[f], n, d, eps)
        if s == 0:
            on[n_on] = f
            n_on += 1
        elif s == 1:
            fr[n_fr] = f
            n_fr += 1
        elif s == 2:
            bk[n_bk] = f
            n_bk += 1
        else:
            splits += 1
            pf, kf, pb, kb = _clip(pv[f], n, d, eps)
            n_pool, n_fr = _emit(pf, kf, prank[f], pv, prank, n_pool, fr, n_fr, eps)
            n_pool, n_bk = _emit(pb, kb, prank[f], pv, prank, n_pool, bk, n_bk, eps)
    return on[:n_on], fr[:n_fr], bk[:n_bk], n_pool, splits


@nb.njit(cache=True, nogil=True)
def _build_kernel(tv: np.ndarray, keep: np.ndarray, eps: float, seed: int) -> tuple:
    """Build the tree depth first with an explicit stack (no recursion limit).

    Fragment index sets live as segments of one buffer; a popped segment is always
    the last one, so its children overwrite it in place.

    Returns
    -------
    tuple
        ``normal (M, 3), front (M,), back (M,), depth (M,), node_frags (F,),
        node_start (M + 1,), pool corners (P, 3, 3), pool rank (P,), splits``.
    """
    pv, prank, n_pool = tv.copy(), np.arange(tv.shape[0]), tv.shape[0]
    buf = keep.copy()
    # stack rows: lo, length, parent * 2 + side (0 front, 1 back), depth
    stack = np.empty(4 * 16, np.int64)
    stack[0:4] = np.array([0, keep.size, -1, 1])
    sp = 1 if keep.size else 0
    nrm, kid, depth = np.empty((0, 3)), np.empty(0, np.int64), np.empty(0, np.int64)
    nfrag, nstart = np.empty(0, np.int64), np.zeros(1, np.int64)
    m = n_nf = splits = 0
    state = np.array([np.uint64(seed) * np.uint64(2654435761) + np.uint64(88172645463325252)])
    while sp > 0:
        sp -= 1
        lo, ln, ps, dp = stack[4 * sp], stack[4 * sp + 1], stack[4 * sp + 2], stack[4 * sp + 3]
        seg = buf[lo : lo + ln]
        n, d, _ = _plane(pv[_choose(pv, seg, eps, state)])
        pv, prank = _grow_t(pv, n_pool + 4 * ln), _grow_i(prank, n_pool + 4 * ln)
        on, fr, bk, n_pool, k = _partition(seg, pv, prank, n_pool, n, d, eps)
        splits += k
        nrm, kid, depth = _grow_f(nrm, m + 1), _grow_i(kid, 2 * m + 2), _grow_i(depth, m + 1)
        nrm[m], kid[2 * m], kid[2 * m + 1], depth[m] = n, -1, -1, dp
        if ps >= 0:
            kid[ps] = m
        nfrag, nstart = _grow_i(nfrag, n_nf + on.size), _grow_i(nstart, m + 2)
        nfrag[n_nf : n_nf + on.size] = on
        n_nf += on.size
        nstart[m + 1] = n_nf
        buf = _grow_i(buf, lo + fr.size + bk.size)
        buf[lo : lo + fr.size] = fr
        buf[lo + fr.size : lo + fr.size + bk.size] = bk
        stack = _grow_i(stack, 4 * sp + 8)
        for side, c_lo, c_len in ((0, lo, fr.size), (1, lo + fr.size, bk.size)):
            if c_len:
                stack[4 * sp : 4 * sp + 4] = np.array([c_lo, c_len, 2 * m + side, dp + 1])
                sp += 1
        m += 1
    return (
        nrm[:m],
        kid[0 : 2 * m : 2].copy(),
        kid[1 : 2 * m : 2].copy(),
        depth[:m],
        nfrag[:n_nf],
        nstart[: m + 1].copy(),
        pv[:n_pool],
        prank[:n_pool],
        splits,
    )


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
    tv = np.ascontiguousarray(vertices[triangles[ids]], np.float64).reshape(-1, 3, 3)
    extent = float(np.ptp(tv.reshape(-1, 3), axis=0).max()) if ids.size else 1.0
    eps = EPS_REL * max(extent, 1e-12)
    area = np.linalg.norm(np.cross(tv[:, 1] - tv[:, 0], tv[:, 2] - tv[:, 0]), axis=1)
    keep = np.nonzero(area > eps * eps)[0].astype(np.int64)
    nrm, front, back, depth, nfrag, nstart, pv, prank, splits = _build_kernel(tv, keep, eps, seed)
    # within a node paint later-in-order first, so the earliest ends on top
    node_of = np.repeat(np.arange(front.size), np.diff(nstart))
    frags = nfrag[np.lexsort((-prank[nfrag], node_of))]
    tree = BspTree(
        key, front, back, nrm, nstart, np.ascontiguousarray(pv[frags]), ids[prank[frags]]
    )
    tree.stats = {
        "nodes": int(front.size),
        "fragments": int(frags.size),
        "splits": int(splits),
        "depth": int(depth.max(initial=0)),
        "build_ms": (time.perf_counter() - t0) * 1e3,
    }
    return tree


@nb.njit(cache=True, nogil=True)
def traverse_kernel(
    front: np.ndarray,
    back: np.ndarray,
    normal: np.ndarray,
    node_start: np.ndarray,
    views: np.ndarray,
    orders: np.ndarray,
) -> None:
    """Back-to-front fragment order of every zone.

    Serial: a walk costs about a millisecond, less than a parallel kernel's start-up.

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
    for z in range(views.shape[0]):
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
    vis.stats = dict(
        t.stats,
        rebuilt=rebuilt,
        traverse_ms=(t1 - t0) * 1e3,
        raster_ms=(time.perf_counter() - t1) * 1e3,
    )
    return vis
