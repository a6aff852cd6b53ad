from pathlib import Path

import numpy as np
import pytest

from service.base.errors import MeshFileError, SettingsError
from service.builtin_scenes import SCENES, builtin_scene
from service.loaders import load_scene
from service.render.scene import Scene

DOCS = Path(__file__).resolve().parents[2] / "docs" / "file-formats.md"


# --- built-in scenes --------------------------------------------------------------


@pytest.mark.parametrize("name", sorted(SCENES))
def test_builtin_scene_fits_display_and_is_lit(name):
    scene = builtin_scene(name)
    assert isinstance(scene, Scene) and scene.objects
    flat = scene.flatten()
    assert np.all(np.abs(flat.vertices[:, 0]) < 1.0)  # default width 2.0
    assert np.all(np.abs(flat.vertices[:, 1]) < 0.75)  # default height 1.5 (320x240)
    assert np.all(np.abs(flat.vertices[:, 2]) <= 0.7)
    assert any(light.kind == "directional" for light in scene.lights)
    assert np.all(np.isfinite(flat.normals))


def test_builtin_scene_unknown_name():
    with pytest.raises(SettingsError, match="game"):
        builtin_scene("nope")


def test_game_scene_has_player_and_six_attackers_within_budget():
    scene = builtin_scene("game")
    names = [o.name for o in scene.objects]
    assert names[0] == "player" and sum(n.startswith("attacker") for n in names) == 6
    assert 7000 <= scene.flatten().n_polygons <= 9000
    assert max(o.mesh.n_polygons for o in scene.objects) <= 2000  # thesis 5.1.2
    z = scene.flatten().vertices[:, 2]
    assert z.min() > -0.62 and z.max() < 0.62
    # attackers move; the player waits for the buttons
    assert all(np.any(o.motion.velocity) for o in scene.objects[1:])
    assert not np.any(scene.objects[0].motion.velocity)


def _inside(tri2: np.ndarray, pts: np.ndarray) -> np.ndarray:
    a, b, c = tri2
    def side(p, q):
        return (q[0] - p[0]) * (pts[:, 1] - p[1]) - (q[1] - p[1]) * (pts[:, 0] - p[0])
    s1, s2, s3 = side(a, b), side(b, c), side(c, a)
    return ((s1 > 0) & (s2 > 0) & (s3 > 0)) | ((s1 < 0) & (s2 < 0) & (s3 < 0))


def _depth_at(tri3: np.ndarray, pts: np.ndarray) -> np.ndarray:
    n = np.cross(tri3[1] - tri3[0], tri3[2] - tri3[0])
    return tri3[0, 2] - (n[0] * (pts[:, 0] - tri3[0, 0]) + n[1] * (pts[:, 1] - tri3[0, 1])) / n[2]


def test_cyclic_scene_overlaps_in_a_cycle_that_average_z_gets_wrong():
    scene = builtin_scene("cyclic")
    tris = [o.transform.apply(o.mesh.vertices) for o in scene.objects]
    assert len(tris) == 3 and all(t.shape == (3, 3) for t in tris)
    g = np.linspace(-1, 1, 401)
    pts = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    in_front = {}
    for i in range(3):
        for j in range(3):
            both = _inside(tris[i][:, :2], pts) & _inside(tris[j][:, :2], pts)
            if i != j and both.any():
                dz = _depth_at(tris[i], pts[both]) - _depth_at(tris[j], pts[both])
                assert np.all(dz > 0) or np.all(dz < 0), "the triangles must not interpenetrate"
                in_front[(i, j)] = bool(dz[0] > 0)
    assert in_front[(0, 1)] and in_front[(1, 2)] and in_front[(2, 0)]  # a cycle
    # painter's order by average z (far first, stable): some overlapping pair is wrong
    order = np.argsort([t[:, 2].mean() for t in tris], kind="stable")
    drawn = {int(k): n for n, k in enumerate(order)}
    wrong = [p for p, front in in_front.items() if front and drawn[p[0]] < drawn[p[1]]]
    assert wrong
    for t in tris:  # all face the viewer, so back-face culling keeps them
        assert np.cross(t[1] - t[0], t[2] - t[0])[2] > 0


