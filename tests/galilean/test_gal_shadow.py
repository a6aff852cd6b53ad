"""Depth-only shadow rendering (section 4.2) against the full renderer."""

import numpy as np
import pytest
from gal_scenes import DISP, FLAT, HZ, box

from service.galilean.fixed_point import FixedPoint, bit_budget
from service.galilean.local_update import render_local
from service.galilean.shadow import shadow_depth
from service.render.pipeline import Renderer
from service.render.scene import Scene
from service.scene_motion import advance_scene, control_points


def two_boxes() -> Scene:
    back = box([0.0, 0.0, -1.0], 0.8, (0.2, 0.2, 0.9), velocity=[0.3, 0, 0])
    front = box([0.1, 0.0, -0.2], 0.4, (0.9, 0.9, 0.1))
    return Scene([back, front], ambient=1.0)


def three_boxes() -> Scene:
    s = two_boxes()
    side = box([-0.35, 0.1, -0.4], 0.3, (0.1, 0.8, 0.2), velocity=[0.0, 0.4, 0.1])
    return Scene([*s.objects, side], ambient=1.0)


def test_shadow_depth_covers_the_renderers_pixels_at_its_depth():
    scene = three_boxes()
    t = 2 / HZ
    full = Renderer().render(advance_scene(scene, t), DISP, FLAT)
    depth, obj = shadow_depth(scene, range(3), DISP, t, FLAT.cull)
    assert depth.dtype == np.float32 and obj.dtype == np.int32
    np.testing.assert_array_equal(depth, full.depth)
    assert set(np.unique(obj)) == {-1, 0, 1, 2}
    assert ((obj >= 0) == np.isfinite(depth)).all()


def test_shadow_depth_of_no_objects_is_empty():
    depth, obj = shadow_depth(three_boxes(), [], DISP)
    assert np.isinf(depth).all() and (obj == -1).all()


@pytest.mark.parametrize("objects", [[0], [2, 0]])
def test_depth_only_local_render_grafts_what_the_full_one_does(objects):
    scene = three_boxes()
    fixed = FixedPoint.for_order(bit_budget(48, 16, 16), 2)
    ctl = control_points(scene, 2 / HZ, DISP)
    kw = dict(settings=FLAT, control=ctl)
    a = render_local(Renderer(), scene, DISP, objects, 2 / HZ, HZ, 2, fixed, shadow="depth", **kw)
    b = render_local(Renderer(), scene, DISP, objects, 2 / HZ, HZ, 2, fixed, shadow="full", **kw)
    assert a.shadowed == b.shadowed and a.shadowed
    np.testing.assert_array_equal(a.buffer.debris, b.buffer.debris)
    np.testing.assert_array_equal(a.buffer.depth, b.buffer.depth)
    np.testing.assert_array_equal(a.buffer.obj, b.buffer.obj)
    take = a.buffer.debris == 0
    assert take.any()
    for name in ("colour", "frac", "motion", "zmotion", "dcolour"):
        np.testing.assert_array_equal(getattr(a.buffer, name)[:, take],
                                      getattr(b.buffer, name)[:, take])
    shadowed = a.buffer.debris.astype(bool) & (a.buffer.obj >= 0)
    assert shadowed.any() and (a.buffer.colour[:, shadowed] == 0).all()  # debris colour


def test_unknown_shadow_mode_is_refused():
    fixed = FixedPoint.for_order(bit_budget(48, 16, 16), 2)
    with pytest.raises(ValueError, match="shadow"):
        render_local(Renderer(), two_boxes(), DISP, [0], 0.0, HZ, 2, fixed, shadow="colour")
