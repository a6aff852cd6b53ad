import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from service.base.errors import MeshFileError
from service.loaders import (
    MESH_LOADERS,
    load_mesh,
    load_obj,
    load_ply,
    load_scene,
    load_thesis_object,
    save_obj,
    save_ply,
    save_thesis_object,
)
from service.primitives import attacker, cube, player, sphere, torus
from service.render.mesh import Mesh

PLY_FORMATS = ["ascii", "binary_little_endian", "binary_big_endian"]


def polygon_coords(mesh: Mesh) -> list:
    return [mesh.vertices[r[:k]].tolist() for r, k in zip(mesh.polygons, mesh.counts, strict=True)]


def same_mesh(a: Mesh, b: Mesh) -> bool:
    return np.array_equal(a.counts, b.counts) and polygon_coords(a) == polygon_coords(b)


# --- round trips ----------------------------------------------------------------

MESHES = {"cube": cube, "sphere": lambda: sphere(0.3, 6, 9), "player": lambda: player(2),
          "attacker": lambda: attacker(3)}


@pytest.mark.parametrize("name", sorted(MESHES))
def test_thesis_object_round_trip(tmp_path, name):
    mesh = MESHES[name]()
    save_thesis_object(tmp_path / "m.hobj", mesh, comment="round trip\ntwo lines")
    back = load_thesis_object(tmp_path / "m.hobj")
    assert same_mesh(mesh, back)
    assert back.n_vertices == mesh.n_vertices  # repeated coordinates welded back
    assert back.name == "m"


@pytest.mark.parametrize("fmt", PLY_FORMATS)
@pytest.mark.parametrize("name", sorted(MESHES))
def test_ply_round_trip(tmp_path, fmt, name):
    mesh = MESHES[name]()
    save_ply(tmp_path / "m.ply", mesh, fmt)
    back = load_ply(tmp_path / "m.ply")
    assert np.array_equal(back.vertices, mesh.vertices)
    assert np.array_equal(back.polygons, mesh.polygons) and np.array_equal(back.counts, mesh.counts)


@pytest.mark.parametrize("name", sorted(MESHES))
def test_obj_round_trip(tmp_path, name):
    mesh = MESHES[name]()
    save_obj(tmp_path / "m.obj", mesh)
    back = load_mesh(tmp_path / "m.obj")
    assert np.array_equal(back.vertices, mesh.vertices)
    assert np.array_equal(back.polygons, mesh.polygons)


def test_load_mesh_dispatches_by_extension(tmp_path):
    mesh = cube()
    for ext, save in ((".hobj", save_thesis_object), (".ply", save_ply), (".OBJ", save_obj)):
        save(tmp_path / f"c{ext}", mesh)
        assert same_mesh(load_mesh(tmp_path / f"c{ext}"), mesh)
    assert set(MESH_LOADERS) == {".hobj", ".ply", ".obj"}
    (tmp_path / "c.stl").write_text("solid")
    with pytest.raises(MeshFileError, match="c.stl.*extension"):
        load_mesh(tmp_path / "c.stl")


# --- the thesis object file -------------------------------------------------------

THESIS_TEXT = """\
# a square pyramid without its base: 4 triangles, 12 vertex lines
12 4   # NUMVERTS NUMPOLYG

3
0 0 1
-1 -1 0
1 -1 0
3
0 0 1
1 -1 0
1 1 0
3
0 0 1
1 1 0
-1 1 0
3
0 0 1
-1 1 0
-1 -1 0
"""


def test_thesis_object_grammar_and_welding(tmp_path):
    path = tmp_path / "pyramid.hobj"
    path.write_text(THESIS_TEXT)
    mesh = load_thesis_object(path)
    assert mesh.n_polygons == 4 and mesh.n_vertices == 5
    assert mesh.vertices[0].tolist() == [0, 0, 1]  # first appearance order
    assert np.all(mesh.polygons[:, 0] == 0)  # the apex is one shared vertex
    assert np.all(mesh.normals[:, 2] > 0)


# --- PLY variants ---------------------------------------------------------------


