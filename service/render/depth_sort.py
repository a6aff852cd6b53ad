"""Stage 3: depth sort by average z, nearest first (thesis section 2.1.2).

The thesis sorts with heapsort for its small memory use.  We sort stably, and
stability gives the thesis's tie rule for free: polygons with equal average z keep
their list order, which is object order, so the earlier object takes precedence
(thesis section 3.2).  One sort serves every zone: under the zones' parallel
projections depth along every view ray is -z.

Every occlusion method reads the order (run-length and BSP paint by it; the z-buffer
and ray casting give a tie in depth to the triangle earlier in it).  The z-buffer
needs no sort for that: it draws the kept triangles (:func:`kept_triangles`) in index
order, and where two tie its depth test asks :func:`earlier_in_order`, which finds the
sort's order of the two from their polygons alone (:mod:`service.render.raster`), so
the pixels are the sorted order's.  For the others the sort is
made cheap, giving
exactly the permutation of ``np.argsort(-avg_z, kind="stable")`` (the reference,
:func:`sort_polygons_reference`): the float64 keys become uint64 ones that sort the
same way, LSD radix passes (11-bit digits, digits every key shares skipped) order
them by their high 32 bits, and insertion finishes the short runs equal there
(:func:`_radix_order`).  :func:`depth_order`, the pipeline's sort step, also averages
z for the kept polygons only and, where every polygon is one triangle, needs no
expansion to triangles.  On the 200-bunny LOD crowd (5 zones, 320x240; 122,000 of
227,000 polygons kept) the step measured 3.7-4.4 ms against 13.1-13.7 ms of CPU
(best and median of 40, interleaved in one process, one thread).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from service.numba_subroutine import subroutine


@nb.njit(cache=True, nogil=True)
def average_z(vertices: np.ndarray, polygons: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Average z of each polygon's vertices.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
    polygons : ndarray, shape (P, K), padded with -1
    counts : ndarray, shape (P,)

    Returns
    -------
    ndarray, shape (P,), float64
    """
    out = np.empty(polygons.shape[0])
    for p in range(polygons.shape[0]):
        s = 0.0
        for k in range(counts[p]):
            s += vertices[polygons[p, k], 2]
        out[p] = s / counts[p]
    return out


#: Bits per digit of the radix sort (2,048 buckets a pass).
RADIX_BITS = 11
#: The radix passes cover the key bits from this one up; runs of keys equal there are
#: finished by insertion (:func:`_radix_order`).
HIGH_BIT = 32
#: Insertion moves per key allowed before the low bits get radix passes too.
INSERTION_WORK = 4


def sort_polygons(avg_z: np.ndarray, keep: np.ndarray | None = None) -> np.ndarray:
    """Polygon indices from nearest (highest average z) to farthest.

    The permutation of :func:`sort_polygons_reference` (``np.argsort`` of ``-avg_z``,
    stable; -0.0 equal to 0.0; NaN last), by a radix sort.

    Parameters
    ----------
    avg_z : ndarray, shape (P,)
    keep : ndarray, shape (P,), bool, optional
        Polygons that survived the cull; others are left out.

    Returns
    -------
    ndarray, shape (N,), int64
        Ties keep polygon (object) order.
    """
    keep = np.ones(avg_z.shape[0], np.bool_) if keep is None else keep
    keys, idx = _sort_keys(np.ascontiguousarray(avg_z, np.float64),
                           np.ascontiguousarray(keep, np.bool_))
    return _radix_order(keys, idx, RADIX_BITS)


