"""Billboard clouds in the pipeline: same depth as the mesh they stand for, z-tested
against meshes in every zone, and stats that say how they were drawn."""

import dataclasses

import numpy as np
import pytest

from service.base.errors import MeshFileError
from service.billboard_render import BillboardObject
from service.display import DisplaySettings
from service.loaders import load_scene
from service.primitives import cube, sphere
from service.render.pipeline import Renderer, RenderSettings
from service.render.scene import Material, Scene, SceneObject, Transform, euler_quaternion
from service.simplify.billboard import build_cloud
from service.simplify.cloud_file import save_cloud

DISPLAY = DisplaySettings(zones=3, cols=96, rows=72)
TILT = Transform(orientation=euler_quaternion(0.5, 0.4, 0.1))


@pytest.fixture(scope="module")
def box():
    m = cube(0.8)
    return m, build_cloud(m.vertices, m.triangles, 0.004, texture_res=256)


def _depths(mesh_scene, cloud_scene, method):
    r = Renderer()
    full = r.render(mesh_scene, DISPLAY, RenderSettings(method=method))
    bb = r.render(cloud_scene, DISPLAY, RenderSettings(method=method))
    return full, bb


@pytest.mark.parametrize("method", ["zbuffer", "raycast"])
def test_cloud_of_a_planar_mesh_renders_the_mesh_depth(box, method):
    mesh, cloud = box
    assert cloud.n_billboards == 6
    full, bb = _depths(Scene([SceneObject(mesh, Material(), TILT)]),
                       Scene([], billboards=[BillboardObject(cloud, Material(), TILT)]), method)
    a, b = np.isfinite(full.depth), np.isfinite(bb.depth)
    # the silhouettes agree but for a texel-wide rim (conservative coverage)
    assert (a ^ b).sum() <= 0.03 * a.sum()
    both = a & b
    assert np.percentile(np.abs(full.depth[both] - bb.depth[both]), 99) < 0.01
    assert bb.stats["billboards"]["drawn_with"] == method
    assert bb.stats["billboards"]["quads"] == 6
    # lit like the mesh: same faces, same normals (flat), same model
    diff = np.abs(full.colour.astype(int) - bb.colour.astype(int))[both]
    assert np.median(diff) <= 2