def ply_bytes(fmt: str, vertex_props: list, vertex_rows: list, face_rows: list,
              count_type: str = "uchar", index_type: str = "int", face_name: str = "vertex_indices",
              extra: str = "") -> bytes:
    """A PLY file with the given vertex properties (type, name) and faces."""
    head = [f"ply\nformat {fmt} 1.0\ncomment test\nelement vertex {len(vertex_rows)}"]
    head += [f"property {t} {n}" for t, n in vertex_props]
    head += [f"element face {len(face_rows)}", "property uchar flag",
             f"property list {count_type} {index_type} {face_name}", "property float quality"]
    head += [extra, "end_header\n"] if extra else ["end_header\n"]
    out = "\n".join(head).encode()
    if fmt == "ascii":
        body = "".join(" ".join(str(v) for v in r) + "\n" for r in vertex_rows)
        body += "".join(f"7 {len(f)} " + " ".join(map(str, f)) + " 0.5\n" for f in face_rows)
        return out + body.encode()
    from service.loaders.ply import FORMATS, PLY_TYPES

    order = FORMATS[fmt]
    vdt = np.dtype([(n, order + PLY_TYPES[t]) for t, n in vertex_props])
    parts = [out, np.array([tuple(r) for r in vertex_rows], vdt).tobytes()]
    for f in face_rows:
        parts += [
            np.array(7, "u1").tobytes(),
            np.array(len(f), order + PLY_TYPES[count_type]).tobytes(),
            np.array(f, order + PLY_TYPES[index_type]).tobytes(),
            np.array(0.5, order + "f4").tobytes(),
        ]
    return b"".join(parts)


VPROPS = [("float", "x"), ("uchar", "red"), ("double", "y"), ("short", "nx"), ("float", "z")]
# z = y / 2, so the quad face [0, 1, 2, 3] is planar
VROWS = [[0.0, 1, 0.0, 3, 0.0], [1.0, 2, 0.0, 3, 0.0], [1.0, 3, 1.0, 3, 0.5], [0.0, 4, 1.0, 3, 0.5]]


@pytest.mark.parametrize("fmt", PLY_FORMATS)
@pytest.mark.parametrize("faces", [[[0, 1, 2], [0, 2, 3]], [[0, 1, 2, 3], [0, 2, 3]]])
def test_ply_skips_other_properties_and_elements(tmp_path, fmt, faces):
    extra = "element edge 0\nproperty int vertex1\nproperty int vertex2"
    for count_type, index_type, name in (("uchar", "int", "vertex_indices"),
                                         ("uint", "uint", "vertex_index")):
        data = ply_bytes(fmt, VPROPS, VROWS, faces, count_type, index_type, name, extra)
        (tmp_path / "v.ply").write_bytes(data)
        mesh = load_ply(tmp_path / "v.ply")
        assert mesh.vertices.tolist() == [[r[0], r[2], r[4]] for r in VROWS]
        assert [list(r[:k]) for r, k in zip(mesh.polygons, mesh.counts, strict=True)] == faces


def test_ply_binary_fast_path_large_triangle_mesh(tmp_path):
    rng = np.random.default_rng(1)
    verts = rng.normal(size=(3000, 3))
    tris = rng.integers(0, 3000, size=(20000, 3))
    distinct = (tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 0] != tris[:, 2])
    tris = tris[distinct]
    save_ply(tmp_path / "big.ply", Mesh.from_triangles(verts, tris))
    mesh = load_ply(tmp_path / "big.ply")
    assert np.array_equal(mesh.polygons, tris) and np.array_equal(mesh.vertices, verts)


# --- OBJ forms ------------------------------------------------------------------

OBJ_TEXT = """\
# OBJ with every face form
mtllib x.mtl
o thing
v 0 0 0
v 1 0 0
v 1 1 0 1.0
v 0 1 0
vt 0 0
vn 0 0 1
g group
usemtl red
s off
f 1 2 3
f 1/1 3/1 4/1
f 1//1 2//1 \\
  4//1
f -4/1/1 -2/1/1 -1/1/1
l 1 2
"""


