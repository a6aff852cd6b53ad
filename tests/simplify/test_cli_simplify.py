"""holo-simplify as a user runs it: a real process, its files, its exit status."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from service.loaders import load_mesh, save_ply
from service.primitives import sphere
from service.simplify.cloud_file import load_cloud


def _run(*args):
    return subprocess.run([sys.executable, "-m", "service.commands.holo_simplify", *map(str, args)],
                          capture_output=True, text=True, timeout=120)


@pytest.fixture(scope="module")
def mesh_file(tmp_path_factory):
    p = tmp_path_factory.mktemp("m") / "ball.ply"
    save_ply(p, sphere(0.5, 10, 20))
    return p


def test_billboard_cloud_json(mesh_file, tmp_path):
    out = tmp_path / "ball.hbc"
    r = _run(mesh_file, "--error", "5%", "--texture-res", "32", "--out", out, "--json")
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    cloud = load_cloud(out)
    assert rep["billboards"] == cloud.n_billboards > 0
    assert rep["eps"] == pytest.approx(0.05 * rep["diagonal"])
    assert rep["build_s"] > 0 and rep["faces_in"] == cloud.source_faces


def test_quadric_within_error(mesh_file, tmp_path):
    out = tmp_path / "low.ply"
    r = _run(mesh_file, "--error", "0.02", "--method", "quadric", "--out", out)
    assert r.returncode == 0, r.stderr
    low = load_mesh(out)
    assert low.triangles.shape[0] < load_mesh(mesh_file).triangles.shape[0]
    assert "error" in r.stdout


@pytest.mark.parametrize("args, needle", [
    (["--error", "0"], "must be > 0"),
    (["--error=-1%"], "must be > 0"),
    (["--error", "abc"], "want a number"),
    (["--error", "1%", "--texture-res", "0"], "must be"),
])
def test_bad_options_exit_2_in_one_line(mesh_file, tmp_path, args, needle):
    r = _run(mesh_file, *args, "--out", tmp_path / "x.hbc")
    assert r.returncode == 2 and needle in r.stderr
    errors = [ln for ln in r.stderr.splitlines() if ln.startswith("holo-simplify: error")]
    assert "Traceback" not in r.stderr and len(errors) == 1


def test_mesh_with_no_faces_exits_2(tmp_path):
    empty = tmp_path / "empty.obj"
    empty.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    r = _run(empty, "--error", "1%", "--out", tmp_path / "x.hbc")
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("\n") == 1 and "holo-simplify" in r.stderr


def test_wrong_output_extension_exits_2(mesh_file, tmp_path):
    r = _run(mesh_file, "--error", "1%", "--out", tmp_path / "x.ply")
    assert r.returncode == 2 and ".hbc" in r.stderr
    assert not Path(tmp_path / "x.ply").exists()


def test_help_is_plain():
    r = _run("--help")
    assert r.returncode == 0 and "Exit status" in r.stdout and "``" not in r.stdout


def _extent(scene, display):
    from service.render.pipeline import Renderer

    covered = np.isfinite(Renderer().render(scene, display).depth[display.zones // 2])
    rows, cols = np.nonzero(covered)
    return np.array([rows.min(), rows.max(), cols.min(), cols.max()]), covered.mean()


def test_a_lone_cloud_renders_the_size_of_its_mesh(mesh_file, tmp_path):
    # a lone .hbc is placed by what it shows, not by its rectangles' corners, which
    # reach past the mesh (the bunny's cloud came out 25 % smaller than the mesh)
    from service.display import DisplaySettings
    from service.loaders import load_scene

    out = tmp_path / "ball.hbc"
    assert _run(mesh_file, "--error", "2%", "--texture-res", "64", "--out", out).returncode == 0
    display = DisplaySettings(zones=3, cols=96, rows=72)
    mesh_box, mesh_cover = _extent(load_scene(mesh_file, display=display), display)
    cloud_box, cloud_cover = _extent(load_scene(out, display=display), display)
    assert np.abs(cloud_box - mesh_box).max() <= 2, (cloud_box, mesh_box)
    assert cloud_cover == pytest.approx(mesh_cover, rel=0.08)


def _grow(mask, k):
    out = mask.copy()
    for _ in range(k):
        o = out.copy()
        o[1:] |= out[:-1]
        o[:-1] |= out[1:]
        o[:, 1:] |= out[:, :-1]
        o[:, :-1] |= out[:, 1:]
        out = o
    return out


def test_a_bunny_cloud_covers_its_mesh_within_its_error(tmp_path):
    # The bunny's feet stood near upright on the horizontal billboard, which took
    # (or cut off) their bottom 2 EPS and showed them as slivers: a gap at the base.
    # Faces now go only to planes within PlaneSettings.max_tilt of their normal.
    from service.display import DisplaySettings
    from service.loaders import load_scene
    from service.render.pipeline import Renderer
    from tests.testkit import shared_fixture

    bunny = shared_fixture("meshes/bunny.ply")
    if not bunny.is_file():
        pytest.skip(f"no {bunny}")
    out = tmp_path / "bunny.hbc"
    r = _run(bunny, "--error", "1%", "--texture-res", "256", "--out", out)
    assert r.returncode == 0, r.stderr
    display = DisplaySettings(zones=3, cols=240, rows=180)
    mesh, cloud = (np.isfinite(Renderer().render(load_scene(p, display=display),
                                                 display).depth[1]) for p in (bunny, out))
    rows = np.flatnonzero(mesh.any(1))
    eps_px = 0.01 * np.sqrt(2) * (rows[-1] - rows[0])  # over-estimates the diagonal
    band = _grow(mesh, int(np.ceil(2 * eps_px))) & _grow(~mesh, int(np.ceil(2 * eps_px)))
    off = (mesh ^ cloud) & ~band  # differing pixels farther than the error from the edge
    assert off.sum() <= 0.01 * mesh.sum(), off.sum()
    base = np.zeros_like(mesh)
    base[rows[-1] - (rows[-1] - rows[0]) // 8:] = True  # the feet: the lowest eighth
    assert (mesh & ~cloud & base & ~band).sum() <= 0.01 * (mesh & base).sum()
    # no speckle: seams between billboards seen off their normals cracked where both
    # layers' texels faced away from the view and were culled (here 204 holes of 11,709
    # inner pixels, 1.7 %, 63 of them 1 px wide; 55 and 0 once the nearest such texel
    # stands in where front-facing ones show on both sides)
    inner = ~_grow(~mesh, 2)  # 2 px inside the silhouette
    holes = inner & ~cloud
    assert holes.sum() <= 0.008 * inner.sum(), (holes.sum(), inner.sum())
    pad = np.pad(cloud, 1)
    thin = holes & ((pad[1:-1, :-2] & pad[1:-1, 2:]) | (pad[:-2, 1:-1] & pad[2:, 1:-1]))
    assert thin.sum() == 0, np.argwhere(thin)  # no isolated hole: cloud on both sides