def test_meshes_and_billboards_hide_each_other(box):
    mesh, cloud = box
    ball = sphere(0.3, 12, 24)
    front = Transform(position=np.array([0.0, 0.0, 0.6]))
    back = Transform(position=np.array([0.0, 0.0, -0.6]))
    scene = Scene([SceneObject(ball, Material(colour=(1.0, 0.0, 0.0)), front)],
                  billboards=[BillboardObject(cloud, Material(colour=(0.0, 0.0, 1.0)), back)])
    f = Renderer().render(scene, DISPLAY)
    centre = f.colour[:, DISPLAY.rows // 2, DISPLAY.cols // 2]
    assert (centre[:, 0] > centre[:, 2]).all()  # the ball in front wins
    scene = Scene([SceneObject(ball, Material(colour=(1.0, 0.0, 0.0)), back)],
                  billboards=[BillboardObject(cloud, Material(colour=(0.0, 0.0, 1.0)), front)])
    f = Renderer().render(scene, DISPLAY)
    centre = f.colour[:, DISPLAY.rows // 2, DISPLAY.cols // 2]
    assert (centre[:, 2] > centre[:, 0]).all()  # now the billboards do


@pytest.mark.parametrize("method", ["runlength", "bsp"])
def test_other_methods_say_billboards_were_z_buffered(box, method):
    mesh, cloud = box
    scene = Scene([SceneObject(sphere(0.2, 8, 16))],
                  billboards=[BillboardObject(cloud, Material(), TILT)])
    st = Renderer().render(scene, DISPLAY, RenderSettings(method=method)).stats["billboards"]
    assert st["drawn_with"] == "zbuffer" and method in st["note"]
    assert st["covered_pixels"] > 0


def test_scene_file_names_a_cloud(tmp_path, box):
    _, cloud = box
    save_cloud(cloud, tmp_path / "box.hbc")
    (tmp_path / "s.toml").write_text(
        '[[object]]\nfile = "box.hbc"\nposition = [0, 0, -0.2]\nmaterial = {colour = [1, 0.5, 0]}\n'
        '[[object]]\nprimitive = "sphere"\nparams = {radius = 0.1}\n')
    scene = load_scene(tmp_path / "s.toml")
    assert len(scene.objects) == 1 and len(scene.billboards) == 1
    assert scene.billboards[0].material.colour == (1.0, 0.5, 0.0)
    lone = load_scene(tmp_path / "box.hbc")
    assert lone.billboards and not lone.objects
    assert Renderer().render(lone, DISPLAY).stats["billboards"]["covered_pixels"] > 0


def test_scene_file_refuses_a_moving_cloud(tmp_path, box):
    _, cloud = box
    save_cloud(cloud, tmp_path / "box.hbc")
    (tmp_path / "s.toml").write_text(
        '[[object]]\nfile = "box.hbc"\nmotion = {velocity = [1, 0, 0]}\n')
    with pytest.raises(MeshFileError, match="motion"):
        load_scene(tmp_path / "s.toml")


def test_billboards_follow_the_viewer_and_stay_put_in_time(box):
    """Head tracking and scene time keep a scene's billboard clouds (not just its meshes)."""
    from service.scene_motion import advance_scene, view_scene

    _, cloud = box
    scene = Scene([SceneObject(sphere(0.2, 8, 16))],
                  billboards=[BillboardObject(cloud, Material(), TILT)])
    later = advance_scene(scene, 0.5)
    assert len(later.billboards) == 1 and later.billboards[0].transform is TILT
    viewer = Transform(position=np.array([0.3, 0.0, 0.0]))
    seen = view_scene(scene, viewer)
    assert np.allclose(seen.billboards[0].transform.position, TILT.position - [0.3, 0, 0])
    assert Renderer().render(seen, DISPLAY).stats["billboards"]["covered_pixels"] > 0


def test_the_service_loads_a_cloud_as_a_scene(tmp_path, box):
    """(tests/service/test_service_billboards.py serves one.)"""
    from service.net import handlers

    _, cloud = box
    save_cloud(cloud, tmp_path / "box.hbc")
    assert len(handlers._load_path(str(tmp_path / "box.hbc")).billboards) == 1


def test_billboard_pixels_move_like_the_mesh_they_stand_for_when_the_viewer_moves(box):
    """The Galilean stage advances pixels by their motion derivatives between renders;
    a billboard pixel's come from its quad (rigid and planar: affine over it), so a
    cube's cloud moves on screen as the cube does under a translating, turning viewer."""
    from service.galilean.motion_field import render_with_motion
    from service.render.scene import MotionState

    mesh, cloud = box
    motion = MotionState(velocity=np.array([0.2, -0.1, 0.05]),
                         angular_velocity=np.array([0.1, 0.4, 0.2]))
    viewer = Transform(position=np.array([0.05, 0.0, 0.1]))

    def derivatives(scene):
        up = render_with_motion(Renderer(), scene, DISPLAY, 0.0, 60.0, viewer=viewer,
                                viewer_motion=motion)
        return up.derivatives, np.isfinite(up.frame.depth)

    d_mesh, a = derivatives(Scene([SceneObject(mesh, Material(), TILT)]))
    d_cloud, b = derivatives(Scene([], billboards=[BillboardObject(cloud, Material(), TILT)]))
    both = a & b
    vel_mesh, vel_cloud = d_mesh[0][:, both], d_cloud[0][:, both]  # (3, N): x, y px; depth
    assert np.abs(vel_mesh[:2]).max() > 0.05  # the picture does move
    assert np.abs(vel_cloud - vel_mesh).max() < 0.01 * np.abs(vel_mesh).max() + 1e-4
    assert np.allclose(d_cloud[1][:, both], d_mesh[1][:, both], atol=1e-3)


def test_a_local_update_behind_a_cloud_stays_behind_it(box):
    """update_objects re-renders one object alone (service/galilean/local_update.py); a
    billboard cloud in front of it must still hide it there, as a mesh would."""
    from service.galilean.fixed_point import FixedPoint, bit_budget
    from service.galilean.local_update import render_local

    _, cloud = box
    ball = sphere(0.3, 12, 24)
    scene = Scene([SceneObject(ball, Material(colour=(1.0, 0.0, 0.0)),
                               Transform(position=np.array([0.5, 0.0, -0.6])))],
                  billboards=[BillboardObject(cloud, Material(), Transform(
                      position=np.array([0.0, 0.0, 0.6])))])
    fixed = FixedPoint.for_order(bit_budget(max(DISPLAY.cols, DISPLAY.rows), 16, 16), 2)
    local = render_local(Renderer(), scene, DISPLAY, [0], 0.0, 60.0, 2, fixed).buffer
    full = Renderer().render(scene, DISPLAY)
    alone = Renderer().render(Scene(scene.objects), DISPLAY)
    hidden = np.isfinite(alone.depth) & (full.depth < 0)  # the ball, behind the cloud
    assert hidden.sum() > 100
    assert (local.debris[hidden] == 1).all()  # no ball pixel grafted over the cloud
    shown = (local.debris == 0)
    assert shown.sum() > 0 and not (shown & hidden).any()


@pytest.fixture(scope="module")
def two_boxes():
    """Two small cubes 1.2 apart: their shared face planes make long, mostly empty
    billboards (126 x 18 texels with a gap of 90 columns between the cubes)."""
    c = cube(0.2)
    v = np.concatenate([c.vertices + [-0.6, 0.0, 0.0], c.vertices + [0.6, 0.0, 0.0]])
    f = np.concatenate([c.triangles, c.triangles + len(c.vertices)])
    return build_cloud(v, f, 0.004, texture_res=128)


@pytest.mark.parametrize("scale", [0.2, 1.0, 1.6])
@pytest.mark.parametrize("yaw", [0.3, 1.0, 2.0])
def test_empty_tiles_are_skipped_without_changing_a_pixel(two_boxes, scale, yaw):
    """A quad drawn close up visits only its texture's tiles that show something.  The
    reference is the same cloud with alpha 1 (below the alpha test, so drawn
    transparent) in every empty texel: no tile of it is empty, so every quad is drawn
    whole.  The pictures must be equal; close up, the culled one visits far fewer pixels."""
    rgba = two_boxes.rgba.copy()
    rgba[rgba[:, 3] == 0, 3] = 1
    whole = dataclasses.replace(two_boxes, rgba=rgba)
    t = Transform(orientation=euler_quaternion(yaw, 0.4, 0.1), scale=scale)
    culled, full = (Renderer().render(Scene([], billboards=[BillboardObject(c, Material(), t)]),
                                      DISPLAY) for c in (two_boxes, whole))
    assert np.array_equal(culled.depth, full.depth)
    assert np.array_equal(culled.colour, full.colour)
    sc, sf = culled.stats["billboards"], full.stats["billboards"]
    assert sc["pixels"] == sf["pixels"] > 0
    assert sc["covered_pixels"] == sf["covered_pixels"]
    if scale >= 1.0:  # close up: the cost follows what is shown, not the rectangles
        assert sc["span_pixels"] <= 0.7 * sf["span_pixels"]
        assert sc["span_pixels"] <= 3.5 * sc["pixels"]


def test_a_clouds_tiles_mark_exactly_the_tiles_holding_a_texel(two_boxes):
    """BillboardCloud.tiles: per billboard, TILE x TILE texel tiles with any alpha > 0."""
    from service.simplify.billboard import LAYERS, TILE

    grid, start = two_boxes.tiles
    assert start[-1] == grid.size
    for p in range(two_boxes.n_billboards):
        rows, cols = (int(x) for x in two_boxes.tex_shape[p])
        tr, tc = -(-rows // TILE), -(-cols // TILE)
        alpha = two_boxes.texture(p)[0][..., 3].reshape(LAYERS, rows, cols).max(axis=0)
        padded = np.zeros((tr * TILE, tc * TILE), alpha.dtype)
        padded[:rows, :cols] = alpha
        want = padded.reshape(tr, TILE, tc, TILE).max(axis=(1, 3)) > 0
        assert np.array_equal(grid[start[p]:start[p + 1]].reshape(tr, tc) > 0, want)
    assert (grid == 0).any() and (grid == 1).any()
