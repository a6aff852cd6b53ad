"""The one-pass multi-zone z-buffer equals the per-zone kernel bit for bit."""

import numpy as np
import pytest

from service.builtin_scenes import builtin_scene
from service.display import DisplaySettings
from service.render.cull import CullSettings, cull, zone_mask
from service.render.depth_sort import NO_TIE_SOURCE, average_z, sort_polygons, triangle_order
from service.render.light import mark_shown
from service.render.occlusion.zbuffer import rows_shared, zbuffer
from service.render.projection import project, project_tables
from service.render.raster import row_bands, shared_rows, triangle_setup, zbuffer_zones_kernel


def inputs(name: str, display: DisplaySettings, per_zone: bool = True):
    arrays = builtin_scene(name).flatten()
    proj = project(arrays.vertices, display)
    settings = CullSettings(per_zone=per_zone)
    keep, _ = cull(arrays.normals, display, settings)
    order = triangle_order(
        sort_polygons(average_z(arrays.vertices, arrays.polygons, arrays.counts), keep),
        arrays.triangle_polygon,
    )
    draw = zone_mask(
        arrays.triangle_polygon, arrays.normals, arrays.polygon_closed, display, settings
    )
    return arrays, proj, order, draw


def assert_same(a, b):
    assert np.array_equal(a.triangle, b.triangle)
    assert np.array_equal(a.depth, b.depth)  # +inf == +inf; no NaN is ever stored


@pytest.mark.parametrize("name", ["game", "cyclic", "threaded", "sphere-torus", "demo"])
@pytest.mark.parametrize(
    ("zones", "angle"), [(1, 0.0), (2, 16.0), (5, 16.0), (5, 60.0), (9, 32.0), (16, 60.0)]
)
def test_one_pass_equals_per_zone(name, zones, angle):
    d = DisplaySettings(zones=zones, angle_deg=angle, cols=160, rows=120)
    arrays, proj, order, draw = inputs(name, d)
    one = zbuffer(arrays, proj, d, order, draw)
    per_zone = zbuffer(arrays, proj, d, order, draw, shared=False)
    assert (one.triangle >= 0).any()
    assert_same(one, per_zone)


@pytest.mark.parametrize("rows", [1, 7, 240])
def test_one_pass_at_full_size_and_odd_heights(rows):
    d = DisplaySettings(zones=5, angle_deg=16.0, cols=320, rows=rows)
    arrays, proj, order, draw = inputs("game", d, per_zone=False)
    assert_same(
        zbuffer(arrays, proj, d, order, draw), zbuffer(arrays, proj, d, order, draw, shared=False)
    )


def test_rows_that_differ_between_zones_take_the_per_zone_kernel():
    d = DisplaySettings(zones=3, angle_deg=16.0, cols=80, rows=60)
    arrays, proj, order, draw = inputs("threaded", d)
    assert rows_shared(proj)
    proj = proj.copy()
    proj[1, :, 1] += 3.0  # not a projection project() makes: zone 1 shifted down 3 rows
    assert not rows_shared(proj)
    got = zbuffer(arrays, proj, d, order, draw)
    want = zbuffer(arrays, proj, d, order, draw, shared=False)
    assert_same(got, want)
    assert not np.array_equal(got.triangle[1], got.triangle[0])


def test_depths_that_differ_between_zones_take_the_per_zone_kernel():
    d = DisplaySettings(zones=3, angle_deg=16.0, cols=80, rows=60)
    arrays, proj, order, draw = inputs("threaded", d)
    proj = proj.copy()
    proj[2, :, 2] = -proj[2, :, 2]  # zone 2 seen from behind: the one-pass kernel can't
    assert not rows_shared(proj)
    got = zbuffer(arrays, proj, d, order, draw)
    assert_same(got, zbuffer(arrays, proj, d, order, draw, shared=False))
    assert not np.array_equal(got.triangle[2], got.triangle[1])


def test_shared_rows_match_the_setup_of_every_zone():
    d = DisplaySettings(zones=5, angle_deg=60.0, cols=160, rows=120)
    arrays, proj, order, _ = inputs("game", d)
    r_first, r_last = shared_rows(proj, arrays.triangles, order, d.rows)
    for z in range(d.zones):
        for i in range(0, order.size, 7):
            t = order[i]
            st = triangle_setup(*(proj[z, arrays.triangles[t, k]] for k in range(3)), d.rows)
            if st[0]:
                assert (st[1], st[2]) == (r_first[i], r_last[i])


