"""Billboard clouds: every face lands on a plane within EPS, rectangles are minimal,
textures cover the faces they stand for, bad input is refused."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service.primitives import cube, sphere
from service.simplify.billboard import build_cloud
from service.simplify.errors import SimplifyError
from service.simplify.planes import PlaneSettings, choose_planes
from service.simplify.rectangle import convex_hull, min_area_rectangle


def _distances(v, f, planes, owner):
    return np.abs(np.einsum("fkd,fd->fk", v[f], planes[owner, :3]) - planes[owner, 3:4])


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n_faces=st.integers(1, 40),
       eps_frac=st.floats(0.002, 0.3), cut=st.booleans())
def test_greedy_leaves_no_face_uncovered(seed, n_faces, eps_frac, cut):
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n_faces * 2 + 3, 3))
    f = np.stack([rng.choice(v.shape[0], 3, replace=False) for _ in range(n_faces)])
    eps = eps_frac * np.linalg.norm(v.max(0) - v.min(0))
    cover = choose_planes(v, f, PlaneSettings(eps=eps, n_theta=4, n_phi=8, cut=cut))
    planes, owner = cover.planes, cover.owner
    assert owner.min() >= 0 and owner.max() < planes.shape[0]
    assert np.allclose(np.linalg.norm(planes[:, :3], axis=1), 1.0)
    assert _distances(cover.vertices, cover.faces, planes, owner).max() <= eps * (1 + 1e-9)
    assert np.array_equal(np.unique(owner), np.arange(planes.shape[0]))  # no empty plane
    # every face is covered: whole, or by pieces whose areas add up to its own
    area = 0.5 * np.linalg.norm(np.cross(v[f][:, 1] - v[f][:, 0], v[f][:, 2] - v[f][:, 0]), axis=1)
    pv = cover.vertices[cover.faces]
    parea = 0.5 * np.linalg.norm(np.cross(pv[:, 1] - pv[:, 0], pv[:, 2] - pv[:, 0]), axis=1)
    got = np.bincount(cover.parent, parea, minlength=n_faces)
    assert np.allclose(got, area, rtol=1e-6, atol=1e-9 * area.max())


def test_a_cube_needs_six_planes_and_a_sphere_more_as_eps_shrinks():
    c = cube(1.0)
    planes = choose_planes(c.vertices, c.triangles, PlaneSettings(eps=0.01)).planes
    assert planes.shape[0] == 6
    s = sphere(0.5, 16, 32)
    counts = [choose_planes(s.vertices, s.triangles, PlaneSettings(eps=e)).planes.shape[0]
              for e in (0.1, 0.03)]
    assert counts[0] < counts[1]


def test_min_area_rectangle_of_a_rotated_box():
    rng = np.random.default_rng(1)
    pts = rng.uniform([0, 0], [4, 1], size=(200, 2))
    pts = np.concatenate([pts, [[0, 0], [4, 0], [4, 1], [0, 1]]])
    a = 0.4
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    origin, axes, size = min_area_rectangle(pts @ rot.T + [3, -2])
    assert np.allclose(sorted(size), [1, 4], atol=1e-9)
    local = (pts @ rot.T + [3, -2] - origin) @ axes.T
    assert local.min() >= -1e-9 and np.all(local.max(0) <= size + 1e-9)
    assert convex_hull(pts).shape[0] == 4


def test_textures_cover_every_face_and_corners_bound_it():
    s = sphere(0.5, 12, 24)
    v, f = s.vertices, s.triangles
    cloud = build_cloud(v, f, 0.05, texture_res=64)
    assert cloud.n_billboards < f.shape[0] // 4
    assert cloud.tex_offset[-1] == cloud.rgba.shape[0] == cloud.normal.shape[0]
    # every face centroid, projected on some billboard, falls on an opaque texel
    cent = v[f].mean(1)
    seen = np.zeros(f.shape[0], bool)
    for p in range(cloud.n_billboards):
        o, c1, _, c3 = cloud.corners[p]
        u_ax, v_ax = c1 - o, c3 - o
        tex, _ = cloud.texture(p)
        tex = tex.max(axis=0)  # either layer (faces on either side of the plane)
        rows, cols = tex.shape[:2]
        uu = (cent - o) @ u_ax / (u_ax @ u_ax) * cols
        vv = (cent - o) @ v_ax / (v_ax @ v_ax) * rows
        d = np.abs(cent @ cloud.planes[p, :3] - cloud.planes[p, 3])
        inside = (uu >= 0) & (uu < cols) & (vv >= 0) & (vv < rows) & (d <= cloud.eps)
        ok = np.zeros(f.shape[0], bool)
        ok[inside] = tex[vv[inside].astype(int), uu[inside].astype(int), 3] == 255
        seen |= ok
    assert seen.all()


@pytest.mark.parametrize("kw, match", [
    ({"eps": 0.0}, "EPS"), ({"eps": -1.0}, "EPS"), ({"eps": float("nan")}, "EPS"),
    ({"texture_res": 0}, "texture resolution"),
    ({"colours": np.zeros((3, 3), np.uint8)}, r"colours must have shape \(\d+, 3\), not \(3, 3\)"),
    ({"colours": np.zeros((3, 3), np.uint8), "eps": 0.0}, "EPS"),  # eps is checked first
])
def test_bad_settings_are_refused(kw, match):
    s = sphere(0.5, 6, 12)
    args = {"eps": 0.05, "texture_res": 16, **kw}
    with pytest.raises(SimplifyError, match=match):
        build_cloud(s.vertices, s.triangles, **args)


def test_no_faces_is_refused():
    with pytest.raises(SimplifyError, match="no triangles"):
        build_cloud(np.zeros((3, 3)), np.zeros((0, 3), np.int64), 0.1)