def test_threaded_scene_interpenetrates():
    scene = builtin_scene("threaded")
    names = [o.name for o in scene.objects]
    rect = scene.objects[names.index("rectangle")].mesh.vertices
    c = scene.objects[names.index("c-shape")].mesh
    depth = np.ptp(c.vertices[:, 2])
    radii = np.linalg.norm(c.vertices[:, :2], axis=1)
    u, v = np.meshgrid(np.linspace(0, 1, 81), np.linspace(0, 1, 21))
    pts = (rect[0] + u[..., None] * (rect[1] - rect[0]) + v[..., None] * (rect[3] - rect[0]))
    pts = pts.reshape(-1, 3)
    r = np.linalg.norm(pts[:, :2], axis=1)
    in_ring = (r > radii.min() + 1e-6) & (r < radii.max() - 1e-6) & (pts[:, 0] < 0)
    inside = in_ring & (np.abs(pts[:, 2]) < depth / 2)
    front = in_ring & (pts[:, 2] > depth / 2)
    behind = in_ring & (pts[:, 2] < -depth / 2)
    assert inside.any() and front.any() and behind.any()
    # and it leaves through the opening on the right without touching the C
    gap = pts[pts[:, 0] > 0.25]
    ang = np.degrees(np.arctan2(gap[:, 1], gap[:, 0]))
    assert np.all(np.abs(ang) < 40)


def test_sphere_torus_and_demo_composition():
    st = builtin_scene("sphere-torus")
    assert [o.name for o in st.objects] == ["sphere", "torus"]
    demo = builtin_scene("demo")
    assert len(demo.objects) >= 5
    assert {light.kind for light in demo.lights} == {"directional", "point"}
    assert len({o.material.colour for o in demo.objects}) == len(demo.objects)
    assert sum(o.material.specular >= 0.7 for o in demo.objects) >= 2
    depths = [o.transform.position[2] for o in demo.objects]
    assert max(depths) - min(depths) > 0.8


# --- scene files ------------------------------------------------------------------


def _doc_block(first_line: str) -> str:
    """The fenced code block of docs/file-formats.md that starts with ``first_line``."""
    blocks, current = [], None
    for line in DOCS.read_text().splitlines():
        if line.startswith("```"):
            if current is None:
                current = []
            else:
                blocks.append("\n".join(current) + "\n")
                current = None
        elif current is not None:
            current.append(line)
    return next(b for b in blocks if b.startswith(first_line))


@pytest.fixture
def scene_dir(tmp_path):
    (tmp_path / "pyramid.hobj").write_text(_doc_block("# pyramid.hobj"))
    (tmp_path / "scene.toml").write_text(_doc_block("# scene.toml"))
    return tmp_path


def test_documented_example_scene_loads(scene_dir):
    scene = load_scene(scene_dir / "scene.toml")
    assert [o.name for o in scene.objects] == ["ball", "ring", "pyramid"]
    assert [light.kind for light in scene.lights] == ["directional", "point"]
    assert scene.ambient == 0.9
    ball, ring, pyr = scene.objects
    assert ball.mesh.n_polygons == 16 * 32 - 2 * 32 + 2 * 32
    assert ball.material.colour == (0.9, 0.2, 0.2) and ball.material.shininess == 5
    assert np.allclose(ball.motion.velocity, [0.1, 0, 0])
    assert np.allclose(ring.motion.angular_velocity, [0, 1, 0])
    assert not np.allclose(ring.transform.orientation, [1, 0, 0, 0])
    assert pyr.mesh.n_polygons == 4 and pyr.transform.scale == 0.2
    assert pyr.material.colour == (0.3, 0.85, 1.0)
    assert np.allclose(scene.lights[1].vector, [-0.6, 0.7, 1.2])


def test_scene_without_lights_gets_default(tmp_path):
    (tmp_path / "s.toml").write_text('[[object]]\nprimitive = "cube"\n'
                                     'material = { color = [1, 1, 1] }\n')
    scene = load_scene(tmp_path / "s.toml")
    assert len(scene.lights) == 1 and scene.objects[0].mesh.n_polygons == 6
    assert scene.objects[0].material.colour == (1.0, 1.0, 1.0)  # 'color' is accepted