def test_non_finite_vertices_are_skipped_as_the_setup_skips_them():
    d = DisplaySettings(zones=5, angle_deg=16.0, cols=80, rows=60)
    arrays, proj, order, draw = inputs("threaded", d)
    proj = proj.copy()
    proj[:, arrays.triangles[order[0], 0], :] = np.nan
    proj[:, arrays.triangles[order[1], 1], 1] = np.inf
    assert_same(
        zbuffer(arrays, proj, d, order, draw), zbuffer(arrays, proj, d, order, draw, shared=False)
    )


@pytest.mark.parametrize(("rows", "threads"), [(1, 1), (1, 4), (7, 2), (120, 1), (240, 2)])
def test_row_bands_cover_every_row_once(rows, threads):
    bands = row_bands(rows, threads)
    covered = np.concatenate([np.arange(a, b + 1) for a, b in bands])
    assert np.array_equal(np.sort(covered), np.arange(rows))


@pytest.mark.parametrize(("threads", "per_thread"), [(1, 3), (2, 1), (3, 5), (4, 60)])
def test_any_banding_gives_the_same_buffers(threads, per_thread):
    d = DisplaySettings(zones=5, angle_deg=45.0, cols=160, rows=120)
    arrays, proj, order, draw = inputs("game", d)
    want = zbuffer(arrays, proj, d, order, draw, shared=False)
    tri = np.empty((d.zones, d.rows, d.cols), np.int32)
    depth = np.empty((d.zones, d.rows, d.cols), np.float32)
    bands = row_bands(d.rows, threads, per_thread)
    shown = np.zeros((d.zones, arrays.n_polygons), bool)
    zbuffer_zones_kernel(
        proj, arrays.triangles, order, np.ascontiguousarray(draw.T), bands, tri, depth,
        arrays.triangle_polygon, shown, np.empty((0, d.zones)), np.empty((0, 2)), threads,
        NO_TIE_SOURCE,
    )
    assert np.array_equal(tri, want.triangle)
    assert np.array_equal(depth, want.depth)
    assert np.array_equal(shown, mark_shown(tri, arrays.triangle_polygon, arrays.n_polygons))


@pytest.mark.parametrize("name", ["game", "threaded", "demo"])
@pytest.mark.parametrize("zones", [1, 5])
def test_the_polygons_shown_are_found_while_drawing(name, zones):
    d = DisplaySettings(zones=zones, angle_deg=16.0, cols=160, rows=120)
    arrays, proj, order, draw = inputs(name, d)
    vis = zbuffer(arrays, proj, d, order, draw, item=arrays.triangle_polygon,
                  n_items=arrays.n_polygons)
    want = mark_shown(vis.triangle, arrays.triangle_polygon, arrays.n_polygons)
    assert want.any() and np.array_equal(vis.shown, want)
    assert zbuffer(arrays, proj, d, order, draw).shown is None  # not asked for
    by_triangle = zbuffer(arrays, proj, d, order, draw_t=np.ascontiguousarray(draw.T))
    assert_same(by_triangle, vis)
    assert zbuffer(arrays, proj, d, order, draw, shared=False, item=arrays.triangle_polygon,
                   n_items=arrays.n_polygons).shown is None  # the per-zone kernel: not found


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_corners_on_one_row_whose_x_order_differs_between_zones(seed):
    # corners on a few shared rows at scattered depths: across 60 degrees the shear
    # swaps the x order of corners on the same row, so each zone orders them itself
    from types import SimpleNamespace

    d = DisplaySettings(zones=7, angle_deg=60.0, cols=64, rows=48)
    rng = np.random.default_rng(seed)
    v = np.column_stack([
        rng.uniform(-0.5, 0.5, 600),
        rng.choice(np.linspace(-0.3, 0.3, 5), 600),
        rng.uniform(-0.6, 0.6, 600),
    ])
    tris = rng.integers(0, 600, (400, 3)).astype(np.int64)  # the pipeline's dtype: no new compile
    proj = project(v, d)
    swapped = 0
    for a, b in ((0, 1), (1, 2), (0, 2)):
        same_row = proj[0, tris[:, a], 1] == proj[0, tris[:, b], 1]
        left = proj[:, tris[:, a], 0] < proj[:, tris[:, b], 0]
        swapped += int((same_row & left.any(axis=0) & ~left.all(axis=0)).sum())
    assert swapped > 10
    order = np.arange(tris.shape[0], dtype=np.int64)
    draw = np.ones((d.zones, tris.shape[0]), bool)
    scene = SimpleNamespace(triangles=tris)
    want = zbuffer(scene, proj, d, order, draw, shared=False)
    assert_same(zbuffer(scene, proj, d, order, draw), want)


