"""The whole pipeline: methods agree with ray casting, cull and sort rules, fallback."""

import numpy as np
import pytest

from service.base.errors import SettingsError
from service.builtin_scenes import builtin_scene
from service.display import DisplaySettings
from service.render.cull import CullSettings, cull
from service.render.depth_sort import average_z, sort_polygons
from service.render.light import LightSettings
from service.render.mesh import Mesh
from service.render.pipeline import METHOD_NAMES, Renderer, RenderSettings
from service.render.scene import Scene, SceneObject

SMALL = DisplaySettings(zones=5, angle_deg=16.0, cols=96, rows=72)


def polygon_map(scene, display, method, fallback="frame"):
    arrays = scene.flatten()
    settings = RenderSettings(method=method, painter_fallback=fallback)
    vis, counts, _ = Renderer().visibility(arrays, display, settings)
    poly = np.where(vis.triangle >= 0, arrays.triangle_polygon[np.maximum(vis.triangle, 0)], -1)
    return poly, vis, counts


@pytest.mark.parametrize("method", [m for m in METHOD_NAMES if m != "raycast"])
def test_methods_match_ray_casting_on_sphere_and_torus(method):
    scene = builtin_scene("sphere-torus")
    ref, _, _ = polygon_map(scene, SMALL, "raycast")
    got, _, _ = polygon_map(scene, SMALL, method, fallback="off")
    assert np.mean(got == ref) >= 0.999


def test_runlength_within_16_degrees_on_the_game_scene():
    scene = builtin_scene("game")
    ref, _, _ = polygon_map(scene, SMALL, "raycast")
    got, vis, _ = polygon_map(scene, SMALL, "runlength", fallback="off")
    assert np.mean(got == ref) >= 0.995


def test_cyclic_overlap_is_detected_and_falls_back_to_the_zbuffer():
    scene = builtin_scene("cyclic")
    ref, _, _ = polygon_map(scene, SMALL, "raycast")
    wrong, vis_wrong, _ = polygon_map(scene, SMALL, "runlength", fallback="off")
    assert vis_wrong.stats["inconsistent_pixels"] > 0
    assert np.mean(wrong != ref) > 0.001  # painter's order alone shows the wrong picture
    fixed, vis, _ = polygon_map(scene, SMALL, "runlength")
    assert vis.stats["fallback"] == "zbuffer"
    assert np.mean(fixed == ref) >= 0.999


def test_interpenetration_is_detected_too():
    scene = builtin_scene("threaded")
    _, vis, _ = polygon_map(scene, SMALL, "runlength", fallback="off")
    assert vis.stats["inconsistent_pixels"] > 0
    _, vis, _ = polygon_map(scene, SMALL, "runlength")
    assert vis.stats.get("fallback") == "zbuffer"


def test_bsp_is_right_where_average_z_is_wrong():
    for name in ("cyclic", "threaded"):
        scene = builtin_scene(name)
        ref, _, _ = polygon_map(scene, SMALL, "raycast")
        got, _, _ = polygon_map(scene, SMALL, "bsp")
        assert np.mean(got == ref) >= 0.999, name


def facing(nx: float, nz: float) -> Mesh:
    """A small triangle whose normal is (nx, 0, nz) (normalised later)."""
    n = np.array([nx, 0.0, nz]) / np.hypot(nx, nz)
    u = np.array([0.0, 1.0, 0.0])
    w = np.cross(u, n)
    v = np.array([np.zeros(3), 0.1 * w, 0.1 * u])
    return Mesh.from_triangles(v, [[0, 1, 2]])


def test_modified_cull_keeps_polygons_that_face_any_zone():
    display = DisplaySettings(zones=5, angle_deg=16.0)
    edge = np.radians(6.4)  # the outermost zone's direction
    # normals just past 90 degrees from +z: facing only the outermost zones
    meshes = [
        facing(1.0, 0.0),  # edge-on to the straight-on view, faces zone 4
        facing(np.cos(edge - 0.01), -np.sin(edge - 0.01)),  # faces zone 4 only
        facing(np.cos(edge + 0.01), -np.sin(edge + 0.01)),  # faces no zone
        facing(0.0, 1.0),
        facing(0.0, -1.0),
    ]
    arrays = Scene([SceneObject(m) for m in meshes]).flatten()
    keep, counts = cull(arrays.normals, display, CullSettings("modified"))
    assert keep.tolist() == [True, True, False, True, False]
    assert counts == {"in": 5, "culled": 2, "kept": 3}
    plain, _ = cull(arrays.normals, display, CullSettings("plain"))
    assert plain.tolist() == [False, False, False, True, False]


