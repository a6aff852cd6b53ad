"""Per-pixel ray casting, the occlusion reference, against answers known in closed form."""

import numpy as np
import pytest

from service.display import DisplaySettings
from service.render.mesh import Mesh
from service.render.occlusion.raycast import raycast
from service.render.projection import project
from service.render.scene import Scene, SceneObject

# one world unit per pixel: column c's centre is at X = c + 0.5 - 32, row r's at Y = 23.5 - r
UNIT = {"cols": 64, "rows": 48, "width": 64.0}


def quad_mesh(x0, x1, y0, y1, z):
    """A rectangle at depth z facing +z, as two triangles (0: lower right, 1: upper left)."""
    v = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], float)
    return Mesh.from_triangles(v, [[0, 1, 2], [0, 2, 3]])


def arrays_of(*meshes):
    return Scene([SceneObject(m) for m in meshes]).flatten()


def pixel_centres(d):
    cols = np.arange(d.cols) + 0.5 - d.width / 2
    rows = d.height / 2 - (np.arange(d.rows) + 0.5)
    return np.meshgrid(cols, rows)  # X (R, C), Y (R, C)


def cast(arrays, d, order=None):
    order = np.arange(arrays.triangles.shape[0]) if order is None else np.asarray(order)
    return raycast(arrays, project(arrays.vertices, d), d, order)


def test_nearer_quad_wins_in_every_zone_and_shifts_with_parallax():
    d = DisplaySettings(zones=5, angle_deg=16.0, **UNIT)
    near, far = quad_mesh(-8, 8, -8, 8, 20.0), quad_mesh(-4, 12, -6, 6, -20.0)
    vis = cast(arrays_of(near, far), d)
    X, Y = pixel_centres(d)
    centroids = []
    for k, t in enumerate(d.shears()):
        # a point at depth z lands at X = x - z t: the near quad moves left when t > 0
        in_near = (X >= -8 - 20 * t) & (X < 8 - 20 * t) & (Y > -8) & (Y <= 8)
        in_far = (X >= -4 + 20 * t) & (X < 12 + 20 * t) & (Y > -6) & (Y <= 6)
        quad = np.where(vis.triangle[k] >= 0, vis.triangle[k] // 2, -1)
        expected = np.where(in_near, 0, np.where(in_far, 1, -1))
        assert np.array_equal(quad, expected), f"zone {k}"
        assert np.all(vis.depth[k][quad == 0] == -20.0)
        assert np.all(vis.depth[k][quad == 1] == 20.0)
        assert np.all(np.isinf(vis.depth[k][quad == -1]))
        centroids.append(X[quad == 0].mean())
    assert np.all(np.diff(centroids) < 0)  # theta grows with k, so the near quad moves left
    assert centroids[0] > 0 > centroids[-1]
    assert centroids[2] == pytest.approx(0.0)


def test_square_with_edges_on_pixel_centres_is_half_open():
    d = DisplaySettings(zones=1, angle_deg=0.0, **UNIT)
    # edges and the shared diagonal run exactly through pixel centres
    vis = cast(arrays_of(quad_mesh(-10.5, 9.5, -9.5, 10.5, 0.0)), d)
    X, Y = pixel_centres(d)
    covered = vis.triangle[0] >= 0
    assert covered.sum() == 400  # area / s^2: each centre on an edge counted once
    # left and top edges are in, right and bottom edges out (as in the raster rule)
    assert np.array_equal(covered, (X >= -10.5) & (X < 9.5) & (Y > -9.5) & (Y <= 10.5))
    on_diagonal = np.isclose(Y - X, 1.0) & covered
    assert on_diagonal.sum() == 19
    assert set(np.unique(vis.triangle[0][covered])) == {0, 1}


@pytest.mark.parametrize("z", [0.0, 3.0, -7.25])
def test_square_pixel_count_equals_area_in_every_zone(z):
    d = DisplaySettings(zones=4, angle_deg=30.0, **UNIT)
    vis = cast(arrays_of(quad_mesh(-7.3, 12.7, -5.1, 9.9, z)), d)
    counts = (vis.triangle >= 0).sum(axis=(1, 2))
    assert np.all(counts == 20 * 15)  # any 20 x 15 rectangle holds 300 pixel centres
    assert np.allclose(vis.depth[vis.triangle >= 0], -z)


def test_only_triangles_in_order_are_candidates():
    d = DisplaySettings(zones=2, **UNIT)
    arrays = arrays_of(quad_mesh(-8, 8, -8, 8, 5.0), quad_mesh(-12, 12, -12, 12, -5.0))
    vis = cast(arrays, d, order=[2, 3])  # the near quad (0, 1) was culled
    assert set(np.unique(vis.triangle)) == {-1, 2, 3}
    assert np.all(vis.depth[vis.triangle >= 0] == 5.0)


def test_empty_order_gives_an_empty_buffer():
    d = DisplaySettings(zones=3, **UNIT)
    vis = cast(arrays_of(quad_mesh(-8, 8, -8, 8, 5.0)), d, order=np.zeros(0, np.int64))
    assert vis.triangle.shape == (3, 48, 64) and np.all(vis.triangle == -1)
    assert np.all(np.isinf(vis.depth))


def brute_force(tv, d):
    """Nearest triangle per zone and pixel by testing every triangle everywhere (numpy)."""
    X, Y = pixel_centres(d)
    out = np.full((d.zones, d.rows, d.cols), -1)
    for k, t in enumerate(d.shears()):
        best = np.full(X.shape, -np.inf)
        for i, (a, b, c) in enumerate(tv):
            P = [np.array([p[0] - p[2] * t, p[1]]) for p in (a, b, c)]
            e = [(P[j][0] - X) * (P[(j + 1) % 3][1] - Y) - (P[j][1] - Y) * (P[(j + 1) % 3][0] - X)
                 for j in range(3)]
            inside = ((e[0] > 0) & (e[1] > 0) & (e[2] > 0)) | ((e[0] < 0) & (e[1] < 0) & (e[2] < 0))
            n = np.cross(b - a, c - a)
            z = (n @ a - n[0] * X - n[1] * Y) / (n[0] * t + n[2])
            win = inside & (z > best)
            best[win], out[k][win] = z[win], i
    return out


def test_matches_brute_force_on_a_random_soup_across_tiles():
    rng = np.random.default_rng(7)
    d = DisplaySettings(zones=3, angle_deg=20.0, cols=72, rows=40, width=72.0)
    centres = rng.uniform([-36, -20, -15], [36, 20, 15], (40, 3))
    tv = centres[:, None, :] + rng.normal(0, 8, (40, 3, 3))  # sizes up to a few tiles
    arrays = arrays_of(Mesh.from_triangles(tv.reshape(-1, 3), np.arange(120).reshape(40, 3)))
    vis = cast(arrays, d)
    ref = brute_force(tv, d)
    # the two differ only where a centre lies exactly on an edge (measure zero here)
    assert np.mean(vis.triangle == ref) > 0.999


def test_geometry_far_off_screen_is_ignored_and_huge_triangles_still_cover():
    d = DisplaySettings(zones=2, **UNIT)
    far_off = quad_mesh(1e12, 2e12, 1e12, 2e12, 0.0)
    huge = quad_mesh(-1e9, 1e9, -1e9, 1e9, -3.0)
    vis = cast(arrays_of(far_off, huge), d)
    assert set(np.unique(vis.triangle)) <= {2, 3}
    assert np.all(vis.depth == 3.0)
