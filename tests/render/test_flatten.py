"""The vectorised flatten: the same polygon list as a per-object build, any mesh mix."""

import numpy as np
import pytest

from service.primitives import cube, sphere
from service.render.mesh import Mesh
from service.render.scene import Material, Scene, SceneObject, Transform, quaternion_matrix


def _per_object(scene: Scene) -> dict:
    """The plain per-object build the vectorised flatten must equal."""
    verts, polys, tris, tri_poly, objs, normals = [], [], [], [], [], []
    v_off = p_off = 0
    k = max(o.mesh.polygons.shape[1] for o in scene.objects)
    for i, o in enumerate(scene.objects):
        m, t = o.mesh, o.transform
        rot = quaternion_matrix(t.orientation)
        verts.append(m.vertices @ (rot * t.scale).T + t.position)
        normals.append(m.normals @ rot.T)
        pad = np.full((m.n_polygons, k), -1)
        pad[:, : m.polygons.shape[1]] = np.where(m.polygons >= 0, m.polygons + v_off, -1)
        polys.append(pad)
        tris.append(m.triangles + v_off)
        tri_poly.append(m.triangle_polygon + p_off)
        objs.append(np.full(m.n_polygons, i))
        v_off += m.n_vertices
        p_off += m.n_polygons
    return {"vertices": np.concatenate(verts), "polygons": np.concatenate(polys),
            "triangles": np.concatenate(tris), "triangle_polygon": np.concatenate(tri_poly),
            "polygon_object": np.concatenate(objs), "normals": np.concatenate(normals)}


def _mixed_scene(rng: np.random.Generator) -> Scene:
    ball, box = sphere(0.2, 6, 8), cube(0.3)
    quad = Mesh.from_polygons([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0]],
                              [[0, 1, 2, 3], [1, 4, 2]])
    meshes = [ball, ball, box, ball, quad, quad, box, box, box]
    return Scene([
        SceneObject(m, Material((0.1 * i % 1, 0.5, 0.5)),
                    Transform(rng.normal(size=3), rng.normal(size=4), 0.5 + rng.random()))
        for i, m in enumerate(meshes)
    ])


@pytest.mark.parametrize("seed", [0, 1])
def test_flatten_equals_the_per_object_build(seed: int) -> None:
    scene = _mixed_scene(np.random.default_rng(seed))
    got, want = scene.flatten(), _per_object(scene)
    np.testing.assert_array_equal(got.polygons, want["polygons"])
    np.testing.assert_array_equal(got.triangles, want["triangles"])
    np.testing.assert_array_equal(got.triangle_polygon, want["triangle_polygon"])
    np.testing.assert_array_equal(got.polygon_object, want["polygon_object"])
    np.testing.assert_allclose(got.vertices, want["vertices"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(got.normals, want["normals"], rtol=0, atol=1e-12)
    assert got.materials[got.polygon_object == 2, 0] == pytest.approx(0.2)
    # moving the objects re-uses the static parts and still matches
    scene.objects = scene.objects[::-1]
    np.testing.assert_allclose(scene.flatten().vertices, _per_object(scene)["vertices"],
                               atol=1e-12)


def test_flatten_of_an_empty_scene() -> None:
    arrays = Scene([]).flatten()
    assert arrays.vertices.shape == (0, 3) and arrays.triangles.shape == (0, 3)