def test_obj_face_forms_and_relative_indices(tmp_path):
    (tmp_path / "f.obj").write_text(OBJ_TEXT)
    mesh = load_obj(tmp_path / "f.obj")
    rows = [list(r[:k]) for r, k in zip(mesh.polygons, mesh.counts, strict=True)]
    assert rows == [[0, 1, 2], [0, 2, 3], [0, 1, 3], [0, 2, 3]]
    assert mesh.n_vertices == 4


# --- bad files ------------------------------------------------------------------

GOOD_PLY = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n" \
    "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
BAD_FILES = [
    ("empty.hobj", "", "", "empty"),
    ("comments.hobj", "# nothing\n", "", "no data"),
    ("header.hobj", "3\n", "line 1", "NUMVERTS NUMPOLYG"),
    ("notnum.hobj", "3 x\n", "line 1", "not an integer"),
    ("trunc.hobj", "3 1\n3\n0 0 0\n1 0 0\n", "polygon 0", "ends"),
    ("missing.hobj", "6 2\n3\n0 0 0\n1 0 0\n0 1 0\n", "polygon 1", "ends"),
    ("twoverts.hobj", "2 1\n2\n0 0 0\n1 0 0\n", "line 1", ">= 3"),
    ("k2.hobj", "5 2\n3\n0 0 0\n1 0 0\n0 1 0\n2\n0 0 0\n", "line 6", "at least 3"),
    ("coord.hobj", "3 1\n3\n0 0 0\n1 zero 0\n0 1 0\n", "line 4", "not a number"),
    ("nan.hobj", "3 1\n3\n0 0 0\n1 nan 0\n0 1 0\n", "line 4", "not finite"),
    ("inf.hobj", "3 1\n3\n0 0 0\n1 0 0\n0 -inf 0\n", "line 5", "not finite"),
    ("ncoord.hobj", "3 1\n3\n0 0 0\n1 0\n0 1 0\n", "line 4", "x y z"),
    ("sum.hobj", "4 1\n3\n0 0 0\n1 0 0\n0 1 0\n", "line 1", "NUMVERTS is 4"),
    ("extra.hobj", "3 1\n3\n0 0 0\n1 0 0\n0 1 0\n1 2 3\n", "line 6", "after the last"),
    ("utf.hobj", b"3 1\n3\n0 0 0\n1 \xff 0\n", "line 4", "UTF-8"),
    ("nul.hobj", b"3 1\n\x00\x01\x02", "line 2", "binary"),
    ("noverts.obj", "v 0 0\nf 1 2 3\n", "line 1", "x, y and z"),
    ("noface.obj", "v 0 0 0\n", "", "no faces"),
    ("range.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n\nf 1 2 4\n", "line 5", "beyond"),
    ("zero.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "line 4", "out of range"),
    ("rel.obj", "v 0 0 0\nv 1 0 0\nf -1 -2 -3\nv 0 1 0\n", "line 3", "out of range"),
    ("short.obj", "v 0 0 0\nv 1 0 0\nf 1 2\n", "line 3", ">= 3"),
    ("word.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 two 3\n", "line 4", "not an integer"),
    # past int64: OverflowError where numpy took the index, before
    ("huge.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999999999\n", "line 4",
     "vertex index is out of range"),
    ("huge.hobj", "99999999999999999999 1\n", "line 1", "NUMVERTS is out of range"),
    ("inf.obj", "v 0 0 0\nv 1e999 0 0\n", "line 2", "not finite"),
    ("magic.ply", "plx\n", "line 1", "not a PLY"),
    ("fmt.ply", "ply\nformat binary_middle_endian 1.0\nend_header\n", "line 2", "format"),
    ("type.ply", "ply\nformat ascii 1.0\nelement vertex 1\nproperty float128 x\n", "line 4",
     "unknown PLY property type"),
    ("kw.ply", "ply\nformat ascii 1.0\nblah\nend_header\n", "line 3", "keyword"),
    ("noend.ply", "ply\nformat ascii 1.0\nelement vertex 3\n", "line 4", "end_header"),
    ("noface.ply", "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nend_header\n",
     "header", "no face"),
    ("trunc.ply", GOOD_PLY + "0 0 0\n1 0 0\n", "vertex 2", "ends early"),
    ("tok.ply", GOOD_PLY + "0 0 0\n1 0 q\n0 1 0\n3 0 1 2\n", "line 11", "not a number"),
    ("few.ply", GOOD_PLY + "0 0 0\n1 0\n0 1 0\n3 0 1 2\n", "line 11", "too few"),
    ("idx.ply", GOOD_PLY + "0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n", "face 0", "outside 0..2"),
    ("huge.ply", GOOD_PLY + "0 0 0\n1 0 0\n0 1 0\n3 0 1 99999999999999999999\n", "line 13",
     "integer value is out of range"),
    ("two.ply", GOOD_PLY + "0 0 0\n1 0 0\n0 1 0\n2 0 1\n", "face 0", "at least 3"),
    ("nan.ply", GOOD_PLY + "0 0 0\n1 0 0\n0 nan 0\n3 0 1 2\n", "vertex 2", "not finite"),
    ("bin.ply", GOOD_PLY.replace("ascii", "binary_little_endian") + "\x00" * 20, "vertex 1",
     "ends early"),
    ("binface.ply", GOOD_PLY.replace("ascii", "binary_big_endian").encode()
     + np.zeros(9, ">f4").tobytes() + b"\x03\x00\x00\x00\x00", "face 0", "ends early"),
]


REPAIRED_WITHOUT_STRICT = {"short.obj", "two.ply"}  # a face of 2 corners: skipped unless strict


@pytest.mark.parametrize("strict", [True, False])
@pytest.mark.parametrize(("name", "content", "where", "reason"), BAD_FILES,
                         ids=[b[0] for b in BAD_FILES])
def test_bad_file_names_file_and_place(tmp_path, name, content, where, reason, strict):
    path = tmp_path / name
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    if name in REPAIRED_WITHOUT_STRICT and not strict:
        where, reason = "", "every polygon is degenerate"  # its only face was skipped
    with pytest.raises(MeshFileError) as info:
        load_mesh(path, strict=strict)
    err = info.value
    assert err.path == str(path) and err.where == where
    assert reason in err.reason
    assert str(path) in str(err) and where in str(err)


def test_missing_file(tmp_path):
    with pytest.raises(MeshFileError, match="cannot read"):
        load_mesh(tmp_path / "absent.ply")


@pytest.mark.parametrize("ext", [".hobj", ".obj", ".ply"])
def test_degenerate_polygons_dropped_with_warning(tmp_path, ext):
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]], float)
    mesh = Mesh.from_polygons(verts, [[0, 1, 2], [0, 1, 3], [1, 2, 0]])  # middle one is a line
    path = tmp_path / f"deg{ext}"
    {".hobj": save_thesis_object, ".obj": save_obj, ".ply": save_ply}[ext](path, mesh)
    with pytest.warns(UserWarning, match=r"deg.*dropped 1 degenerate"):
        back = load_mesh(path)
    assert back.n_polygons == 2


