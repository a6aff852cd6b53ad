"""Stage 5 (service.render.light): analytic intensities, view-dependent glints, modes agree."""

from __future__ import annotations

import numpy as np
import pytest

from service.base.errors import RenderError, SettingsError
from service.display import DisplaySettings
from service.primitives import sphere
from service.render.light import LightSettings, intensity, shade, shade_linear, to_uint8
from service.render.mesh import Mesh
from service.render.occlusion import Visibility
from service.render.projection import project
from service.render.scene import (
    Light,
    Material,
    Scene,
    SceneObject,
    Transform,
    axis_angle_quaternion,
)

EVALS = ("polygon", "vertex", "point")


def rasterise(scene, proj: np.ndarray, display: DisplaySettings) -> Visibility:
    """Test-only z-buffer: point-in-triangle at every pixel centre, nearest wins."""
    vis = Visibility.empty(display.zones, display.rows, display.cols)
    y, x = np.mgrid[0 : display.rows, 0 : display.cols] + 0.5
    for z in range(display.zones):
        for t, (a, b, c) in enumerate(scene.triangles):
            (ax, ay, az), (bx, by, bz), (cx, cy, cz) = proj[z, a], proj[z, b], proj[z, c]
            det = (bx - ax) * (cy - ay) - (cx - ax) * (by - ay)
            if abs(det) < 1e-12:
                continue
            w1 = ((x - ax) * (cy - ay) - (cx - ax) * (y - ay)) / det
            w2 = ((bx - ax) * (y - ay) - (x - ax) * (by - ay)) / det
            w0 = 1 - w1 - w2
            d = w0 * az + w1 * bz + w2 * cz
            win = (w0 >= -1e-9) & (w1 >= -1e-9) & (w2 >= -1e-9) & (d < vis.depth[z])
            vis.depth[z][win] = d[win]
            vis.triangle[z][win] = t
    return vis


def square(size: float = 1.0, flip: bool = False) -> Mesh:
    h = size / 2
    verts = [[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]]
    poly = [3, 2, 1, 0] if flip else [0, 1, 2, 3]
    return Mesh.from_polygons(verts, [poly])


def render(mesh, material, lights, display, settings, *, rot=None, ambient=1.0, fn=shade_linear):
    tf = Transform(orientation=rot) if rot is not None else Transform()
    sa = Scene([SceneObject(mesh, material, tf)], lights, ambient).flatten()
    proj = project(sa.vertices, display)
    vis = rasterise(sa, proj, display)
    return fn(sa, proj, vis, display, lights, ambient, settings), vis


HEAD_ON = DisplaySettings(zones=1, angle_deg=0.0, cols=16, rows=16, width=2.0)
MAT = Material(colour=(0.6, 0.4, 0.2), ambient=0.2, diffuse=0.5, specular=0.3, shininess=5)


@pytest.mark.parametrize("model", ["phong", "blinn"])
@pytest.mark.parametrize("evaluation", EVALS)
def test_head_on_square_has_analytic_colour(model, evaluation):
    light = Light("directional", [0, 0, 1])
    st = LightSettings(model=model, evaluation=evaluation)
    lin, vis = render(square(), MAT, [light], HEAD_ON, st)
    expect = np.array([0.6, 0.4, 0.2]) * (0.2 + 0.5) + 0.3  # N.L = R.V = N.H = 1
    covered = vis.triangle[0] >= 0
    assert covered.sum() == 64  # the unit square covers 8 x 8 pixels
    np.testing.assert_allclose(lin[0][covered], np.broadcast_to(expect, (64, 3)), atol=1e-6)
    assert np.all(lin[0][~covered] == 0)
    u8, _ = render(square(), MAT, [light], HEAD_ON, st, fn=shade)
    np.testing.assert_array_equal(u8[0][covered][0], np.round(expect * 255).astype(np.uint8))


def test_oblique_light_gives_phong_and_blinn_terms():
    a = np.radians(60)
    light = Light("directional", [np.sin(a), 0, np.cos(a)], colour=(1.0, 0.5, 1.0), intensity=0.8)
    for model, spec in (("phong", 0.5**5), ("blinn", np.cos(a / 2) ** 5)):
        lin, vis = render(square(), MAT, [light], HEAD_ON, LightSettings(model, "point"))
        px = lin[0][vis.triangle[0] >= 0]
        e = np.array([1.0, 0.5, 1.0]) * 0.8
        expect = np.array([0.6, 0.4, 0.2]) * (0.2 + 0.5 * 0.5 * e) + 0.3 * spec * e
        np.testing.assert_allclose(px, np.broadcast_to(expect, px.shape), atol=1e-6)


def test_ambient_model_ignores_lights_and_zones():
    disp = DisplaySettings(zones=3, angle_deg=20, cols=16, rows=16)
    light = Light("directional", [0, 0, 1], intensity=5.0)
    out, vis = render(square(), MAT, [light], disp, LightSettings("ambient"), ambient=0.5, fn=shade)
    expect = np.round(np.array([0.6, 0.4, 0.2]) * 0.2 * 0.5 * 255).astype(np.uint8)
    for z in range(3):
        assert np.all(out[z][vis.triangle[z] >= 0] == expect)