def test_the_shared_set_up_equals_each_zones_own_bit_for_bit():
    # the per-triangle set-up the one-pass kernel shares between zones, against
    # setup_xyz run in each zone: same corners, same depth plane, to the last bit
    # (the buffers alone would hide a last-bit difference behind the float32 store)
    from service.render.raster import _setup_zones, setup_xyz, vertex_tables

    d = DisplaySettings(zones=7, angle_deg=60.0, cols=64, rows=48)
    rng = np.random.default_rng(3)
    v = np.column_stack([
        rng.uniform(-0.5, 0.5, 300),
        rng.choice(np.linspace(-0.3, 0.3, 4), 300),  # many corners share a row
        rng.uniform(-0.6, 0.6, 300),
    ])
    proj = project(v, d)
    tables = vertex_tables(proj)
    xs, plane = np.zeros((2, 3, d.zones)), np.zeros((2, 3, d.zones))
    ties = 0
    tris = rng.integers(0, 300, (200, 3)).astype(np.int64)
    draw_t = np.ones((tris.shape[0], d.zones), bool)
    for t, tri in enumerate(tris):
        j = t % 2  # the table row written
        ay, by, cy, any_live = _setup_zones(tables, tris, t, draw_t, xs, plane, j)
        live = (xs[j] != 0.0).any(axis=0)  # a zone not drawn in has every x 0
        assert any_live == live.any()
        ties += len({proj[0, k, 1] for k in tri}) < 3
        for z in range(d.zones):
            st = setup_xyz(*proj[z, tri].ravel(), d.rows)
            assert live[z] == st[0]
            if st[0]:
                assert (st[4], st[6], st[8]) == (ay, by, cy)
                assert (st[3], st[5], st[7]) == tuple(xs[j, :, z])
                assert (st[9], st[10], st[11]) == tuple(plane[j, :, z])
    assert ties > 20


@pytest.mark.parametrize("zones", [1, 5])
def test_the_projection_by_vertex_equals_the_kernels_own_tables(zones):
    from service.render.raster import vertex_tables

    d = DisplaySettings(zones=zones, angle_deg=16.0, cols=96, rows=72)
    v = builtin_scene("game").flatten().vertices
    proj, xz, yd = project_tables(v, d)
    assert np.array_equal(proj, project(v, d))
    if zones == 1:  # one zone's z-buffer reads proj itself
        assert xz.shape == (0, 1) and yd.shape == (0, 2)
    else:
        want_xz, want_yd = vertex_tables(proj)
        assert np.array_equal(xz, want_xz) and np.array_equal(yd, want_yd)
    assert project_tables(v, d, tables=False)[1].shape == (0, zones)


@pytest.mark.parametrize("zones", [1, 5])
@pytest.mark.parametrize("broken", [False, True])
def test_the_z_buffer_given_the_tables_equals_the_per_zone_kernel(zones, broken):
    # given the tables, the one-pass kernel runs without checking that rows are
    # shared: also where vertices are not finite (which that check would send to the
    # per-zone kernel)
    d = DisplaySettings(zones=zones, angle_deg=16.0, cols=160, rows=120)
    arrays, _, order, draw = inputs("game", d)
    verts = arrays.vertices.copy()
    if broken:
        verts[arrays.triangles[order[0], 0]] = np.nan
        verts[arrays.triangles[order[1], 1], 1] = np.inf
        verts[arrays.triangles[order[2], 2], 2] = -np.inf
    proj, xz, yd = project_tables(verts, d)
    want = zbuffer(arrays, proj, d, order, draw, shared=False)
    got = zbuffer(arrays, proj, d, order, draw_t=np.ascontiguousarray(draw.T),
                  item=arrays.triangle_polygon, n_items=arrays.n_polygons, tables=(xz, yd))
    assert (got.triangle >= 0).any()
    assert_same(got, want)
    assert np.array_equal(got.shown, mark_shown(got.triangle, arrays.triangle_polygon,
                                                 arrays.n_polygons))


def covers_each_row_once(bands, rows):
    assert (bands[:, 0] <= bands[:, 1]).all()
    covered = np.concatenate([np.arange(a, b + 1) for a, b in bands])
    assert np.array_equal(covered, np.arange(rows))  # top to bottom, each row once


