"""Real-world meshes load: repairs on load, their counts, --strict, and ear clipping."""

import json
import subprocess
import sys
import warnings

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from service.base.errors import MeshFileError
from service.display import DisplaySettings
from service.loaders import load_mesh, load_scene
from service.mesh_repair import MeshRepair, MeshRepairWarning
from service.render.pipeline import Renderer
from service.triangulate import ear_clip, triangulate_rows
from tests.render.mesh_corpus import CASES, knot_quads, write_corpus

CASE_IDS = [c.name for c in CASES]


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    folder = tmp_path_factory.mktemp("corpus")
    return dict(zip(CASE_IDS, write_corpus(folder), strict=True))


def load_recording(path, **kw):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        mesh = load_mesh(path, **kw)
    return mesh, [w for w in caught if issubclass(w.category, MeshRepairWarning)]


def area(vertices, polygons, counts):
    """Total polygon area by Newell's method (for planar polygons: exact)."""
    total = 0.0
    for row, k in zip(polygons, counts, strict=True):
        p = vertices[row[:k]]
        total += np.linalg.norm(np.cross(p, np.roll(p, -1, axis=0)).sum(axis=0)) / 2
    return total


@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_corpus_loads_counts_and_renders(corpus, case):
    mesh, caught = load_recording(corpus[case.name])
    want = MeshRepair(faces_read=mesh.repair.faces_read, **case.expect)
    assert mesh.repair == want
    assert len(caught) == (1 if case.expect else 0)  # one warning per file, one line
    if caught:
        text = str(caught[0].message)
        assert "\n" not in text and str(corpus[case.name]) in text and "--strict" in text
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MeshRepairWarning)
        scene = load_scene(corpus[case.name])
    frame = Renderer().render(scene, DisplaySettings(zones=2, cols=48, rows=36))
    assert np.isfinite(frame.depth).sum() > 50  # something drawn in both zones


@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_strict_refuses_as_before(corpus, case):
    if not case.strict_error:
        mesh, caught = load_recording(corpus[case.name], strict=True)
        assert mesh.n_polygons == mesh.repair.faces_read and not caught
        return
    with pytest.raises(MeshFileError, match=case.strict_error) as info:
        load_mesh(corpus[case.name], strict=True)
    assert info.value.where  # names the line or face


def test_triangulated_polygons_keep_area_and_winding(corpus):
    """The concave star's 8 triangles cover its area and face the way it did."""
    mesh, _ = load_recording(corpus["concave.obj"])
    star = mesh.vertices[:10, :2]
    shoelace = shoelace_area(star)
    tris = mesh.polygons[:8, :3]
    assert np.all(tris < 10) and np.isclose(area(mesh.vertices, mesh.polygons[:8], mesh.counts[:8]),
                                            shoelace)
    assert np.allclose(mesh.normals[:8], [0, 0, 1])  # counter-clockwise, like the star


def test_knot_triangles_are_its_quads_split(corpus):
    mesh, _ = load_recording(corpus["knot.obj"])
    verts, faces = knot_quads()
    assert mesh.n_polygons == 2 * len(faces) and np.all(mesh.counts == 3)
    for q in (0, 17, len(faces) - 1):  # each quad's two triangles use its corners only
        pair = mesh.polygons[2 * q : 2 * q + 2, :3]
        assert set(pair.ravel().tolist()) == set(faces[q])


def test_degenerate_faces_skipped_with_count(tmp_path):
    text = ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2\nf 1 2 2\nf 1 2 4\nf 3\n")
    (tmp_path / "d.obj").write_text(text)
    mesh, caught = load_recording(tmp_path / "d.obj")
    assert mesh.n_polygons == 1 and mesh.repair.degenerate == 4 and mesh.repair.faces_read == 5
    assert "dropped 4 degenerate" in str(caught[0].message)


def test_ascii_ply_trailing_values_on_vertex_lines(tmp_path):
    head = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
            "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
            "end_header\n")
    (tmp_path / "t.ply").write_text(head + "0 0 0 9\n1 0 0 9 9\n0 1 0\n3 0 1 2\n")
    mesh, caught = load_recording(tmp_path / "t.ply")
    assert mesh.repair.trailing_values == 2 and len(caught) == 1
    assert mesh.vertices.tolist() == [[0, 0, 0], [1, 0, 0], [0, 1, 0]]