# --- polygon shapes: planar and convex -------------------------------------------

SHAPE_TRIANGLE = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
BAD_SHAPES = {  # corners of polygon 1; polygon 0 is SHAPE_TRIANGLE
    "concave": ([[0, 0, 1], [2, 0, 1], [0.5, 0.5, 1], [0, 2, 1]], "not convex"),
    "non-planar": ([[0, 0, 1], [2, 0, 1], [2, 2, 1.2], [0, 2, 1]], "not planar"),
    "bow-tie": ([[0, 0, 1], [2, 2, 1], [2, 0, 1], [0, 2, 1]], "not convex"),
}
# a square in the tilted plane z = 1 + 0.3x - 0.7y, written with 6 decimals (as many
# exporters do), then off the plane by up to 1e-6: within the tolerance (1e-5 of the extent)
_TILT = [[x, y, 1 + 0.3 * x - 0.7 * y] for x, y in ((0, 0), (1.7, 0.1), (1.9, 1.3), (0.3, 1.9))]
GOOD_SHAPES = {
    "convex quad": [[0, 0, 1], [2, 0, 1], [2.5, 2, 1], [0, 2, 1]],
    "pentagon, collinear corner": [[0, 0, 1], [1, 0, 1], [2, 0, 1], [2, 2, 1], [0, 2, 1]],
    "noisy quad": (np.round(np.array(_TILT), 6) + [[0, 0, 1e-6], [0, 0, -1e-6], [0, 0, 0],
                                                    [0, 0, 5e-7]]).tolist(),
}
SHAPE_FORMATS = [".obj", ".hobj", "ascii.ply", "binary_little_endian.ply",
                 "binary_big_endian.ply"]