@pytest.mark.parametrize("mode", ["modified", "plain", "none"])
def test_both_culls_from_one_facing_table_equal_their_own(mode):
    from service.render.cull import facing as facing_table
    from service.render.cull import zone_mask

    a = builtin_scene("game").flatten()
    settings = CullSettings(mode)
    faces = facing_table(a.normals, SMALL)
    assert faces.shape == (a.normals.shape[0], SMALL.zones)
    own, own_counts = cull(a.normals, SMALL, settings)
    shared, counts = cull(a.normals, SMALL, settings, faces)
    assert np.array_equal(own, shared) and own_counts == counts
    args = (a.triangle_polygon, a.normals, a.polygon_closed, SMALL, settings)
    assert np.array_equal(zone_mask(*args), zone_mask(*args, faces))
    by_triangle = zone_mask(*args, faces, by_triangle=True)
    assert by_triangle.flags.c_contiguous and np.array_equal(by_triangle.T, zone_mask(*args))


@pytest.mark.parametrize("mode", ["modified", "plain", "none"])
@pytest.mark.parametrize("per_zone", [True, False])
@pytest.mark.parametrize("name", ["game", "demo", "edge-on"])
@pytest.mark.parametrize("zones", [1, 5])
def test_one_pass_cull_equals_cull_and_zone_mask(mode, per_zone, name, zones):
    from service.render.cull import cull_zones, zone_mask

    if name == "edge-on":  # normals on and just past each zone's edge, one zero
        edge = np.radians(6.4)
        meshes = [facing(np.cos(edge + e), -np.sin(edge + e)) for e in (-0.01, 0.0, 0.01)]
        meshes += [facing(1.0, 0.0), facing(0.0, 1.0), facing(0.0, -1.0)]
        arrays = Scene([SceneObject(m) for m in meshes]).flatten()
        arrays.normals[2] = 0.0  # a degenerate polygon: always culled
    else:
        arrays = builtin_scene(name).flatten()
    d = DisplaySettings(zones=zones, angle_deg=16.0, cols=96, rows=72)
    settings = CullSettings(mode, per_zone)
    keep, counts, draw_t = cull_zones(
        arrays.normals, arrays.triangle_polygon, arrays.polygon_closed, d, settings
    )
    own, own_counts = cull(arrays.normals, d, settings)
    mask = zone_mask(arrays.triangle_polygon, arrays.normals, arrays.polygon_closed, d,
                     settings, by_triangle=True)
    assert np.array_equal(keep, own) and counts == own_counts
    assert draw_t.flags.c_contiguous and np.array_equal(draw_t, mask)
    assert not keep[np.all(arrays.normals == 0.0, axis=1)].any()


def test_sort_is_nearest_first_and_ties_keep_object_order():
    z = np.array([0.0, 0.5, 0.5, -1.0, 0.5])
    assert sort_polygons(z).tolist() == [1, 2, 4, 0, 3]
    assert sort_polygons(z, np.array([1, 0, 1, 1, 1], bool)).tolist() == [2, 4, 0, 3]


def test_coincident_objects_first_object_wins():
    # Thesis 3.2: equal average z -> object 1 takes precedence over object 2.
    tri = [[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.0, 0.5, 0.0]]
    a = Mesh.from_triangles(tri, [[0, 1, 2]])
    scene = Scene([SceneObject(a), SceneObject(a)])
    arrays = scene.flatten()
    assert np.allclose(average_z(arrays.vertices, arrays.polygons, arrays.counts), 0.0)
    for method in ("runlength", "zbuffer"):
        poly, _, _ = polygon_map(scene, SMALL, method)
        assert set(np.unique(poly)) == {-1, 0}


def test_render_gives_frame_with_counts_and_timings():
    scene = builtin_scene("demo")
    frame = Renderer().render(scene, SMALL, RenderSettings(light=LightSettings("phong", "vertex")))
    assert frame.colour.shape == (5, 72, 96, 3) and frame.colour.dtype == np.uint8
    assert frame.depth.shape == (5, 72, 96) and frame.depth.dtype == np.float32
    counts = frame.stats["polygons"]
    assert counts["in"] == sum(o.mesh.n_polygons for o in scene.objects)
    assert counts["culled"] + counts["kept"] == counts["in"]
    assert 0 < counts["drawn"] <= counts["kept"]
    for stage in ("flatten", "project", "cull", "sort", "occlusion", "light", "total"):
        assert frame.stats["ms"][stage] >= 0
    empty = np.isinf(frame.depth)
    assert (frame.colour[empty] == 0).all() and not empty.all()


def test_zones_see_parallax():
    frame = Renderer().render(builtin_scene("demo"), SMALL)
    assert not np.array_equal(frame.colour[0], frame.colour[4])