@pytest.mark.parametrize(("rows", "n"), [(1, 1), (1, 4), (3, 3), (7, 2), (240, 2), (240, 16)])
@pytest.mark.parametrize("layout", ["none", "one row", "last row", "spread"])
def test_balanced_bands_cover_every_row_once(rows, n, layout):
    from service.render.raster import balanced_bands

    rng = np.random.default_rng(rows * n)
    if layout == "none":  # no triangle has a row: the bands split the rows evenly
        r_first, r_last = np.array([5, 0], np.int64), np.array([4, -1], np.int64)
    elif layout in ("one row", "last row"):  # all the work on one row
        r = 0 if layout == "one row" else rows - 1
        r_first = r_last = np.full(50, r, np.int64)
    else:
        r_first = rng.integers(0, rows, 200)
        r_last = np.minimum(r_first + rng.integers(0, 4, 200), rows - 1)
    bands = balanced_bands(r_first, r_last, rows, n, 1)
    assert bands.shape == (min(n, rows), 2)
    covers_each_row_once(bands, rows)


def test_balanced_bands_share_the_game_scenes_rows():
    from service.render.raster import balanced_bands

    d = DisplaySettings(zones=5, angle_deg=16.0, cols=320, rows=240)
    arrays, proj, order, _ = inputs("game", d)
    r_first, r_last = shared_rows(proj, arrays.triangles, order, d.rows)
    work = np.zeros(d.rows)
    for a, b in zip(r_first, r_last, strict=True):
        work[a : b + 1] += 1
    bands = balanced_bands(r_first, r_last, d.rows, 2, 0)
    share = work[: bands[0, 1] + 1].sum() / work.sum()
    assert 0.48 <= share <= 0.52  # fixed interleaved bands gave one thread 0.57-0.63