def test_cli_json_mesh_block_warning_and_strict(corpus, tmp_path):
    path = str(corpus["knot.obj"])
    cmd = [sys.executable, "-m", "service.commands.holo_render", path, "--zones", "2", "--size",
           "32x24",
           "--out", str(tmp_path / "o"), "--json"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    block = json.loads(r.stdout)["mesh"]
    assert block["non_planar"] == 1145 and block["triangles_added"] == 2290
    assert block["polygons"] == 2290 and block["triangles"] == 2290 and not block["strict"]
    warn = [ln for ln in r.stderr.splitlines() if "warning" in ln]
    assert len(warn) == 1 and "triangulated 1145 non-planar" in warn[0]
    r = subprocess.run([*cmd, "--strict"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and r.stdout == ""
    assert len(r.stderr.strip().splitlines()) == 1 and "is not planar" in r.stderr


# --- ear clipping -----------------------------------------------------------------


def cross2(u, v):
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def shoelace_area(poly):
    return 0.5 * np.sum(cross2(poly, np.roll(poly, -1, axis=0)))


def star_polygon(angles, radii):
    order = np.argsort(angles)
    a, r = np.asarray(angles)[order], np.asarray(radii)[order]
    return np.stack([r * np.cos(a), r * np.sin(a)], axis=1)


def inside(points, poly):
    """Even-odd point-in-polygon test, points (N, 2) against poly (n, 2)."""
    x, y = points[:, 0:1], points[:, 1:2]
    ax, ay = poly[:, 0], poly[:, 1]
    bx, by = np.roll(ax, -1), np.roll(ay, -1)
    crosses = ((ay > y) != (by > y)) & (x < (bx - ax) * (y - ay) / (by - ay + 1e-300) + ax)
    return crosses.sum(axis=1) % 2 == 1


@settings(max_examples=150, deadline=None)
@given(
    st.lists(st.tuples(st.floats(0, 2 * np.pi, exclude_max=True), st.floats(0.2, 1.0)),
             min_size=3, max_size=14, unique_by=lambda t: round(t[0], 3)),
    st.booleans(),
)
def test_ear_clip_covers_random_simple_polygons_exactly(corners, clockwise):
    """Random star-shaped (so simple) polygons, often concave: n-2 triangles, exact cover."""
    angles = np.sort([a for a, _ in corners])
    assume(np.max(np.diff(np.r_[angles, angles[0] + 2 * np.pi])) < np.pi - 0.05)  # 0 inside
    poly = star_polygon(*zip(*corners, strict=True))
    if clockwise:
        poly = poly[::-1]
    n = poly.shape[0]
    shoelace = shoelace_area(poly)
    tri = ear_clip(poly)
    assert tri.shape == (n - 2, 3)
    a, b, c = poly[tri[:, 0]], poly[tri[:, 1]], poly[tri[:, 2]]
    signed = 0.5 * cross2(b - a, c - a)
    # every triangle wound as the polygon is, and together exactly its area
    assert np.all(signed * np.sign(shoelace) >= -1e-12)
    assert np.isclose(signed.sum(), shoelace, rtol=1e-9, atol=1e-12)
    # sample points: inside the polygon, covered by exactly one triangle; outside, by none
    rng = np.random.default_rng(n)
    pts = rng.uniform(-1, 1, (400, 2))
    cover = np.zeros(len(pts), int)
    for t in range(n - 2):
        d = [cross2(q - p, pts - p) for p, q in ((a[t], b[t]), (b[t], c[t]), (c[t], a[t]))]
        s = np.sign(signed[t])
        cover += (np.min([di * s for di in d], axis=0) > 1e-9).astype(int)
    near_edge = np.zeros(len(pts), bool)
    for e in range(n):  # skip points within 1e-6 of an edge: boundaries are shared
        p, q = poly[e], poly[(e + 1) % n]
        u = np.clip(((pts - p) @ (q - p)) / max((q - p) @ (q - p), 1e-300), 0, 1)
        near_edge |= np.linalg.norm(pts - (p + u[:, None] * (q - p)), axis=1) < 1e-6
    ok = ~near_edge
    assert np.all(cover[ok] <= 1)
    assert np.array_equal(cover[ok] == 1, inside(pts[ok], poly))


def test_far_non_planar_polygon_triangles_use_its_corners_once():
    a = np.linspace(0, 2 * np.pi, 7, endpoint=False)
    verts = np.stack([np.cos(a), np.sin(a), 0.8 * np.cos(3 * a)], axis=1)
    tri, first = triangulate_rows(verts, np.arange(7)[None, :], np.array([7]), np.array([0]))
    assert tri.shape == (5, 3) and first.tolist() == [0, 5]
    edges = {tuple(sorted(e)) for t in tri for e in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))}
    assert {tuple(sorted((i, (i + 1) % 7))) for i in range(7)} <= edges  # the outline is kept
