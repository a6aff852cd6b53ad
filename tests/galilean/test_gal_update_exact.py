"""render_with_motion's one-pass update against the update rendered five times over.

The reference is the update as it was built before issue 34: the scene placed and
flattened at ``t - 2h .. t + 2h``, projected at each, the vertex derivatives from
those projections (:func:`vertex_derivatives`), :func:`interpolate` across the
visibility at ``t``, light at ``t - h, t, t + h`` (:func:`shade_linear`) and its
central differences (:func:`colour_derivatives`).  The one-pass update must give
the same galpixmap bit for bit: every map, every light model and evaluation, with
a moving viewer and without colour motion.
"""

from dataclasses import replace

import numpy as np
import pytest

from service.builtin_scenes import builtin_scene
from service.display import DisplaySettings
from service.galilean.motion_field import (
    colour_derivatives,
    interpolate,
    project_motion,
    render_with_motion,
    vertex_derivatives,
)
from service.render.light import LightSettings, shade, shade_linear
from service.render.pipeline import Renderer, RenderSettings
from service.render.projection import project
from service.render.scene import MotionState, Transform, euler_quaternion, flatten
from service.scene_motion import advance_scene, placements, scene_at

DISPLAY = DisplaySettings(zones=5, cols=64, rows=48)
VIEWER = (Transform(np.array([0.1, 0.0, 0.3]), euler_quaternion(0.05, 0.02, 0.0)),
          MotionState(np.array([0.2, 0.1, 0.0]), np.zeros(3), np.array([0.0, 0.6, 0.1]),
                      np.zeros(3)))


def reference_update(scene, display, t, hz, settings, viewer=None, motion=None,
                     colour_motion=True, h=0.25):
    """Colour, depth, derivatives, colour derivatives and object map, five renders' way."""
    scenes = [scene_at(scene, t + k * h / hz, viewer, motion) for k in (-2, -1, 0, 1, 2)]
    arrays = [s.flatten() for s in scenes]
    projs = np.stack([project(a.vertices, display) for a in arrays])
    vis, _, _ = Renderer().visibility(arrays[2], display, settings)
    lin = [shade_linear(arrays[i], projs[i], vis, display, scenes[i].lights, scenes[i].ambient,
                        settings.light) for i in (1, 2, 3)]
    colour = shade(arrays[2], projs[2], vis, display, scenes[2].lights, scenes[2].ambient,
                   settings.light)
    der = interpolate(vis.triangle, arrays[2].triangles, projs[2], vertex_derivatives(projs, h))
    tri = vis.triangle
    obj = np.where(tri >= 0, arrays[2].polygon_object[arrays[2].triangle_polygon[
        np.maximum(tri, 0)]], -1)
    return colour, vis.depth, der, colour_derivatives(lin, h) if colour_motion else None, obj


CASES = [
    ("game", RenderSettings(), False, True),
    ("game", RenderSettings(light=LightSettings("phong")), False, True),
    ("game", RenderSettings(light=LightSettings("ambient")), False, False),
    ("game", RenderSettings(light=LightSettings("blinn", "vertex")), False, True),
    ("game", RenderSettings(method="runlength"), True, True),
    ("cyclic", RenderSettings(light=LightSettings("blinn", "point")), True, True),
    ("cyclic", RenderSettings(), True, True),
]


@pytest.mark.parametrize(("name", "settings", "moving_viewer", "colour_motion"), CASES)
def test_one_pass_update_equals_the_five_render_update(name, settings, moving_viewer,
                                                       colour_motion):
    scene = builtin_scene(name)
    viewer = VIEWER if moving_viewer else (None, None)
    want = reference_update(scene, DISPLAY, 0.1, 60.0, settings, *viewer, colour_motion)
    up = render_with_motion(Renderer(), builtin_scene(name), DISPLAY, 0.1, 60.0, settings,
                            *viewer, colour_motion=colour_motion)
    got = (up.frame.colour, up.frame.depth, up.derivatives, up.dcolour, up.obj)
    for label, a, b in zip(("colour", "depth", "derivatives", "dcolour", "obj"), want, got,
                           strict=True):
        if a is None:
            assert b is None, label
            continue
        assert a.shape == b.shape and np.array_equal(a, b), label
    assert np.abs(up.derivatives).max() > 0 and (up.dcolour is None or
                                                 np.abs(up.dcolour).max() > 0)


def test_placements_are_scene_at_bit_for_bit():
    scene = builtin_scene("game")
    dts = [-0.01, 0.0, 0.37]
    for viewer in ((None, None), VIEWER):
        pos, quat = placements(scene, dts, *viewer)
        for i, dt in enumerate(dts):
            moved = scene_at(scene, dt, *viewer)
            assert np.array_equal(pos[i], [o.transform.position for o in moved.objects])
            assert np.array_equal(quat[i], [o.transform.orientation for o in moved.objects])
            assert np.array_equal(flatten(scene, quat[i], pos[i]).vertices,
                                  moved.flatten().vertices)


def test_project_motion_is_project_and_vertex_derivatives():
    scene = builtin_scene("game")
    verts = np.stack([advance_scene(scene, k / 240).flatten().vertices for k in range(-2, 3)])
    proj, vd = project_motion(verts, DISPLAY, 0.25)
    want = np.stack([project(v, DISPLAY) for v in verts])
    assert np.array_equal(proj, want)
    assert np.array_equal(vd, vertex_derivatives(want, 0.25))


def test_moved_scenes_share_the_flatten_cache_and_a_change_stays_their_own():
    scene = builtin_scene("game")
    scene.flatten()  # builds the placement-free arrays the moved copies share
    moved = advance_scene(scene, 0.1)
    assert moved._static is scene._static  # built once, for every moved copy
    moved.objects = moved.objects[1:]  # one object fewer in the moved scene only
    assert moved.flatten().n_polygons == scene.flatten().n_polygons - \
        scene.objects[0].mesh.n_polygons
    assert scene.flatten().n_polygons == sum(o.mesh.n_polygons for o in scene.objects)
    again = replace(scene.objects[0], name="renamed")  # same mesh and material: same cache
    scene.objects[0] = again
    assert scene.flatten().vertices.shape == advance_scene(scene, 0.0).flatten().vertices.shape