@pytest.mark.parametrize("model", ["phong", "blinn"])
@pytest.mark.parametrize("evaluation", EVALS)
def test_glint_on_tilted_mirror_is_seen_by_one_zone(model, evaluation):
    """Light head-on; a mirror tilted by theta_k / 2 reflects it into zone k only."""
    disp = DisplaySettings(zones=5, angle_deg=40, cols=24, rows=24, width=2.0)
    mirror = Material(colour=(1, 1, 1), ambient=0, diffuse=0, specular=1, shininess=2000)
    light = Light("directional", [0, 0, 1])
    st = LightSettings(model, evaluation)
    for k, theta in enumerate(disp.zone_angles()):
        rot = axis_angle_quaternion([0, 1, 0], theta / 2)
        lin, vis = render(square(), mirror, [light], disp, st, rot=rot)
        seen = [lin[z].mean(-1)[vis.triangle[z] >= 0].mean() for z in range(5)]
        assert int(np.argmax(seen)) == k
        assert seen[k] > 0.95
        assert max(np.delete(seen, k)) < 0.05


@pytest.mark.parametrize("model", ["phong", "blinn"])
def test_flat_polygon_vertex_and_point_equal_polygon(model):
    disp = DisplaySettings(zones=3, angle_deg=16, cols=20, rows=20)
    lights = [Light("directional", [0.3, 0.5, 1]), Light("directional", [-1, 0.2, 0.4], (1, 0, 0))]
    rot = axis_angle_quaternion([1, 1, 0], 0.4)
    outs = {
        ev: render(square(1.4), MAT, lights, disp, LightSettings(model, ev), rot=rot)[0]
        for ev in EVALS
    }
    np.testing.assert_allclose(outs["vertex"], outs["polygon"], atol=1e-6)
    np.testing.assert_allclose(outs["point"], outs["polygon"], atol=1e-6)


def test_point_light_direction_varies_across_surface():
    disp = DisplaySettings(zones=1, angle_deg=0, cols=32, rows=32, width=2.0)
    white = Material(colour=(1, 1, 1), ambient=0, diffuse=1, specular=0)
    h, x0 = 0.5, 0.4
    lin, vis = render(square(2.0), white, [Light("point", [x0, 0, h])], disp,
                      LightSettings("blinn", "point"))
    c = np.arange(32) + 0.5
    x = c * disp.pixel_size - 1.0
    y = 1.0 - c * disp.pixel_size
    expect = h / np.sqrt((x[None, :] - x0) ** 2 + y[:, None] ** 2 + h**2)
    np.testing.assert_allclose(lin[0, ..., 0], expect, atol=1e-5)
    # brightest column sits under the light; per-polygon uses the centroid only
    assert abs(x[np.argmax(lin[0, 16, :, 0])] - x0) <= disp.pixel_size
    flat, _ = render(square(2.0), white, [Light("point", [x0, 0, h])], disp, LightSettings())
    np.testing.assert_allclose(flat[0, ..., 0], h / np.hypot(x0, h), atol=1e-6)
    below, _ = render(square(2.0), white, [Light("point", [0, 0, -h])], disp,
                      LightSettings("blinn", "point"))
    assert np.all(below == 0)


@pytest.mark.parametrize("evaluation", EVALS)
def test_several_lights_add(evaluation):
    disp = DisplaySettings(zones=3, angle_deg=16, cols=24, rows=24)
    mat = Material(colour=(0.5, 0.4, 0.3), ambient=0.1, diffuse=0.3, specular=0.2, shininess=3)
    a = Light("directional", [0.2, 0.4, 1], intensity=0.5)
    b = Light("point", [-1, 1, 2], colour=(0.2, 0.6, 1.0), intensity=0.5)
    st = LightSettings("blinn", evaluation)
    ball = sphere(0.8, 8, 12)
    both = render(ball, mat, [a, b], disp, st)[0]
    only_a = render(ball, mat, [a], disp, st)[0]
    only_b = render(ball, mat, [b], disp, st)[0]
    none = render(ball, mat, [], disp, st)[0]
    assert both.max() < 1.0  # nothing clamped, so the sum is exact
    np.testing.assert_allclose(both, only_a + only_b - none, atol=1e-5)


def horizontal_jumps(img: np.ndarray, covered: np.ndarray) -> np.ndarray:
    both = covered[:, 1:] & covered[:, :-1]
    return np.abs(np.diff(img, axis=1))[both]


def test_per_point_sphere_is_smooth_and_per_polygon_faceted():
    disp = DisplaySettings(zones=1, angle_deg=0, cols=96, rows=96, width=2.0)
    mat = Material(colour=(0.8, 0.8, 0.8), ambient=0.1, diffuse=0.7, specular=0.3, shininess=5)
    light = [Light("directional", [0.3, 0.4, 1])]
    ball = sphere(0.8, 10, 20)
    jumps = {}
    for ev in EVALS:
        img, vis = render(ball, mat, light, disp, LightSettings("blinn", ev), fn=intensity)
        r, c = np.mgrid[0:96, 0:96] - 47.5
        inner = (vis.triangle[0] >= 0) & (np.hypot(r, c) < 0.7 * 0.8 / disp.pixel_size)
        jumps[ev] = horizontal_jumps(img[0], inner)
    assert jumps["point"].max() < 0.03
    assert jumps["polygon"].max() > 3 * jumps["point"].max()
    assert np.mean(jumps["polygon"] == 0) > 0.5  # flat facets: most neighbours identical
    assert jumps["vertex"].max() < jumps["polygon"].max()


