"""The planar-and-convex rule for polygons of 4 or more corners (service.render.mesh)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import service.render.mesh as mesh_module
from service.base.errors import MeshError
from service.builtin_scenes import SCENES, c_shape
from service.primitives import PRIMITIVES
from service.render.mesh import CONVEX, PLANAR, SHAPE_TOL, Mesh, polygon_shape_faults

TRIANGLE = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
BAD = {  # polygon 1 of a two-polygon mesh; polygon 0 is TRIANGLE
    "concave": ([[0, 0, 1], [2, 0, 1], [0.5, 0.5, 1], [0, 2, 1]], CONVEX),
    "non-planar": ([[0, 0, 1], [2, 0, 1], [2, 2, 1.2], [0, 2, 1]], PLANAR),
    "bow-tie": ([[0, 0, 1], [2, 2, 1], [2, 0, 1], [0, 2, 1]], CONVEX),
    "pentagram": ([[np.cos(a), np.sin(a), 1] for a in np.radians(90 + 144 * np.arange(5))],
                  CONVEX),
    "doubles back": ([[0, 0, 1], [2, 0, 1], [3, 0, 1], [1, 0, 1], [0, 1, 1]], CONVEX),
    "repeated reflex corner": ([[0, 0, 1], [2, 0, 1], [0.5, 0.5, 1], [0.5, 0.5, 1], [0, 2, 1]],
                               CONVEX),
}
GOOD = {
    "square": [[0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]],
    "clockwise square": [[0, 0, 1], [0, 1, 1], [1, 1, 1], [1, 0, 1]],
    "pentagon, collinear corner": [[0, 0, 1], [1, 0, 1], [2, 0, 1], [2, 2, 1], [0, 2, 1]],
    "repeated corner": [[0, 0, 1], [1, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]],
    "noisy square": [[0, 0, 1 + 1e-7], [1, 0, 1 - 1e-7], [1, 1 + 1e-7, 1], [0, 1, 1]],
    "all on a line": [[0, 0, 1], [1, 0, 1], [2, 0, 1], [3, 0, 1]],  # zero area: not checked
}


def two_polygons(corners: list) -> Mesh:
    verts = np.array(TRIANGLE + list(corners), dtype=float)
    return Mesh.from_polygons(verts, [[0, 1, 2], list(range(3, 3 + len(corners)))], "two")


@pytest.mark.parametrize("name", sorted(BAD))
def test_bad_polygon_raises_naming_mesh_and_polygon(name):
    corners, kind = BAD[name]
    with pytest.raises(MeshError, match=r"^two: polygon 1 is not (planar|convex)") as info:
        two_polygons(corners)
    assert ("not planar" if kind == PLANAR else "not convex") in str(info.value)
    verts = np.array(TRIANGLE + list(corners), dtype=float)
    polys = np.array([[0, 1, 2] + [-1] * (len(corners) - 3), list(range(3, 3 + len(corners)))])
    faults = polygon_shape_faults(verts, polys, np.array([3, len(corners)]))
    assert faults.polygon.tolist() == [1] and faults.kind.tolist() == [kind]
    assert faults.deviation[0] > faults.tolerance


@pytest.mark.parametrize("name", sorted(GOOD))
def test_good_polygon_builds(name):
    mesh = two_polygons(GOOD[name])
    assert mesh.triangles.shape == (1 + len(GOOD[name]) - 2, 3)


def test_tolerance_is_relative_to_the_mesh_extent():
    square = np.array(GOOD["square"], float)  # extent 1
    for lift, ok in ((SHAPE_TOL, True), (8 * SHAPE_TOL, False)):
        lifted = square.copy()
        lifted[2, 2] += lift  # every corner ends lift / 4 off the polygon's plane
        for scale, offset in ((1.0, 0.0), (1e-6, 5e-6), (1e6, -3e6)):
            faults = polygon_shape_faults(lifted * scale + offset, np.arange(4)[None, :],
                                          np.array([4]))
            assert faults.tolerance == pytest.approx(SHAPE_TOL * scale)
            assert faults.kind.tolist() == ([] if ok else [PLANAR])


def test_first_fault_reported_across_sizes_and_chunks(monkeypatch):
    monkeypatch.setattr(mesh_module, "SHAPE_CHUNK", 16)  # one polygon per vectorised step
    polys, verts = [], []
    for p in range(12):  # squares, pentagons and triangles side by side along x
        corners = GOOD["pentagon, collinear corner"] if p % 3 == 0 else GOOD["square"]
        corners = TRIANGLE if p % 3 == 2 else corners
        if p in (5, 9):
            corners = BAD["concave"][0] if p == 9 else BAD["doubles back"][0]
        polys.append(list(range(len(verts), len(verts) + len(corners))))
        verts += [[x + 4 * p, y, z] for x, y, z in corners]
    with pytest.raises(MeshError, match=r"polygon 5 is not convex.*; 1 more polygon"):
        Mesh.from_polygons(np.array(verts, float), polys)


def test_every_builtin_primitive_and_scene_is_exactly_planar_and_convex():
    meshes = [build() for build in PRIMITIVES.values()] + [c_shape()]
    meshes += [obj.mesh for build in SCENES.values() for obj in build().objects]
    for mesh in meshes:
        extent = float(np.ptp(mesh.vertices, axis=0).max())
        faults = polygon_shape_faults(mesh.vertices, mesh.polygons, mesh.counts, 1e-9 * extent)
        assert faults.polygon.size == 0, mesh.name


def circle_polygon(k: int, gaps: list, radius: float, axis: list, offset: list) -> np.ndarray:
    """k corners on a circle, counter-clockwise about a random normal, shape (k, 3)."""
    angles = 2 * np.pi * np.cumsum(gaps[:k]) / np.sum(gaps[:k])
    normal = np.array(axis) / np.linalg.norm(axis)
    u = np.cross(normal, np.eye(3)[np.abs(normal).argmin()])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    pts = radius * (np.cos(angles)[:, None] * u + np.sin(angles)[:, None] * v)
    return pts + np.array(offset) * radius


CIRCLES = dict(
    k=st.integers(4, 12),
    gaps=st.lists(st.floats(0.2, 1.0), min_size=12, max_size=12),
    radius=st.floats(1e-3, 1e3),
    axis=st.lists(st.floats(-1, 1), min_size=3, max_size=3).filter(
        lambda a: np.linalg.norm(a) > 0.1
    ),
    offset=st.lists(st.floats(-50, 50), min_size=3, max_size=3),
    corner=st.integers(0, 11),
)


@settings(max_examples=200, deadline=None)
@given(**CIRCLES)
def test_random_convex_planar_polygons_pass(k, gaps, radius, axis, offset, corner):
    pts = circle_polygon(k, gaps, radius, axis, offset)
    for order in (list(range(k)), list(range(k))[::-1]):
        Mesh.from_polygons(pts, [order])


@settings(max_examples=200, deadline=None)
@given(**CIRCLES)
def test_random_dented_or_lifted_polygons_fail(k, gaps, radius, axis, offset, corner):
    pts = circle_polygon(k, gaps, radius, axis, offset)
    i = corner % k
    chord_mid = (pts[i - 1] + pts[(i + 1) % k]) / 2
    dented = pts.copy()
    dented[i] = chord_mid + 0.5 * (chord_mid - pts[i])  # past the chord: a reflex corner
    faults = polygon_shape_faults(dented, np.arange(k)[None, :], np.array([k]))
    assert faults.kind.tolist() == [CONVEX]
    lifted = pts.copy()
    lifted[i] += 0.01 * radius * np.array(axis) / np.linalg.norm(axis)
    faults = polygon_shape_faults(lifted, np.arange(k)[None, :], np.array([k]))
    assert faults.kind.tolist() == [PLANAR]


@pytest.mark.parametrize("scale", [1e31, 1e150, 1e300])
def test_coordinates_too_large_for_the_geometry_are_refused(scale):
    verts = np.array(TRIANGLE, dtype=float) * scale
    with pytest.raises(MeshError,
                       match=r"^big: vertex 1: coordinate .* beyond 1e\+30: .*scale the mesh down"):
        Mesh.from_polygons(verts, [[0, 1, 2]], "big")


def test_large_coordinates_below_the_limit_render_as_small_ones(tmp_path):
    from service.display import DisplaySettings
    from service.loaders import load_scene, save_obj
    from service.render.pipeline import Renderer, RenderSettings

    def frame(scale):  # a mesh file is centred and scaled to fit the display
        tet = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float) * scale
        path = tmp_path / f"tet-{scale:g}.obj"
        save_obj(path, Mesh.from_polygons(tet, [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]))
        return Renderer().render(load_scene(path), DisplaySettings(cols=64, rows=48),
                                 RenderSettings())

    small, big = frame(1.0), frame(mesh_module.MAX_COORDINATE / 2)
    assert (small.depth < np.inf).any()
    np.testing.assert_array_equal(big.depth < np.inf, small.depth < np.inf)
    np.testing.assert_allclose(big.colour, small.colour, atol=1)