BAD_SCENES = [
    ("ambient = = 1\n", "line 1", "Invalid"),
    ("colour = 3\n[[object]]\nprimitive = 'cube'\n", "", "unknown top-level key"),
    ("ambient = 1\n", "", "no [[object]]"),
    ("object = 3\n", "object", "[[object]]"),
    ("[[object]]\nname = 'a'\nprimitive = 'cube'\nsize = 2\n", "object 1 (a)", "key 'size'"),
    ("[[object]]\nprimitive = 'cone'\n", "object 1", "unknown primitive"),
    ("[[object]]\nprimitive = 'sphere'\nparams = { radus = 1 }\n", "object 1", "radus"),
    ("[[object]]\nprimitive = 'sphere'\nparams = { radius = -1 }\n", "object 1", "radius"),
    ("[[object]]\nprimitive = 'sphere'\nparams = { n_lat = 'many' }\n", "object 1", "n_lat"),
    # 10^10 polygons: the loader was killed for memory
    ("[[object]]\nprimitive = 'sphere'\nparams = { n_lat = 100000, n_lon = 100000 }\n",
     "object 1", "would have 10,000,000,000 polygons"),
    ("[[light]]\ndirection = [1e308, 1e308, 0]\n[[object]]\nprimitive = 'cube'\n", "light 1",
     "length below"),
    ("[[object]]\nprimitive = 'cube'\nfile = 'x.ply'\n", "object 1", "exactly one"),
    ("[[object]]\n", "object 1", "exactly one"),
    ("[[object]]\nprimitive = 'cube'\nposition = [1, 2]\n", "object 1", "3 numbers"),
    ("[[object]]\nprimitive = 'cube'\nscale = 0\n", "object 1", "scale"),
    ("[[object]]\nprimitive = 'cube'\nrotation = [0, 0, 0]\norientation = [1, 0, 0, 0]\n",
     "object 1", "not both"),
    ("[[object]]\nprimitive = 'cube'\nmaterial = { shininess = 0 }\n",
     "object 1, material", "shininess"),
    ("[[object]]\nprimitive = 'cube'\nmaterial = { colour = [2, 0, 0] }\n",
     "object 1, material", "colour"),
    ("[[object]]\nprimitive = 'cube'\nmaterial = { gloss = 1 }\n", "object 1, material", "gloss"),
    ("[[object]]\nprimitive = 'cube'\nmotion = { velocity = [0, 'a', 0] }\n",
     "object 1, motion, velocity", "3 numbers"),
    ("[[light]]\nkind = 'spot'\n[[object]]\nprimitive = 'cube'\n", "light 1", "spot"),
    ("[[light]]\ndirection = [0, 0, 0]\n[[object]]\nprimitive = 'cube'\n", "light 1", "non-zero"),
    ("[[light]]\ndirection = [0, 0, 1]\nposition = [0, 0, 1]\n[[object]]\nprimitive = 'cube'\n",
     "light 1", "not several"),
    (b"ambient = 1\n# caf\xe9\n", "line 2", "UTF-8"),
    ("", "", "empty"),
]


@pytest.mark.parametrize(("text", "where", "reason"), BAD_SCENES)
def test_bad_scene_file_names_file_and_place(tmp_path, text, where, reason):
    path = tmp_path / "bad.toml"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    with pytest.raises(MeshFileError) as info:
        load_scene(path)
    assert info.value.path == str(path) and info.value.where == where
    assert reason in info.value.reason


def test_scene_error_in_referenced_mesh_names_that_file(tmp_path):
    (tmp_path / "s.toml").write_text("[[object]]\nfile = 'sub/m.hobj'\n")
    with pytest.raises(MeshFileError) as info:  # missing: the scene file and object named
        load_scene(tmp_path / "s.toml")
    assert info.value.path == str(tmp_path / "s.toml") and info.value.where == "object 1"
    assert "'sub/m.hobj' not found" in info.value.reason
    assert str(tmp_path / "sub" / "m.hobj") in info.value.reason
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "m.hobj").write_text("3 1\n3\n0 0 0\n1 0 0\n")
    with pytest.raises(MeshFileError, match=r"m\.hobj, polygon 0"):
        load_scene(tmp_path / "s.toml")


@pytest.mark.parametrize("name", ["gone.hbc", "gone.obj", "folder.hbc"])
def test_scene_naming_a_missing_file_names_scene_object_and_file(tmp_path, name):
    (tmp_path / "folder.hbc").mkdir()
    (tmp_path / "s.toml").write_text(f"[[object]]\nname = 'x'\nfile = '{name}'\n")
    with pytest.raises(MeshFileError) as info:
        load_scene(tmp_path / "s.toml")
    assert info.value.path == str(tmp_path / "s.toml") and info.value.where == "object 1 (x)"
    want = "is not a file" if name.startswith("folder") else "not found"
    assert f"{name!r} {want}" in info.value.reason