@pytest.mark.parametrize("evaluation", EVALS)
def test_polygon_facing_away_from_a_zone_is_lit_as_its_visible_side(evaluation):
    """A steep quad faces zone 4 but shows its back to zone 0: zone 0 lights -N."""
    disp = DisplaySettings(zones=5, angle_deg=40, cols=32, rows=32, width=1.0)
    rot = axis_angle_quaternion([0, 1, 0], np.radians(80))
    n = np.array([np.sin(np.radians(80)), 0, np.cos(np.radians(80))])
    views = disp.view_vectors()
    assert views[0] @ n < 0 < views[4] @ n
    lights = [Light("directional", [-1, 0.3, 0.2]), Light("directional", [1, 0.2, 0.3])]
    st = LightSettings("blinn", evaluation)
    front, vis = render(square(0.8), MAT, lights, disp, st, rot=rot)
    back, vis_b = render(square(0.8, flip=True), MAT, lights, disp, st, rot=rot)
    np.testing.assert_array_equal(vis.triangle >= 0, vis_b.triangle >= 0)
    assert (vis.triangle[0] >= 0).sum() > 20
    np.testing.assert_allclose(front, back, atol=1e-6)
    ambient_only = np.array([0.6, 0.4, 0.2]) * 0.2
    assert np.all(front[0][vis.triangle[0] >= 0] > ambient_only + 0.05)


def test_shade_is_quantised_linear_and_background_fills_empty():
    disp = DisplaySettings(zones=2, angle_deg=10, cols=32, rows=24)
    lights = [Light("point", [0.5, 0.5, 1.5])]
    for ev in EVALS:
        st = LightSettings("phong", ev, background=(10, 20, 30))
        lin, vis = render(sphere(0.5, 8, 12), MAT, lights, disp, st)
        u8, _ = render(sphere(0.5, 8, 12), MAT, lights, disp, st, fn=shade)
        assert u8.dtype == np.uint8 and u8.shape == (2, 24, 32, 3)
        np.testing.assert_array_equal(u8, to_uint8(lin))
        assert np.all(u8[vis.triangle < 0] == (10, 20, 30))


def test_bad_settings_and_shapes_are_refused():
    with pytest.raises(SettingsError):
        LightSettings(model="lambert")
    with pytest.raises(SettingsError):
        LightSettings(evaluation="pixel")
    with pytest.raises(SettingsError):
        LightSettings(background=(0, 0, 256))
    sa = Scene([SceneObject(square())]).flatten()
    proj = project(sa.vertices, HEAD_ON)
    with pytest.raises(RenderError):
        shade(sa, proj, Visibility.empty(1, 8, 8), HEAD_ON, [], 1.0)
    with pytest.raises(RenderError):
        shade(sa, proj[:, :2], Visibility.empty(1, 16, 16), HEAD_ON, [], 1.0)


@pytest.mark.parametrize(("kind", "vector"), [
    ("directional", [0, 0, 0]), ("directional", [np.nan, 0, 1]), ("point", [np.inf, 0, 0]),
    # finite, but its length overflows: normalised it would be a silent zero or NaN light
    ("directional", [1e308, 1e308, 0]), ("point", [0, 2e154, 0]),
])
def test_a_light_vector_that_cannot_be_normalised_is_refused(kind, vector):
    with pytest.raises(SettingsError, match="light vector must be finite"):
        Light(kind, vector)


def test_a_far_point_light_and_a_tiny_direction_are_kept():
    assert Light("point", [0, 1e150, 0]).vector[1] == 1e150
    assert Light("directional", [1e-150, 0, 0]).vector[0] == 1e-150


def test_light_benchmark_writes_its_files_and_ranks_modes(tmp_path, capsys):
    from service.bench import light_bench

    argv = ["--out", str(tmp_path), "--scenes", "sphere", "--zones", "1,3", "--size", "64x48",
            "--repeats", "1"]
    assert light_bench.main(argv) == 0
    for name in ("light_bench.json", "light_bench.csv", "light_bench.png"):
        assert (tmp_path / name).stat().st_size > 0
    import json

    rows = json.loads((tmp_path / "light_bench.json").read_text())["rows"]
    assert len(rows) == 2 * len(light_bench.VARIANTS)
    err = {(r["zones"], r["model"], r["evaluation"]): r["error"] for r in rows}
    for z in (1, 3):
        assert err[(z, "blinn", "point")] == 0.0
        assert err[(z, "blinn", "vertex")] < err[(z, "blinn", "polygon")]
        assert err[(z, "blinn", "polygon")] < err[(z, "ambient", "polygon")]
    assert "wrote" in capsys.readouterr().out