def depth_order(vertices: np.ndarray, polygons: np.ndarray, counts: np.ndarray,
                triangle_polygon: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """The triangles of the kept polygons, nearest polygon (highest average z) first.

    ``triangle_order(sort_polygons(average_z(...), keep), triangle_polygon)`` in one
    call, averaging z only over the polygons kept.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
    polygons : ndarray, shape (P, K), padded with -1
    counts : ndarray, shape (P,)
    triangle_polygon : ndarray, shape (T,)
        Polygon of each triangle; a polygon's triangles are contiguous, in polygon
        order, at least one each (a mesh's polygons have 3 corners or more), so
        ``T == P`` means triangle ``t`` is polygon ``t``.
    keep : ndarray, shape (P,), bool

    Returns
    -------
    ndarray, shape (M,), int64
    """
    keys, idx = _depth_keys(vertices, polygons, counts, np.ascontiguousarray(keep, np.bool_))
    order = _radix_order(keys, idx, RADIX_BITS)
    if triangle_polygon.shape[0] == polygons.shape[0]:  # one triangle each: polygon t is
        return order  # triangle t (a polygon's triangles are contiguous, in order)
    return triangle_order(order, triangle_polygon)


def kept_triangles(triangle_polygon: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """The triangles of the kept polygons, ascending: the z-buffer's drawing order.

    The z-buffer draws these in index order and finds a tie's order from
    :func:`tie_source` only where it meets one (:func:`earlier_in_order`).

    Parameters
    ----------
    triangle_polygon : ndarray, shape (T,)
    keep : ndarray, shape (P,), bool

    Returns
    -------
    ndarray, shape (M,), int64
    """
    return _kept_triangles(np.ascontiguousarray(triangle_polygon, np.int64),
                           np.ascontiguousarray(keep, np.bool_))


@nb.njit(cache=True, nogil=True)
def _kept_triangles(triangle_polygon: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Numba body of :func:`kept_triangles` (no branch on ``keep``)."""
    order = np.empty(triangle_polygon.shape[0] + 1, np.int64)
    m = 0
    for t in range(triangle_polygon.shape[0]):
        order[m] = t
        m += np.int64(keep[triangle_polygon[t]])
    return order[:m]


def tie_source(vertices: np.ndarray, polygons: np.ndarray, counts: np.ndarray,
               triangle_polygon: np.ndarray) -> tuple:
    """What the z-buffer's depth test reads to order two tied triangles.

    (:func:`earlier_in_order` reads it.)

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
    polygons : ndarray, shape (P, K), padded with -1
    counts : ndarray, shape (P,)
    triangle_polygon : ndarray, shape (T,)
        Polygon of each triangle (contiguous, in polygon order).

    Returns
    -------
    tuple of ndarray
        The four, contiguous float64 / int64; :data:`NO_TIE_SOURCE` when there is no
        depth order to follow (ties then go to the triangle drawn first).
    """
    return (np.ascontiguousarray(vertices, np.float64), np.ascontiguousarray(polygons, np.int64),
            np.ascontiguousarray(counts, np.int64),
            np.ascontiguousarray(triangle_polygon, np.int64))


#: :func:`tie_source` of nothing: no depth order, ties go to the triangle drawn first.
NO_TIE_SOURCE = (np.empty((0, 3)), np.empty((0, 1), np.int64), np.empty(0, np.int64),
                 np.empty(0, np.int64))


@nb.njit(cache=True, nogil=True, inline="always")
def _depth_value(vertices: np.ndarray, polygons: np.ndarray, counts: np.ndarray,
                 p: int) -> float:
    """``-average z`` of polygon ``p`` (:func:`average_z`'s arithmetic, term for term).

    The one source of a polygon's depth for the sort (:func:`_depth_keys`) and for a
    tie's order (:func:`earlier_in_order`), so the two agree bit for bit.
    """
    s = 0.0
    for k in range(counts[p]):
        s += vertices[polygons[p, k], 2]
    return -(s / counts[p])


@nb.njit(cache=True, nogil=True)
def earlier_in_order(source: tuple, t: int, u: int) -> bool:
    """Whether triangle ``t`` comes before ``u`` in :func:`depth_order`.

    The sort's order of two triangles (their polygons' ``-average z``, as
    :func:`depth_order`'s radix keys order it, then the triangle index), found from the
    two polygons alone (``source``: :func:`tie_source`): -0.0 equal to 0.0, NaN last.
    """
    vertices, polygons, counts, triangle_polygon = source
    a = _depth_value(vertices, polygons, counts, triangle_polygon[t])
    b = _depth_value(vertices, polygons, counts, triangle_polygon[u])
    if a != a or b != b:  # a NaN sorts after every number; two NaNs by index
        return (b != b and a == a) or (a != a and b != b and t < u)
    return a < b or (a == b and t < u)


def sort_polygons_reference(avg_z: np.ndarray, keep: np.ndarray | None = None) -> np.ndarray:
    """Polygon indices from nearest (highest average z) to farthest, by ``np.argsort``.

    Parameters
    ----------
    avg_z : ndarray, shape (P,)
    keep : ndarray, shape (P,), bool, optional
        Polygons that survived the cull; others are left out.

    Returns
    -------
    ndarray, shape (N,), int64
        Ties keep polygon (object) order.
    """
    idx = np.arange(avg_z.shape[0]) if keep is None else np.nonzero(keep)[0]
    # a stable sort of ascending indices keeps equal keys in index (object) order
    return idx[np.argsort(-avg_z[idx], kind="stable")].astype(np.int64)


def triangle_order(polygon_order: np.ndarray, triangle_polygon: np.ndarray) -> np.ndarray:
    """Expand a polygon order into the order of their (fan) triangles.

    Parameters
    ----------
    polygon_order : ndarray, shape (N,)
    triangle_polygon : ndarray, shape (T,)
        Polygon of each triangle; a polygon's triangles are contiguous.

    Returns
    -------
    ndarray, shape (M,), int64
    """
    return _triangle_order(
        np.ascontiguousarray(polygon_order, np.int64),
        np.ascontiguousarray(triangle_polygon, np.int64),
    )


@nb.njit(cache=True, nogil=True)
def _triangle_order(polygon_order: np.ndarray, triangle_polygon: np.ndarray) -> np.ndarray:
    """Numba body of :func:`triangle_order`."""
    n_poly = triangle_polygon.max() + 1 if triangle_polygon.size else 0
    first = np.full(n_poly + 1, 0, np.int64)
    for t in range(triangle_polygon.size):
        first[triangle_polygon[t] + 1] += 1
    for p in range(n_poly):
        first[p + 1] += first[p]
    total = 0
    for p in polygon_order:
        total += first[p + 1] - first[p]
    out = np.empty(total, np.int64)
    i = 0
    for p in polygon_order:
        for t in range(first[p], first[p + 1]):
            out[i] = t
            i += 1
    return out


@subroutine(nrt=True)
def _to_keys(keys: np.ndarray) -> None:
    """In place: float64 values (viewed as uint64 ``keys``) to keys that sort as they do.

    -0.0 sorts as 0.0 and every NaN last, as ``np.argsort`` has them.
    """
    values = keys.view(np.float64)
    top = np.uint64(1) << np.uint64(63)
    for i in range(keys.shape[0]):
        x = values[i]
        if x != x:
            keys[i] = np.uint64(0xFFFFFFFFFFFFFFFF)
            continue
        values[i] = x + 0.0  # -0.0 becomes 0.0
        b = keys[i]
        keys[i] = ~b if b & top else b | top


@nb.njit(cache=True, nogil=True)
def _sort_keys(avg_z: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Radix keys of ``-avg_z`` and the indices of the kept polygons, in index order."""
    n = 0
    for p in range(avg_z.shape[0]):
        if keep[p]:
            n += 1
    keys, idx = np.empty(n, np.uint64), np.empty(n, np.int64)
    values = keys.view(np.float64)  # keys stays C-contiguous (a view is typed 'A')
    i = 0
    for p in range(avg_z.shape[0]):
        if keep[p]:
            values[i], idx[i] = -avg_z[p], p
            i += 1
    _to_keys(keys)
    return keys, idx


@nb.njit(cache=True, nogil=True)
def _depth_keys(vertices: np.ndarray, polygons: np.ndarray, counts: np.ndarray,
                keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_sort_keys` of :func:`average_z`, for the kept polygons.

    Every polygon's key is written and the write position moves on only for a kept
    one: no branch on ``keep``, which a cull leaves in no pattern a CPU predicts.
    """
    n = 0
    for p in range(polygons.shape[0]):
        n += np.int64(keep[p])
    keys, idx = np.empty(n + 1, np.uint64), np.empty(n + 1, np.int64)
    values = keys.view(np.float64)  # keys stays C-contiguous (a view is typed 'A')
    i = 0
    for p in range(polygons.shape[0]):
        values[i], idx[i] = _depth_value(vertices, polygons, counts, p), p
        i += np.int64(keep[p])
    keys, idx = keys[:n], idx[:n]
    _to_keys(keys)
    return keys, idx


@nb.njit(cache=True, nogil=True)
def _radix_order(keys: np.ndarray, idx: np.ndarray, bits: int) -> np.ndarray:
    """``idx`` stably sorted by ``keys`` (consumes both arrays).

    LSD radix passes over the high 32 bits of the keys, then an insertion sort of
    each run of equal high bits by the whole key (runs are short: keys sharing their
    sign, exponent and first 20 mantissa bits).  Should the runs be long (their
    insertion work past :data:`INSERTION_WORK` moves per key), the passes over the
    low 32 bits are run as well, which sorts whatever order the keys were left in.
    Both steps are stable, so equal keys keep their order in ``idx``.
    """
    keys, idx = _radix_passes(keys, idx, bits, np.int64(HIGH_BIT))
    if _sort_runs(keys, idx, INSERTION_WORK * keys.shape[0] + 64):
        return idx
    return _radix_passes(keys, idx, bits, np.int64(0))[1]


@subroutine(nrt=True)
def _sort_runs(keys: np.ndarray, idx: np.ndarray, budget: int) -> bool:
    """Insertion-sort runs of equal high 32 bits by the whole key; False past ``budget`` moves.

    Stable (a key moves only past greater ones); on False the arrays are a
    permutation of what they were, in no promised order.
    """
    high = np.uint64(HIGH_BIT)
    start = 0
    for j in range(1, keys.shape[0]):
        k = keys[j]
        if (k >> high) != (keys[j - 1] >> high):
            start = j
            continue
        m = j
        if keys[m - 1] <= k:
            continue
        i = idx[j]
        while m > start and keys[m - 1] > k:
            keys[m] = keys[m - 1]
            idx[m] = idx[m - 1]
            m -= 1
            budget -= 1
        keys[m] = k
        idx[m] = i
        if budget < 0:
            return False
    return True


@subroutine(nrt=True)
def _radix_passes(keys: np.ndarray, idx: np.ndarray, bits: int,
                  lo_bit: int) -> tuple[np.ndarray, np.ndarray]:
    """LSD radix passes over the key bits from ``lo_bit`` up: stable by those bits.

    All digit histograms come from one read of the keys; a digit every key shares
    moves nothing and its pass is skipped.  Returns the sorted keys and indices
    (either the arrays given or two new ones).
    """
    n = keys.shape[0]
    width = 1 << bits
    mask = np.uint64(width - 1)
    passes = (64 - lo_bit + bits - 1) // bits
    hist = np.zeros((passes, width), np.int64)
    for j in range(n):
        k = keys[j]
        for d in range(passes):
            hist[d, (k >> np.uint64(lo_bit + d * bits)) & mask] += 1
    k2, i2 = np.empty(n, np.uint64), np.empty(n, np.int64)
    for d in range(passes):
        h = hist[d]
        shift = np.uint64(lo_bit + d * bits)
        if n == 0 or h[(keys[0] >> shift) & mask] == n:
            continue  # one bucket holds every key
        start = 0
        for b in range(width):
            c = h[b]
            h[b] = start
            start += c
        for j in range(n):
            k = keys[j]
            b = (k >> shift) & mask
            pos = h[b]
            h[b] = pos + 1
            k2[pos] = k
            i2[pos] = idx[j]
        keys, k2 = k2, keys
        idx, i2 = i2, idx
    return keys, idx
