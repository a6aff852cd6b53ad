"""render_with_motion's one-pass update against the update rendered five times over.

The reference is the update as it was built before issue 34: the scene placed and
flattened at ``t - 2h .. t + 2h``, projected at each, the vertex derivatives from
those projections (:func:`vertex_derivatives`), :func:`interpolate` across the
visibility at ``t``, light at ``t - h, t, t + h`` (:func:`shade_linear`) and its
central differences (:func:`colour_derivatives`).  The one-pass update takes the
motion from the motion states and flat light's derivatives by the chain rule, so:

* colour, depth and the object map are the same bit for bit;
* motion derivatives agree within ``1e-6 + 1e-5 |ref|`` (px, depth units per
  refresh^n; the differences are the finite differences' rounding, about 1e-9);
* flat light's colour derivatives agree with central differences at h = 1/50
  refresh within 1e-3 (dA, dB, dC, 0..255 per refresh) and 5e-2 (d2A per
  refresh^2: float32 colours differenced over 1/50 refresh round to about 0.03),
  wherever the differences have converged (they agree with those at twice the
  step): across a kink of the light within the step (a channel reaching 1, a
  highlight or a light coming on) central differences give a mean slope, the chain
  rule the slope at ``t`` (docs/galilean.md);
* per-vertex and per-point light still take central differences: equal bit for bit.
"""

from dataclasses import replace

import numpy as np
import pytest

from service.builtin_scenes import builtin_scene
from service.display import DisplaySettings
from service.galilean.motion_field import (
    colour_derivatives,
    interpolate,
    render_with_motion,
    vertex_derivatives,
    vertex_motion,
    vertex_object,
)
from service.render.light import LightSettings, shade, shade_linear
from service.render.pipeline import Renderer, RenderSettings
from service.render.projection import project
from service.render.scene import MotionState, Transform, euler_quaternion, flatten
from service.scene_motion import advance_scene, motion_derivatives, placements, scene_at

DISPLAY = DisplaySettings(zones=5, cols=64, rows=48)
VIEWER = (Transform(np.array([0.1, 0.0, 0.3]), euler_quaternion(0.05, 0.02, 0.0)),
          MotionState(np.array([0.2, 0.1, 0.0]), np.zeros(3), np.array([0.0, 0.6, 0.1]),
                      np.zeros(3)))
#: Tolerances (see the module notes): motion atol, rtol; dA dB dC; d2A; the step.
MOTION_TOL, DCOLOUR_TOL, D2A_TOL, FINE_H = (1e-6, 1e-5), 1e-3, 5e-2, 0.02


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


def assert_colour_motion_converged(got, ref, ref2, covered):
    """``got`` within tolerance of ``ref`` where ``ref`` and ``ref2`` (twice the step) agree."""
    tol = np.array([DCOLOUR_TOL] * 3 + [D2A_TOL])[:, None, None, None]
    converged = (np.abs(ref - ref2) <= tol).all(axis=0) & covered
    assert converged.mean() > 0.97 * covered.mean()  # kinks are rare
    assert (np.abs(got - ref) <= tol)[:, converged].all()
    assert (got[:, ~covered] == 0).all()


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
def test_one_pass_update_matches_the_five_render_update(name, settings, moving_viewer,
                                                        colour_motion):
    scene = builtin_scene(name)
    viewer = VIEWER if moving_viewer else (None, None)
    want = reference_update(scene, DISPLAY, 0.1, 60.0, settings, *viewer, colour_motion)
    for order in (3, 2):
        up = render_with_motion(Renderer(), builtin_scene(name), DISPLAY, 0.1, 60.0, settings,
                                *viewer, colour_motion=colour_motion, order=order)
        for label, a, b in zip(("colour", "depth", "obj"), (want[0], want[1], want[4]),
                               (up.frame.colour, up.frame.depth, up.obj), strict=True):
            assert a.shape == b.shape and np.array_equal(a, b), label
        assert up.derivatives.shape == (order, 3, *DISPLAY_SHAPE)
        np.testing.assert_allclose(up.derivatives, want[2][:order], rtol=MOTION_TOL[1],
                                   atol=MOTION_TOL[0])
        assert np.abs(up.derivatives).max() > 0
    if not colour_motion:
        assert up.dcolour is None
    elif settings.light.evaluation != "polygon":
        assert np.array_equal(up.dcolour, want[3])
    else:
        fine = [reference_update(scene, DISPLAY, 0.1, 60.0, settings, *viewer, True, h)[3]
                for h in (FINE_H, 2 * FINE_H)]
        assert_colour_motion_converged(up.dcolour, *fine, up.obj >= 0)
        assert np.abs(up.dcolour).max() > 0


DISPLAY_SHAPE = (DISPLAY.zones, DISPLAY.rows, DISPLAY.cols)


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


def test_vertex_motion_is_the_derivative_of_the_projection():
    scene = builtin_scene("game")
    for viewer in ((None, None), VIEWER):
        verts = np.stack([scene_at(scene, 0.1 + k / 600, *viewer).flatten().vertices
                          for k in range(-2, 3)])
        want = vertex_derivatives(np.stack([project(v, DISPLAY) for v in verts]), 0.1)
        rates = motion_derivatives(scene, 0.1, 1 / 60, *viewer)
        got = vertex_motion(verts[2], vertex_object(scene), rates, DISPLAY)
        np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-8)


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


def test_flat_light_uses_the_normals_a_level_of_detail_carries():
    """A mesh carrying shading normals (a level's, its full mesh's) is lit with them, as
    Renderer.render lights it; its colour derivatives come from them too."""
    from service.primitives import sphere
    from service.render.mesh import Mesh, Shading
    from service.render.scene import Light, Material, Scene, SceneObject

    ball = sphere(0.5, 8, 12)
    turn = np.array([[0.96, -0.28, 0.0], [0.28, 0.96, 0.0], [0.0, 0.0, 1.0]])
    carried = Mesh(ball.vertices, ball.polygons, ball.counts, "carried",
                   shading=Shading(ball.normals @ turn.T))
    lights = [Light("directional", np.array([0.4, 0.6, 1.0]), (1.0, 1.0, 1.0), 0.9)]
    spin = MotionState(angular_velocity=np.array([0.0, 2.0, 0.5]))
    for mesh in (ball, carried):
        scene = Scene([SceneObject(mesh, Material((0.8, 0.7, 0.55), 0.2, 0.7, 0.4, 5.0),
                                   Transform(np.array([0.0, 0.0, -1.0])), spin)], lights, 1.0)
        up = render_with_motion(Renderer(), scene, DISPLAY, 0.1, 60.0, order=2)
        frame = Renderer().render(scene_at(scene, 0.1), DISPLAY)
        assert np.array_equal(up.frame.colour, frame.colour)
        fine = [reference_update(scene, DISPLAY, 0.1, 60.0, RenderSettings(), h=h)[3]
                for h in (2 * FINE_H, 4 * FINE_H)]  # no kinks here: less float32 noise
        assert_colour_motion_converged(up.dcolour, *fine, up.obj >= 0)
