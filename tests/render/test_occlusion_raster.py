"""Z-buffer and run-length occlusion on scenes whose answer is known."""

import numpy as np

from service.display import DisplaySettings
from service.render.cull import CullSettings, cull
from service.render.depth_sort import average_z, sort_polygons, triangle_order
from service.render.mesh import Mesh
from service.render.occlusion.runlength import runlength
from service.render.occlusion.zbuffer import zbuffer
from service.render.projection import project
from service.render.scene import Scene, SceneObject


def square(cx: float, cy: float, z: float, half: float) -> Mesh:
    v = [
        [cx - half, cy - half, z],
        [cx + half, cy - half, z],
        [cx + half, cy + half, z],
        [cx - half, cy + half, z],
    ]
    return Mesh.from_polygons(np.array(v), [[0, 1, 2, 3]])


def prepare(meshes, display):
    arrays = Scene([SceneObject(m) for m in meshes]).flatten()
    proj = project(arrays.vertices, display)
    keep, _ = cull(arrays.normals, display, CullSettings("modified"))
    order = triangle_order(
        sort_polygons(average_z(arrays.vertices, arrays.polygons, arrays.counts), keep),
        arrays.triangle_polygon,
    )
    return arrays, proj, order


def test_square_covers_its_area_exactly():
    d = DisplaySettings(zones=1, angle_deg=0, cols=64, rows=64, width=2.0)
    arrays, proj, order = prepare([square(0, 0, 0, 0.5)], d)
    for method in (zbuffer, runlength):
        vis = method(arrays, proj, d, order)
        # 1.0 x 1.0 world units at 32 px per unit: 32 x 32 pixels, no seam on the diagonal
        assert (vis.triangle[0] >= 0).sum() == 32 * 32
        assert np.allclose(vis.depth[0][vis.triangle[0] >= 0], 0.0)
        assert np.isinf(vis.depth[0][vis.triangle[0] < 0]).all()


def test_nearer_square_wins_and_shifts_with_zone():
    d = DisplaySettings(zones=5, angle_deg=16, cols=80, rows=40, width=2.0)
    near, far = square(0, 0, 0.3, 0.3), square(0, 0, -0.3, 0.5)
    arrays, proj, order = prepare([far, near], d)
    zb = zbuffer(arrays, proj, d, order)
    rl = runlength(arrays, proj, d, order)
    assert np.array_equal(zb.triangle, rl.triangle)
    assert rl.stats["inconsistent_pixels"] == 0
    near_poly = arrays.triangle_polygon[zb.triangle] == 1
    centres = [np.nonzero(near_poly[z].any(axis=0))[0].mean() for z in range(5)]
    # z > 0: the image moves left (toward -x) as the zone moves right
    assert all(a >= b for a, b in zip(centres, centres[1:], strict=False))
    assert centres[0] > centres[-1]
    shift = (centres[0] - centres[4]) * d.pixel_size
    expected = 0.3 * (np.tan(d.zone_angles()[4]) - np.tan(d.zone_angles()[0]))
    assert abs(shift - expected) < 2 * d.pixel_size


def test_runlength_reports_a_wrong_sort():
    # Two crossing quads: average z says A is in front, but B pokes through it.
    d = DisplaySettings(zones=1, angle_deg=0, cols=40, rows=40, width=2.0)
    a = Mesh.from_polygons(
        np.array([[-0.8, -0.8, 0.1], [0.8, -0.8, 0.1], [0.8, 0.8, 0.1], [-0.8, 0.8, 0.1]]),
        [[0, 1, 2, 3]],
    )
    b = Mesh.from_polygons(
        np.array([[-0.8, -0.8, -0.5], [0.8, -0.8, 0.5], [0.8, 0.8, 0.5], [-0.8, 0.8, -0.5]]),
        [[0, 1, 2, 3]],
    )
    arrays, proj, order = prepare([a, b], d)
    rl = runlength(arrays, proj, d, order)
    zb = zbuffer(arrays, proj, d, order)
    assert rl.stats["inconsistent_pixels"] > 0
    wrong = (rl.triangle != zb.triangle).sum()
    assert wrong == rl.stats["inconsistent_pixels"]


def test_back_faces_hidden_by_front_faces():
    # A closed cube: whatever the cull keeps, nothing behind the front shows through.
    d = DisplaySettings(zones=5, angle_deg=30, cols=60, rows=60, width=2.0)
    v = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
    faces = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    cube = Mesh.from_polygons(v, faces)
    arrays, proj, order = prepare([cube], d)
    zb = zbuffer(arrays, proj, d, order)
    seen = arrays.triangle_polygon[zb.triangle[zb.triangle >= 0]]
    normals = arrays.normals[seen]
    assert (normals[:, 2] > 0).any()
    for z in range(5):
        pz = arrays.triangle_polygon[zb.triangle[z][zb.triangle[z] >= 0]]
        assert (arrays.normals[pz] @ d.view_vectors()[z] > 0).all()