def write_two_polygons(tmp_path: Path, fmt: str, corners: list) -> tuple[Path, str]:
    """A file with SHAPE_TRIANGLE then ``corners``; returns it and polygon 1's place."""
    verts = SHAPE_TRIANGLE + list(corners)
    faces = [[0, 1, 2], list(range(3, len(verts)))]
    if fmt.endswith(".ply"):
        path = tmp_path / "shape.ply"
        path.write_bytes(ply_bytes(fmt[:-4], [("double", a) for a in "xyz"], verts, faces))
        return path, "face 1"
    lines = ["# two polygons"]
    if fmt == ".obj":
        lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in verts]
        lines += ["f " + " ".join(str(i + 1) for i in f) for f in faces]
        where = f"line {len(lines)}"
    else:
        lines += [f"{len(verts)} 2"]
        for f in faces:
            lines += [str(len(f))] + [" ".join(repr(c) for c in verts[i]) for i in f]
        where = f"line {2 + 1 + 3 + 1}"  # comment, header, triangle, then its k
    path = tmp_path / f"shape{fmt}"
    path.write_text("\n".join(lines) + "\n")
    return path, where


@pytest.mark.parametrize("fmt", SHAPE_FORMATS)
@pytest.mark.parametrize("shape", sorted(BAD_SHAPES))
def test_non_planar_or_non_convex_polygon_names_file_and_place(tmp_path, fmt, shape):
    corners, reason = BAD_SHAPES[shape]
    path, where = write_two_polygons(tmp_path, fmt, corners)
    with pytest.raises(MeshFileError) as info:
        load_mesh(path, strict=True)
    err = info.value
    assert err.path == str(path) and err.where == where
    assert err.reason.startswith(f"polygon 1 is {reason}")
    assert "planar and convex" in err.reason and "tolerance" in err.reason
    assert str(err).startswith(f"{path}, {where}: polygon 1")


@pytest.mark.parametrize("fmt", SHAPE_FORMATS)
@pytest.mark.parametrize("shape", sorted(GOOD_SHAPES))
def test_planar_convex_polygons_load(tmp_path, fmt, shape):
    path, _ = write_two_polygons(tmp_path, fmt, GOOD_SHAPES[shape])
    mesh = load_mesh(path)
    assert mesh.counts.tolist() == [3, len(GOOD_SHAPES[shape])]
    assert np.allclose(mesh.vertices[mesh.polygons[1, : mesh.counts[1]]], GOOD_SHAPES[shape])


def test_rounded_coordinates_of_small_quads_load(tmp_path):
    """File rounding is noise, not a fault: float32 PLY far from the origin, 6-decimal OBJ.

    Relative to each quad's own size these are off their planes by 1.5e-6 (torus) and
    1.2e-5 (sphere); relative to the mesh's extent, by 6e-8 and 4e-7.
    """
    mesh = torus(0.5, 0.15, 64, 24)
    verts = (mesh.vertices + [3.0, -2.0, 1.0]).astype(np.float32).tolist()
    faces = [list(r[:k]) for r, k in zip(mesh.polygons, mesh.counts, strict=True)]
    path = tmp_path / "torus32.ply"
    path.write_bytes(ply_bytes("binary_little_endian", [("float", a) for a in "xyz"], verts,
                               faces))
    assert load_mesh(path).n_polygons == mesh.n_polygons
    ball = sphere(0.5, 64, 128)
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in ball.vertices]
    lines += ["f " + " ".join(str(i + 1) for i in r[:k])
              for r, k in zip(ball.polygons, ball.counts, strict=True)]
    (tmp_path / "ball.obj").write_text("\n".join(lines) + "\n")
    assert load_mesh(tmp_path / "ball.obj").n_polygons == ball.n_polygons


# --- fuzz -----------------------------------------------------------------------


