from collections import Counter

import numpy as np
import pytest

from service.base.errors import SettingsError
from service.builtin_scenes import c_shape
from service.primitives import (
    PRIMITIVES,
    attacker,
    cube,
    geodesic_sphere,
    lathe,
    player,
    signed_volume,
    sphere,
    torus,
)
from service.render.mesh import Mesh


def directed_edges(mesh: Mesh) -> Counter:
    edges = Counter()
    for row, k in zip(mesh.polygons, mesh.counts, strict=True):
        ring = [int(i) for i in row[:k]]
        edges.update(zip(ring, ring[1:] + ring[:1], strict=True))
    return edges


def assert_closed_outward(mesh: Mesh) -> None:
    edges = directed_edges(mesh)
    assert all(n == 1 for n in edges.values()), "an edge is walked twice the same way"
    assert all(edges[(b, a)] == 1 for a, b in edges), "an edge is not shared by two faces"
    assert signed_volume(mesh.vertices, mesh.polygons, mesh.counts) > 0
    assert np.all(np.linalg.norm(mesh.normals, axis=1) > 0.99), "degenerate polygon"


MESHES = {
    "cube": lambda: cube(0.7),
    "sphere": lambda: sphere(0.4, 8, 12),
    "sphere-min": lambda: sphere(1.0, 2, 3),
    "torus": lambda: torus(0.5, 0.2, 10, 6),
    "player-1": lambda: player(1),
    "player-4": lambda: player(4),
    "attacker-1": lambda: attacker(1),
    "attacker-6": lambda: attacker(6),
    "c-shape": c_shape,
    "lathe-capped": lambda: lathe(np.array([[0.2, 0.5], [0.3, 0.0], [0.1, -0.5]]), 7),
}


@pytest.mark.parametrize("name", sorted(MESHES))
def test_closed_and_wound_outward(name):
    assert_closed_outward(MESHES[name]())


@pytest.mark.parametrize("name", ["cube", "sphere", "torus"])
def test_normals_point_away_from_centre(name):
    # each polygon's normal points away from the origin (or, for the torus, from the
    # nearest point of its centre circle of radius 0.5 in the z = 0 plane)
    mesh = MESHES[name]()
    pairs = zip(mesh.polygons, mesh.counts, strict=True)
    cen = np.array([mesh.vertices[r[:k]].mean(0) for r, k in pairs])
    if name == "torus":
        ring = cen * [1, 1, 0]
        cen = cen - 0.5 * ring / np.linalg.norm(ring, axis=1, keepdims=True)
    assert np.all(np.einsum("ij,ij->i", mesh.normals, cen) > 0)


def test_volumes_match_formulas():
    c = cube(2.0)
    assert signed_volume(c.vertices, c.polygons, c.counts) == pytest.approx(8.0)
    s = sphere(1.0, 64, 128)
    assert signed_volume(s.vertices, s.polygons, s.counts) == pytest.approx(4 / 3 * np.pi, 2e-3)
    t = torus(1.0, 0.25, 128, 64)
    expect = 2 * np.pi**2 * 1.0 * 0.25**2
    assert signed_volume(t.vertices, t.polygons, t.counts) == pytest.approx(expect, 5e-3)


def test_polygon_counts_follow_parameters():
    assert cube().n_polygons == 6
    s = sphere(1.0, 10, 20)
    assert s.n_polygons == 20 * 8 + 2 * 20
    assert sorted(Counter(s.counts.tolist()).items()) == [(3, 40), (4, 160)]
    assert torus(1.0, 0.3, 12, 5).n_polygons == 60
    assert attacker(8).n_polygons == 1280
    assert player(2).n_polygons < player(4).n_polygons < 2000


def test_geodesic_sphere_is_welded_unit_sphere():
    verts, tris = geodesic_sphere(4)
    assert verts.shape == (10 * 16 + 2, 3) and tris.shape == (320, 3)
    assert np.allclose(np.linalg.norm(verts, axis=1), 1.0)
    assert len(np.unique(np.round(verts, 9), axis=0)) == len(verts)


def test_attacker_is_spiky_and_player_points_up():
    a = attacker(8, radius=0.1, spike=0.9)
    r = np.linalg.norm(a.vertices, axis=1)
    assert r.min() == pytest.approx(0.1) and r.max() == pytest.approx(0.19)
    p = player(3, size=0.35)
    top = p.vertices[np.argmax(p.vertices[:, 1])]
    assert np.allclose(top[[0, 2]], 0.0) and top[1] == pytest.approx(0.175)
    assert np.ptp(p.vertices[:, 0]) > 0.25  # the wings spread sideways


@pytest.mark.parametrize(
    "build",
    [
        lambda: cube(0),
        lambda: sphere(-1),
        lambda: sphere(1, 1, 8),
        lambda: torus(0.2, 0.3),
        lambda: player(0),
        lambda: attacker(2.5),
        lambda: attacker(radius=float("nan")),
    ],
)
def test_bad_parameters_raise_settings_error(build):
    with pytest.raises(SettingsError):
        build()


@pytest.mark.parametrize("build", [
    lambda: sphere(1.0, 100_000, 100_000), lambda: torus(1.0, 0.3, 2001, 2000),
    lambda: player(500), lambda: attacker(500),
])
def test_a_resolution_past_the_polygon_limit_is_refused_before_allocating(build):
    # sphere(1, 1e5, 1e5) asked for 10^10 polygons: the process was killed for memory
    with pytest.raises(SettingsError, match=r"would have [\d,]+ polygons \(at most 4,000,000\)"):
        build()


def test_primitive_table_names_builders():
    assert set(PRIMITIVES) == {"cube", "sphere", "torus", "player", "attacker"}
    for build in PRIMITIVES.values():
        assert isinstance(build(), Mesh)
