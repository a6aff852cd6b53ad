"""The per-pixel motion kernels of ``motion_field`` against plain numpy formulas."""

import dataclasses

import numpy as np
import pytest

from service.builtin_scenes import game_scene
from service.display import DisplaySettings
from service.galilean.galpixmap import RGB_TO_ABC
from service.galilean.motion_field import (
    colour_derivatives,
    interpolate,
    render_with_motion,
    vertex_derivatives,
)
from service.render.pipeline import Renderer, RenderSettings
from service.render.scene import MotionState
from service.scene_motion import scene_at


def reference_interpolate(tri_map, triangles, proj, vd):
    """Barycentrics of each pixel centre in its triangle, one formula per pixel."""
    nz, nr, nc = tri_map.shape
    out = np.zeros((3, 3, nz, nr, nc))
    for z, r, c in zip(*np.nonzero(tri_map >= 0), strict=True):
        i = triangles[tri_map[z, r, c]]
        (ax, ay), (bx, by), (cx, cy) = proj[z, i, :2]
        det = (bx - ax) * (cy - ay) - (cx - ax) * (by - ay)
        w1 = w2 = 1.0 / 3.0
        if det != 0.0:
            x, y = c + 0.5, r + 0.5
            w1 = ((x - ax) * (cy - ay) - (cx - ax) * (y - ay)) / det
            w2 = ((bx - ax) * (y - ay) - (x - ax) * (by - ay)) / det
        w = np.array([1.0 - w1 - w2, w1, w2])
        out[:, :, z, r, c] = np.einsum("v,kvd->kd", w, vd[:, z, i])
    return out


def test_interpolate_matches_per_pixel_barycentrics():
    display = DisplaySettings(zones=3, cols=40, rows=30)
    arrays = scene_at(game_scene(), 0.0).flatten()
    vis, _, _ = Renderer().visibility(arrays, display, RenderSettings())
    rng = np.random.default_rng(5)
    proj = np.stack([np.c_[rng.uniform(0, 40, (len(arrays.vertices), 2)),
                           rng.uniform(0, 1, len(arrays.vertices))]] * 3)
    proj[1, arrays.triangles[0]] = proj[1, arrays.triangles[0][0]]  # a zero-area triangle
    vd = rng.normal(0, 3, (3, 3, len(arrays.vertices), 3))
    tri = np.ascontiguousarray(vis.triangle, np.int32)
    tri[1, 5, :] = 0  # a row of the degenerate triangle in zone 1
    got = interpolate(tri, arrays.triangles, proj, vd)
    want = reference_interpolate(tri, arrays.triangles, proj, vd)
    assert got.dtype == np.float32 and got.shape == (3, 3, 3, 30, 40)
    assert (tri >= 0).sum() > 300 and (got[:, :, tri < 0] == 0).all()
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-3)
    # the degenerate triangle shows its vertices' mean
    np.testing.assert_allclose(got[:, :, 1, 5, 0], vd[:, 1, arrays.triangles[0]].mean(axis=1),
                               rtol=1e-5, atol=1e-5)


def test_colour_derivatives_are_central_differences_in_abc():
    rng = np.random.default_rng(2)
    m, c, p = (rng.uniform(0, 1, (2, 7, 9, 3)).astype(np.float32) for _ in range(3))
    h = 0.25
    got = colour_derivatives([m, c, p], h)
    m, c, p = (f.astype(np.float64) * 255.0 for f in (m, c, p))
    d1 = np.moveaxis((p - m) / (2 * h) @ RGB_TO_ABC.T, -1, 0)
    d2a = (p - 2 * c + m) / h**2 @ RGB_TO_ABC[0]
    assert got.shape == (4, 2, 7, 9) and got.dtype == np.float32
    np.testing.assert_allclose(got[:3], d1, rtol=1e-5, atol=1e-3)
    np.testing.assert_allclose(got[3], d2a, rtol=1e-5, atol=1e-2)


def test_colour_derivatives_reject_mismatched_frames():
    f = np.zeros((1, 4, 4, 3), np.float32)
    with pytest.raises(ValueError, match="3 frames"):
        colour_derivatives([f, f, np.zeros((1, 4, 5, 3), np.float32)], 0.25)
    with pytest.raises(ValueError, match="3 frames"):
        colour_derivatives([f, f], 0.25)


def test_render_with_motion_of_a_still_scene_has_no_motion():
    display = DisplaySettings(zones=2, cols=32, rows=24)
    scene = game_scene()
    scene.objects[:] = [dataclasses.replace(o, motion=MotionState()) for o in scene.objects]
    up = render_with_motion(Renderer(), scene, display, 0.0, 60.0)
    assert (up.obj >= 0).any()
    assert np.abs(up.derivatives).max() < 1e-6 and np.abs(up.dcolour).max() < 1e-3
    projs = np.stack([np.zeros((2, 4, 3))] * 5)
    assert (vertex_derivatives(projs, 0.25) == 0).all()