@pytest.mark.parametrize("setup", [0, 3, 40])
def test_balanced_bands_count_each_triangles_set_up(setup):
    from service.render.raster import balanced_bands

    # many small triangles at the top (the far scene), a few tall ones below
    r_first = np.concatenate([np.arange(0, 60) % 30, np.full(4, 40)]).astype(np.int64)
    r_last = np.concatenate([np.arange(0, 60) % 30, np.full(4, 239)]).astype(np.int64)
    work = np.full(240, 2, np.int64)  # base
    for a, b in zip(r_first, r_last, strict=True):
        work[a : b + 1] += 1
        work[a] += setup
    cum = np.cumsum(work)
    cut = int(np.searchsorted(cum, cum[-1] // 2))  # the first row reaching half the work
    bands = balanced_bands(r_first, r_last, 240, 2, 2, setup)
    assert bands.tolist() == [[0, cut], [cut + 1, 239]]
    if setup:  # the set-ups draw the cut up the screen, toward the small triangles
        assert cut < balanced_bands(r_first, r_last, 240, 2, 2, 0)[0, 1]


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("zones", [1, 5])
def test_the_kernels_own_bands_give_the_same_buffers(threads, zones):
    import numba as nb

    from service.render.raster import no_bands

    d = DisplaySettings(zones=zones, angle_deg=16.0, cols=160, rows=120)
    arrays, proj, order, draw = inputs("game", d)
    want = zbuffer(arrays, proj, d, order, draw, shared=False)
    tri = np.empty((d.zones, d.rows, d.cols), np.int32)
    depth = np.empty((d.zones, d.rows, d.cols), np.float32)
    shown = np.zeros((d.zones, arrays.n_polygons), bool)
    before = nb.get_num_threads()
    nb.set_num_threads(min(threads, nb.config.NUMBA_NUM_THREADS))
    try:
        zbuffer_zones_kernel(
            proj, arrays.triangles, order, np.ascontiguousarray(draw.T), no_bands(), tri,
            depth, arrays.triangle_polygon, shown, np.empty((0, d.zones)), np.empty((0, 2)),
            nb.get_num_threads(), NO_TIE_SOURCE,
        )
    finally:
        nb.set_num_threads(before)
    assert np.array_equal(tri, want.triangle) and np.array_equal(depth, want.depth)
    assert np.array_equal(shown, mark_shown(tri, arrays.triangle_polygon, arrays.n_polygons))


@pytest.mark.parametrize("name", ["game", "cyclic", "threaded", "sphere-torus", "demo"])
@pytest.mark.parametrize("zones", [2, 5])
def test_the_polygons_shown_drawn_far_to_near_in_many_bands(name, zones):
    # the several-zone kernel marks from how many pixels each triangle holds at the
    # end: drawn farthest first, most pixels are taken from a triangle that held them
    d = DisplaySettings(zones=zones, angle_deg=32.0, cols=160, rows=120)
    arrays, proj, order, draw = inputs(name, d)
    order = np.ascontiguousarray(order[::-1])
    want = zbuffer(arrays, proj, d, order, draw, shared=False)
    for threads, per_thread in ((1, 1), (3, 4)):
        tri = np.empty((d.zones, d.rows, d.cols), np.int32)
        depth = np.empty((d.zones, d.rows, d.cols), np.float32)
        shown = np.zeros((d.zones, arrays.n_polygons), bool)
        zbuffer_zones_kernel(
            proj, arrays.triangles, order, np.ascontiguousarray(draw.T),
            row_bands(d.rows, threads, per_thread), tri, depth, arrays.triangle_polygon,
            shown, np.empty((0, d.zones)), np.empty((0, 2)), threads, NO_TIE_SOURCE,
        )
        assert np.array_equal(tri, want.triangle) and np.array_equal(depth, want.depth)
        want_shown = mark_shown(tri, arrays.triangle_polygon, arrays.n_polygons)
        assert want_shown.any() and np.array_equal(shown, want_shown)


def test_a_prefetch_reads_nothing_and_any_row_is_safe():
    import numba as nb

    from service.render.raster import _prefetch_row

    @nb.njit
    def fetch_rows(a, rows):
        for r in rows:
            _prefetch_row(a, r)
        return a.sum()

    a = np.arange(12.0).reshape(4, 3)
    assert fetch_rows(a, np.array([0, 3, 4, 1000, -7], np.int64)) == 66.0  # past the ends too


def _tied_triangles(seed: int, n: int = 300):
    """Triangles on a few planes of constant depth, some nudged by less than a float32
    step there: exact ties and near ones (two depths rounding to one float32)."""
    rng = np.random.default_rng(seed)
    centre = rng.uniform(-0.4, 0.4, (n, 1, 2))
    xy = centre + rng.uniform(-0.25, 0.25, (n, 3, 2))
    z = rng.choice([-0.25, 0.0, 0.5], (n, 1)) + rng.choice([0.0, 1e-9, -1e-9, 3e-8], (n, 3))
    v = np.concatenate([xy, z[..., None]], axis=2).reshape(-1, 3)
    tris = np.arange(3 * n, dtype=np.int64).reshape(n, 3)
    return v, tris


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("zones", [1, 5])
def test_the_depth_key_gives_the_depth_orders_pixels_drawn_in_any_order(seed, zones):
    from types import SimpleNamespace

    from service.render.depth_sort import depth_order, kept_triangles, tie_source

    d = DisplaySettings(zones=zones, angle_deg=32.0, cols=80, rows=60)
    v, tris = _tied_triangles(seed)
    counts = np.full(tris.shape[0], 3, np.int64)
    poly = np.arange(tris.shape[0], dtype=np.int64)
    keep = np.random.default_rng(seed).random(tris.shape[0]) < 0.9
    order = kept_triangles(poly, keep)
    key = tie_source(v, tris, counts, poly)
    sorted_ = depth_order(v, tris, counts, poly, keep)
    proj = project(v, d)
    scene = SimpleNamespace(triangles=tris)
    draw = np.ones((d.zones, tris.shape[0]), bool)
    want = zbuffer(scene, proj, d, sorted_, draw, shared=False)  # the sorted order, no key
    rng = np.random.default_rng(seed + 10)
    for drawn in (order, order[::-1], rng.permutation(order), sorted_):
        drawn = np.ascontiguousarray(drawn)
        for shared in (True, False):
            assert_same(zbuffer(scene, proj, d, drawn, draw, shared=shared, key=key), want)
    # without the key the order drawn decides: reversed, the pixels differ
    assert not np.array_equal(zbuffer(scene, proj, d, np.ascontiguousarray(sorted_[::-1]),
                                      draw).triangle, want.triangle)


@pytest.mark.parametrize("name", ["game", "cyclic", "threaded", "demo"])
@pytest.mark.parametrize("zones", [1, 5])
def test_the_key_in_index_order_equals_the_sorted_draw_on_the_scenes(name, zones):
    from service.render.depth_sort import kept_triangles, tie_source

    d = DisplaySettings(zones=zones, angle_deg=16.0, cols=160, rows=120)
    arrays, proj, order, draw = inputs(name, d)
    keep, _ = cull(arrays.normals, d, CullSettings())
    index_order = kept_triangles(arrays.triangle_polygon, keep)
    key = tie_source(arrays.vertices, arrays.polygons, arrays.counts, arrays.triangle_polygon)
    want = zbuffer(arrays, proj, d, order, draw)
    assert_same(zbuffer(arrays, proj, d, index_order, draw, key=key), want)
    assert_same(zbuffer(arrays, proj, d, index_order, draw, shared=False, key=key), want)