def test_bad_settings_are_clear_errors():
    with pytest.raises(SettingsError, match="method"):
        RenderSettings(method="magic")
    with pytest.raises(SettingsError, match="zones"):
        DisplaySettings(zones=65)
    with pytest.raises(SettingsError, match="angle"):
        DisplaySettings(angle_deg=61)


def test_pixel_fallback_equals_the_zbuffer_and_reports_it():
    # The tie rule: the repair is the z-buffer's strict test, so exact ties keep the
    # surface drawn first and the buffers equal the z-buffer's bit for bit.
    for name in ("cyclic", "threaded", "game", "demo"):
        arrays = builtin_scene(name).flatten()
        zb, _, _ = Renderer().visibility(arrays, SMALL, RenderSettings("zbuffer"))
        vis, _, _ = Renderer().visibility(arrays, SMALL, RenderSettings("runlength"))
        assert vis.stats["inconsistent_pixels"] > 0, name
        assert vis.stats["fallback"] == "pixel", name  # the default
        assert np.array_equal(vis.triangle, zb.triangle), name
        assert np.array_equal(vis.depth, zb.depth), name


def test_pixel_repair_tie_rule_on_exact_and_near_ties():
    # Two overlapping triangles drawn in a given order: an exact depth tie keeps the
    # first (as the z-buffer and ray casting do); a later one nearer by less than the
    # inconsistency threshold is repaired (as the z-buffer would) but not counted.
    from service.render.occlusion.runlength import DEPTH_EPS, runlength
    from service.render.occlusion.zbuffer import zbuffer
    from service.render.projection import project

    tri = np.array([[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.0, 0.5, 0.0]])
    display = DisplaySettings(zones=3, angle_deg=16.0, cols=32, rows=24)
    for dz, counted in ((0.0, False), (DEPTH_EPS / 4, False), (4 * DEPTH_EPS, True)):
        second = Mesh.from_triangles(tri + [0.0, 0.0, dz], [[0, 1, 2]])
        scene = Scene([SceneObject(Mesh.from_triangles(tri, [[0, 1, 2]])), SceneObject(second)])
        arrays = scene.flatten()
        proj = project(arrays.vertices, display)
        order = np.array([0, 1], np.int64)  # the farther (or tied) one first
        zb = zbuffer(arrays, proj, display, order)
        rl = runlength(arrays, proj, display, order, repair=True)
        assert np.array_equal(rl.triangle, zb.triangle), dz
        assert set(np.unique(rl.triangle)) == ({-1, 1} if dz else {-1, 0}), dz
        assert (rl.stats["inconsistent_pixels"] > 0) == counted, dz


def test_per_zone_cull_changes_no_pixel_of_closed_meshes():
    scene = builtin_scene("demo")
    wide = DisplaySettings(zones=9, angle_deg=60.0, cols=96, rows=72)
    arrays = scene.flatten()
    assert arrays.polygon_closed.any()
    for method in ("zbuffer", "runlength"):
        maps = []
        for per_zone in (True, False):
            s = RenderSettings(method=method, cull=CullSettings(per_zone=per_zone))
            vis, _, _ = Renderer().visibility(arrays, wide, s)
            maps.append(vis.triangle)
        assert np.array_equal(maps[0], maps[1]), method


def test_open_surfaces_are_drawn_from_behind():
    # A lone quad facing +x is seen from behind by the zones left of it: an open mesh,
    # so the per-zone cull must keep it there.
    quad = Mesh.from_polygons(
        np.array([[0, -0.5, -0.5], [0, -0.5, 0.5], [0, 0.5, 0.5], [0, 0.5, -0.5]], float),
        [[0, 1, 2, 3]],
    )
    assert not quad.is_closed
    wide = DisplaySettings(zones=4, angle_deg=60.0, cols=64, rows=48)
    vis, _, _ = Renderer().visibility(Scene([SceneObject(quad)]).flatten(), wide, RenderSettings())
    seen = (vis.triangle >= 0).any(axis=(1, 2))
    assert seen.all()


def test_closed_mesh_detection():
    from service.primitives import cube, sphere, torus

    assert cube(1.0).is_closed and sphere(0.5, 8, 16).is_closed and torus(0.5, 0.2, 12, 8).is_closed
    c = cube(1.0)
    open_box = Mesh.from_polygons(c.vertices, [c.polygons[i, : c.counts[i]] for i in range(5)])
    assert not open_box.is_closed
    flipped = Mesh.from_polygons(
        c.vertices,
        [c.polygons[0, : c.counts[0]][::-1]] + [c.polygons[i, : c.counts[i]] for i in range(1, 6)],
    )
    assert not flipped.is_closed


