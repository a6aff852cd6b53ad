"""holo-render as a user runs it: a real process, real files."""

import json
import subprocess
import sys

import numpy as np
import pytest

from service.loaders import save_obj
from service.png import read_png
from service.primitives import torus
from tests.testkit import shared_fixture


def run(*args, cwd=None):
    return subprocess.run(
        [sys.executable, "-m", "service.commands.holo_render", *args],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=cwd,
    )


def test_renders_a_mesh_file_and_reports_json(tmp_path):
    mesh = tmp_path / "ring.obj"
    save_obj(mesh, torus(0.5, 0.2, 24, 12))
    out = tmp_path / "out"
    r = run(
        str(mesh),
        "--zones",
        "3",
        "--size",
        "64x48",
        "--method",
        "runlength",
        "--light",
        "phong",
        "--specular",
        "vertex",
        "--out",
        str(out),
        "--json",
    )
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout)
    assert report["settings"]["zones"] == 3 and report["settings"]["method"] == "runlength"
    p = report["polygons"]
    assert p["in"] == 24 * 12 and p["in"] == p["culled"] + p["kept"] and p["drawn"] > 0
    assert {"project", "cull", "sort", "occlusion", "light"} <= set(report["ms"])
    for k in range(3):
        img = read_png(out / f"zone-{k:02d}.png")
        assert img.shape == (48, 64, 3)
        depth = np.load(out / f"depth-{k:02d}.npy")
        assert depth.dtype == np.float32 and depth.shape == (48, 64)
        assert np.isinf(depth).any() and np.isfinite(depth).any()
        assert ((img.sum(axis=2) > 0) <= np.isfinite(depth)).all()
    assert read_png(out / "strip.png").shape[1] >= 3 * 64


def test_builtin_scene_and_fallback_note(tmp_path):
    r = run("builtin:cyclic", "--method", "runlength", "--size", "80x60", "--out", str(tmp_path))
    assert r.returncode == 0, r.stderr
    assert "z-tested per pixel" in r.stdout  # the default fallback
    r = run("builtin:cyclic", "--method", "runlength", "--size", "80x60", "--fallback", "frame",
            "--out", str(tmp_path))
    assert r.returncode == 0, r.stderr
    assert "redrawn with the zbuffer" in r.stdout


def test_bad_file_names_file_and_line(tmp_path):
    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nv 0 1 zz\nf 1 2 3\n")
    r = run(str(bad), "--out", str(tmp_path / "o"))
    assert r.returncode == 2
    assert "bad.obj" in r.stderr and "line 3" in r.stderr
    assert "Traceback" not in r.stderr


def test_missing_file_and_bad_size_are_clear(tmp_path):
    r = run(str(tmp_path / "nope.ply"), "--out", str(tmp_path))
    assert r.returncode == 2 and "nope.ply" in r.stderr and "Traceback" not in r.stderr
    r = run("builtin:demo", "--size", "big", "--out", str(tmp_path))
    assert r.returncode == 2 and "320x240" in r.stderr
    r = run("builtin:demo", "--zones", "0", "--out", str(tmp_path))
    assert r.returncode == 2 and "zones" in r.stderr
    # 64 zones of 8192x8192: a 16 GiB buffer was asked for first (MemoryError)
    r = run("builtin:demo", "--zones", "64", "--size", "8192x8192", "--out", str(tmp_path))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "4,294,967,296 pixels (at most 67,108,864)" in r.stderr


def test_help_lists_the_options():
    r = run("--help")
    assert r.returncode == 0
    for opt in (
        "--zones",
        "--angle",
        "--size",
        "--method",
        "--light",
        "--specular",
        "--out",
        "--json",
    ):
        assert opt in r.stdout


@pytest.mark.parametrize("display", [("--zones", "5"), ("--zones", "9", "--angle", "40",
                                                         "--size", "96x160")],
                         ids=["default", "wide-angle-tall"])
def test_a_lone_mesh_fits_inside_every_zones_view(tmp_path, display):
    """The bunny's ear tips and feet (taller than wide) and the outer zones' shear
    stay inside the frame: no covered pixel touches an edge in any zone."""
    bunny = shared_fixture("meshes/bunny.ply")
    if not bunny.is_file():
        pytest.skip(f"no {bunny}")
    out = tmp_path / "out"
    r = run(str(bunny), *display, "--out", str(out))
    assert r.returncode == 0, r.stderr
    zones = int(display[1])
    for k in range(zones):
        covered = np.isfinite(np.load(out / f"depth-{k:02d}.npy"))
        assert covered.sum() > 0.1 * covered.size  # fitted, not shrunk to a speck
        edges = (covered[0], covered[-1], covered[:, 0], covered[:, -1])
        assert not any(e.any() for e in edges), f"zone {k} touches the frame edge"
