"""BSP-tree occlusion: equal to the ray-cast reference where average-z sorting fails."""

import numpy as np
import pytest

from service.display import DisplaySettings
from service.primitives import torus
from service.render.mesh import Mesh
from service.render.occlusion import Visibility
from service.render.occlusion.bsp import BspCache, bsp, build_bsp, fingerprint
from service.render.occlusion.raycast import raycast
from service.render.projection import project
from service.render.raster import painter_kernel
from service.render.scene import Scene, SceneObject, Transform, euler_quaternion

UNIT = {"cols": 64, "rows": 48, "width": 64.0}  # one world unit per pixel
WIDE = DisplaySettings(zones=5, angle_deg=30.0, **UNIT)


def soup(tv):
    """Scene arrays of triangles given by their corners, shape (N, 3, 3)."""
    tv = np.asarray(tv, float)
    mesh = Mesh.from_triangles(tv.reshape(-1, 3), np.arange(tv.size // 3).reshape(-1, 3))
    return Scene([SceneObject(mesh)]).flatten()


def average_z_order(arrays):
    """Triangles nearest first by average z (the depth sort BSP has to beat)."""
    zc = arrays.vertices[arrays.triangles][:, :, 2].mean(axis=1)
    return np.argsort(-zc, kind="stable")


def agreement(arrays, d, order, method):
    proj = project(arrays.vertices, d)
    ref = raycast(arrays, proj, d, order)
    vis = method(arrays, proj, d, order)
    covered = (ref.triangle >= 0) | (vis.triangle >= 0)
    return np.mean(vis.triangle[covered] == ref.triangle[covered]), vis


def painter_average_z(arrays, proj, d, order):
    """Painter's algorithm drawing in reverse average-z order, for comparison."""
    vis = Visibility.empty(d.zones, d.rows, d.cols)
    back_to_front = np.tile(order[::-1], (d.zones, 1))
    painter_kernel(proj, arrays.triangles, np.arange(arrays.triangles.shape[0]), back_to_front,
                   vis.triangle, vis.depth)
    return vis


def pinwheel():
    """Three tilted sticks, each lying over the next at their junctions: a cyclic overlap.

    Stick k runs from corner k to corner k+1 of a triangle (overhanging both ends),
    rising from z = -6 to z = +6, so at every corner the arriving stick is above
    the leaving one, and all three have the same average z.
    """
    corners = [16 * np.array([np.cos(a), np.sin(a)]) for a in np.radians([90, 210, 330])]
    tris = []
    for k in range(3):
        a, b = corners[k], corners[(k + 1) % 3]
        u = (b - a) / np.linalg.norm(b - a)
        w = np.array([-u[1], u[0]]) * 3.0
        p, q = a - 6 * u, b + 6 * u
        quad = [[*(p - w), -6], [*(q - w), 6], [*(q + w), 6], [*(p + w), -6]]
        tris += [[quad[0], quad[1], quad[2]], [quad[0], quad[2], quad[3]]]
    return soup(tris)


def crossing_pair():
    """Two triangles that pass through each other along the line x = 0."""
    a = [[-15, -12, -6], [15, -12, 6], [0, 14, 0]]  # plane z = 0.4 x
    b = [[-15, -10, 6], [0, 12, 0], [15, -10, -6]]  # plane z = -0.4 x
    return soup([a, b])


def test_matches_raycast_on_random_non_intersecting_soups():
    rng = np.random.default_rng(3)
    for _ in range(3):
        n = 30
        centres = np.column_stack(
            [rng.uniform(-24, 24, n), rng.uniform(-16, 16, n), np.arange(n) * 2.0 - n]
        )
        # corners within +-0.9 of the centre's z: slabs 2 apart never intersect
        offsets = np.column_stack(
            [rng.normal(0, 8, (n * 3, 2)), rng.uniform(-0.9, 0.9, n * 3)]
        ).reshape(n, 3, 3)
        arrays = soup(centres[:, None, :] + offsets)
        order = rng.permutation(n)  # BSP must not depend on the order being right
        share, _ = agreement(arrays, WIDE, order, bsp)
        assert share > 0.999


def test_matches_raycast_on_a_non_convex_mesh():
    obj = SceneObject(torus(12.0, 4.0, 24, 10),
                      transform=Transform(orientation=euler_quaternion(0.3, 1.1, 0.2)))
    arrays = Scene([obj]).flatten()
    share, vis = agreement(arrays, WIDE, average_z_order(arrays), bsp)
    assert share > 0.999
    assert vis.stats["splits"] > 0 and vis.stats["fragments"] > arrays.triangles.shape[0]


def test_resolves_cyclic_overlap_where_average_z_fails():
    arrays = pinwheel()
    order = average_z_order(arrays)
    proj = project(arrays.vertices, WIDE)
    ref = raycast(arrays, proj, WIDE, order)
    painted = painter_average_z(arrays, proj, WIDE, order)
    assert np.sum(painted.triangle // 2 != ref.triangle // 2) > 20  # the sort is wrong
    share, vis = agreement(arrays, WIDE, order, bsp)
    assert share > 0.999
    assert np.sum(vis.triangle // 2 != ref.triangle // 2) <= 2


def test_resolves_interpenetrating_triangles_by_splitting():
    arrays = crossing_pair()
    order = average_z_order(arrays)
    proj = project(arrays.vertices, WIDE)
    ref = raycast(arrays, proj, WIDE, order)
    painted = painter_average_z(arrays, proj, WIDE, order)
    assert np.sum(painted.triangle != ref.triangle) > 20  # one triangle always on top
    share, vis = agreement(arrays, WIDE, order, bsp)
    assert vis.stats["splits"] == 1
    # only pixels right at the intersection line may differ
    assert share > 0.99
    assert np.allclose(vis.depth[vis.triangle >= 0], ref.depth[vis.triangle >= 0], atol=0.5)
    for k in range(WIDE.zones):  # each triangle is in front on its own side of x = 0
        seen = set(np.unique(vis.triangle[k])) - {-1}
        assert seen == {0, 1}


def test_fragments_of_a_split_triangle_keep_the_original_id():
    arrays = crossing_pair()
    tree = build_bsp(arrays.vertices, arrays.triangles, np.array([1, 0]))
    assert tree.stats["splits"] == 1 and tree.stats["fragments"] >= 3
    assert set(tree.frag_ids.tolist()) == {0, 1}
    for corners, tid in zip(tree.frag_vertices, tree.frag_ids, strict=True):
        a, b, c = arrays.vertices[arrays.triangles[tid]]
        n = np.cross(b - a, c - a)
        n /= np.linalg.norm(n)
        assert np.allclose((corners - a) @ n, 0.0, atol=1e-9)  # lies in its parent's plane
    split_id = np.bincount(tree.frag_ids).argmax()
    total = sum(
        np.linalg.norm(np.cross(t[1] - t[0], t[2] - t[0]))
        for t, i in zip(tree.frag_vertices, tree.frag_ids, strict=True)
        if i == split_id
    )
    a, b, c = arrays.vertices[arrays.triangles[split_id]]
    assert total == pytest.approx(np.linalg.norm(np.cross(b - a, c - a)))  # area kept


def test_tree_is_reused_until_the_geometry_changes():
    arrays = pinwheel()
    order = average_z_order(arrays)
    cache = BspCache()
    first = bsp(arrays, None, WIDE, order, cache)
    again = bsp(arrays, None, WIDE, order, cache)
    assert first.stats["rebuilt"] and not again.stats["rebuilt"] and cache.builds == 1
    tree = cache.tree
    assert np.array_equal(first.triangle, again.triangle)
    moved = soup(arrays.vertices[arrays.triangles] + np.array([1.0, 0.0, 0.0]))
    assert bsp(moved, None, WIDE, order, cache).stats["rebuilt"] and cache.builds == 2
    assert bsp(moved, None, WIDE, order[:-1], cache).stats["rebuilt"] and cache.builds == 3
    # a tree passed directly is used only if it was built from this geometry
    assert not bsp(arrays, None, WIDE, order, tree).stats["rebuilt"]
    assert bsp(moved, None, WIDE, order, tree).stats["rebuilt"]
    assert tree.key == fingerprint(arrays.vertices, arrays.triangles, order)


def test_empty_order_gives_an_empty_buffer():
    arrays = crossing_pair()
    vis = bsp(arrays, None, WIDE, np.zeros(0, np.int64))
    assert np.all(vis.triangle == -1) and np.all(np.isinf(vis.depth))
    assert vis.stats["nodes"] == 0