def _load_quietly(path: Path) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            mesh = load_mesh(path)
        except MeshFileError:
            return
    assert isinstance(mesh, Mesh)


FUZZ = settings(max_examples=60, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture])


def _seed_files() -> dict:
    from tempfile import TemporaryDirectory

    out, mesh = {}, sphere(0.5, 3, 4)
    with TemporaryDirectory() as d:
        for name, save in (("a.hobj", save_thesis_object), ("a.obj", save_obj),
                           ("ascii.ply", lambda p, m: save_ply(p, m, "ascii")),
                           ("le.ply", save_ply),
                           ("be.ply", lambda p, m: save_ply(p, m, "binary_big_endian")),
                           ("tri.ply", lambda p, m: save_ply(p, cube_tris()))):
            save(Path(d) / name, mesh)
            out[name] = (Path(d) / name).read_bytes()
    return out


def cube_tris() -> Mesh:
    c = cube()
    return Mesh.from_triangles(c.vertices, c.triangles)


SEEDS = _seed_files()


@FUZZ
@given(data=st.binary(max_size=300), ext=st.sampled_from([".hobj", ".obj", ".ply"]))
def test_fuzz_random_bytes(tmp_path, data, ext):
    path = tmp_path / f"r{ext}"
    path.write_bytes(data)
    _load_quietly(path)


@FUZZ
@given(name=st.sampled_from(sorted(SEEDS)), cut=st.floats(0, 1))
def test_fuzz_truncation(tmp_path, name, cut):
    data = SEEDS[name]
    path = tmp_path / name
    path.write_bytes(data[: int(len(data) * cut)])
    _load_quietly(path)


@FUZZ
@given(name=st.sampled_from(sorted(SEEDS)),
       edits=st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), min_size=1, max_size=6))
def test_fuzz_byte_flips(tmp_path, name, edits):
    data = bytearray(SEEDS[name])
    for where, value in edits:
        data[min(int(where * len(data)), len(data) - 1)] = value
    path = tmp_path / name
    path.write_bytes(bytes(data))
    _load_quietly(path)


# --- scenes from files ----------------------------------------------------------


def test_single_mesh_becomes_fitted_one_object_scene(tmp_path):
    big = Mesh(cube(10.0).vertices + 100.0, cube().polygons, cube().counts)
    save_ply(tmp_path / "box.ply", big)
    scene = load_scene(tmp_path / "box.ply")
    assert len(scene.objects) == 1 and len(scene.lights) == 1
    world = scene.flatten().vertices
    assert np.allclose(world.min(0), -world.max(0))  # centred
    # a cube is as tall as wide: the height, 0.8 of the default view's 1.5, decides
    assert np.allclose(world.max(0), 0.6)
    assert scene.objects[0].name == "box"


@pytest.mark.parametrize(
    ("name", "content", "reason"),
    [
        ("none.ply", "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
         "property float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n",
         "no polygons"),
        ("flat.obj", "v 0 0 0\nv 1 1 1\nv 2 2 2\nf 1 2 3\n", "every polygon is degenerate"),
        # cut off after its first 'f' (found by test_fuzz_truncation: an IndexError)
        ("bare-f.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf\n", "every polygon is degenerate"),
        ("bare-fs.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf\nf  \n", "every polygon is degenerate"),
    ],
)
def test_files_without_usable_polygons(tmp_path, name, content, reason):
    (tmp_path / name).write_text(content)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(MeshFileError, match=reason):
            load_mesh(tmp_path / name)


def test_a_vertex_too_large_to_compute_with_names_the_vertex(tmp_path):
    path = tmp_path / "big.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1e31 0\nf 1 2 3\n")
    for strict in (True, False):
        with pytest.raises(MeshFileError, match="beyond") as info:
            load_mesh(path, strict=strict)
        assert info.value.where == "vertex 2" and "scale the mesh down" in info.value.reason


def test_the_repair_warning_points_at_the_loaders_caller(tmp_path):
    path = tmp_path / "deg.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 1 2\n")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load_obj(path)
    assert [w.filename for w in caught] == [__file__]
    assert "repaired on load" in str(caught[0].message)