def test_five_zone_error_grows_with_angle_and_shrinks_with_zones():
    # A viewer between zone centres sees the nearest zone's image: the wider the
    # viewing angle, or the fewer the zones, the more pixels show the wrong object.
    from service.bench.render_bench import continuous_error

    size = (96, 72)
    by_angle = [continuous_error("game", 5, a, size) for a in (4.0, 16.0, 60.0)]
    assert by_angle[0] < by_angle[1] < by_angle[2]
    by_zones = [continuous_error("game", z, 32.0, size) for z in (1, 5, 17)]
    assert by_zones[0] > by_zones[1] > by_zones[2]
    assert continuous_error("game", 5, 0.0, size) == 0.0  # no look-around, nothing to miss


def test_zone_cost_rows_and_chart(tmp_path):
    from service.bench.render_bench import STAGES, chart_zone_cost, zone_cost

    rows = zone_cost("sphere-torus", zones=(1, 3), repeats=1, rounds=2, size=(48, 36))
    assert [r["zones"] for r in rows] == [1, 3]
    assert rows[0]["ratio"] == 1.0
    # the ratio is taken before the milliseconds are rounded to 3 places: each ms
    # is off by up to 5e-4, which at these tiny sizes moves their ratio by more
    ms0, ms1 = rows[0]["ms"], rows[1]["ms"]
    slack = 5e-4 + (ms1 / ms0) * (5e-4 / ms0 + 5e-4 / ms1) * 1.01
    assert rows[1]["ratio"] == pytest.approx(ms1 / ms0, abs=slack)
    for r in rows:
        assert all(r[f"ms_{k}"] > 0.0 for k in STAGES)
        assert r["ms"] >= sum(r[f"ms_{k}"] for k in STAGES) * 0.5
    chart_zone_cost(rows, tmp_path / "z.png")
    assert (tmp_path / "z.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_render_reuses_its_triangle_map_and_visibility_returns_fresh_ones():
    from service.builtin_scenes import builtin_scene

    scene = builtin_scene("threaded")
    d = DisplaySettings(zones=3, cols=64, rows=48)
    r = Renderer()
    first = r.render(scene, d)
    a, _, _ = r.visibility(scene.flatten(), d, RenderSettings())
    second = r.render(scene, d)
    b, _, _ = r.visibility(scene.flatten(), d, RenderSettings())
    assert not np.shares_memory(a.triangle, b.triangle)
    assert np.array_equal(a.triangle, b.triangle)
    assert not np.shares_memory(first.depth, second.depth)
    assert np.array_equal(first.colour, second.colour)
    assert np.array_equal(first.depth, second.depth)


def test_subclass_with_the_old_visibility_signature_renders():
    from service.builtin_scenes import builtin_scene

    class Counting(Renderer):
        calls = 0

        def visibility(self, arrays, display, settings, clock=None):
            self.calls += 1
            return super().visibility(arrays, display, settings, clock)

    d = DisplaySettings(zones=2, cols=48, rows=32)
    r = Counting()
    frame = r.render(builtin_scene("cyclic"), d)
    assert r.calls == 1
    assert np.array_equal(frame.colour, Renderer().render(builtin_scene("cyclic"), d).colour)


def test_triangle_buffers_are_kept_per_shape_up_to_the_limit():
    from service.render.pipeline import SCRATCH_SHAPES

    r = Renderer()
    shapes = [(z, 8, 8) for z in range(1, SCRATCH_SHAPES + 2)]
    first = {s: r._triangle_buffer(s) for s in shapes[:SCRATCH_SHAPES]}
    assert all(r._triangle_buffer(s) is b for s, b in first.items())
    r._triangle_buffer(shapes[-1])  # one shape too many: the least recently used goes
    assert r._triangle_buffer(shapes[0]) is not first[shapes[0]]
    assert r._triangle_buffer(shapes[-1]).shape == shapes[-1]


@pytest.mark.parametrize(("zones", "angle"), [(1, 0.0), (5, 16.0), (17, 60.0)])
def test_project_equals_the_array_formula_bit_for_bit(zones, angle):
    from service.render.projection import project

    d = DisplaySettings(zones=zones, angle_deg=angle)
    rng = np.random.default_rng(zones)
    v = rng.normal(size=(500, 3)) * rng.choice([1e-3, 1.0, 1e3], size=(500, 1))
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    want = np.stack(
        np.broadcast_arrays(
            (x[None] - z[None] * d.shears()[:, None] + d.width / 2) / d.pixel_size,
            ((d.height / 2 - y) / d.pixel_size)[None],
            -z[None],
        ),
        axis=-1,
    )
    assert np.array_equal(project(v, d), want)
