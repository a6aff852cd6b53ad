"""holo-render: the occlusion counters of --json for every method, exclusive fallbacks."""

from __future__ import annotations

import json

import numpy as np
import pytest

from service.commands import holo_render as cli_render
from service.render.pipeline import METHOD_NAMES

#: Counters each method adds to the common ones.
OWN = {"runlength": {"inconsistent_pixels", "inconsistent_by_zone"},
       "zbuffer": set(),
       "bsp": {"nodes", "fragments", "splits", "depth", "build_ms"},
       "raycast": {"candidates", "bin_entries"}}


def _report(capsys, *argv: str) -> dict:
    assert cli_render.main([*argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


@pytest.mark.parametrize("method", METHOD_NAMES)
def test_json_has_occlusion_counters_for_every_method(method, tmp_path, capsys):
    report = _report(capsys, "builtin:sphere_torus", "--method", method, "--zones", "3",
                     "--size", "64x48", "--out", str(tmp_path))
    occ = report["occlusion"]
    assert {"covered_pixels", "covered_by_zone", "fallback"} | OWN[method] <= set(occ)
    depth = np.stack([np.load(tmp_path / f"depth-{k:02d}.npy") for k in range(3)])
    covered = np.isfinite(depth).sum(axis=(1, 2))
    assert occ["covered_by_zone"] == covered.tolist() and occ["covered_pixels"] == covered.sum()
    assert 0 < occ["covered_pixels"] < 3 * 64 * 48
    assert occ["fallback"] is None


def test_json_names_the_fallback_and_the_inconsistent_pixels(tmp_path, capsys):
    occ = _report(capsys, "builtin:cyclic", "--method", "runlength", "--size", "80x60",
                  "--out", str(tmp_path))["occlusion"]
    assert occ["fallback"] == "pixel" and occ["inconsistent_pixels"] > 0  # the default
    occ = _report(capsys, "builtin:cyclic", "--method", "runlength", "--size", "80x60",
                  "--fallback", "frame", "--out", str(tmp_path))["occlusion"]
    assert occ["fallback"] == "zbuffer" and occ["inconsistent_pixels"] > 0
    occ = _report(capsys, "builtin:cyclic", "--method", "runlength", "--size", "80x60",
                  "--no-fallback", "--out", str(tmp_path))["occlusion"]
    assert occ["fallback"] is None and occ["inconsistent_pixels"] > 0


def test_fallback_and_no_fallback_are_exclusive(capsys):
    with pytest.raises(SystemExit) as exc:
        cli_render.main(["builtin:game", "--fallback", "pixel", "--no-fallback"])
    assert exc.value.code == 2
    assert "--no-fallback: not allowed with argument --fallback" in capsys.readouterr().err


def test_summary_line_adds_up(tmp_path, capsys):
    """in - culled = kept; "drawn" (seen in a zone) is named so, not read as in - culled."""
    assert cli_render.main(["builtin:sphere_torus", "--zones", "3", "--size", "64x48",
                            "--out", str(tmp_path), "--json"]) == 0
    p = json.loads(capsys.readouterr().out)["polygons"]
    assert cli_render.main(["builtin:sphere_torus", "--zones", "3", "--size", "64x48",
                            "--out", str(tmp_path)]) == 0
    line = capsys.readouterr().out.splitlines()[0]
    assert p["in"] - p["culled"] == p["kept"]
    assert line.startswith(f"{p['in']} polygons, {p['culled']} culled, {p['kept']} kept, "
                           f"{p['drawn']} seen in a zone; ")


def test_max_error_alone_turns_quality_auto_on(tmp_path, capsys):
    """Before: --max-error without --quality auto was dropped without a word."""
    report = _report(capsys, "builtin:cyclic", "--size", "32x24", "--max-error", "5",
                     "--out", str(tmp_path))
    assert report["quality"] and report["quality"]["reason"]
    fixed = _report(capsys, "builtin:cyclic", "--size", "32x24", "--out", str(tmp_path))
    assert not fixed["quality"]


def test_max_error_with_quality_fixed_is_bad_usage(tmp_path, capsys):
    assert cli_render.main(["builtin:cyclic", "--quality", "fixed", "--max-error", "5",
                            "--out", str(tmp_path)]) == 2
    assert "--max-error is the budget of --quality auto" in capsys.readouterr().err


def test_summary_of_a_billboard_cloud_counts_its_billboards(tmp_path, capsys):
    """Before: 'holo-render bunny.hbc' said '0 polygons, ... 0 seen in a zone' of a frame
    full of billboards."""
    from service.commands import holo_simplify as cli_simplify
    from service.loaders import save_obj
    from service.primitives import sphere

    save_obj(tmp_path / "ball.obj", sphere(0.5, 12, 8))
    assert cli_simplify.main([str(tmp_path / "ball.obj"), "--error", "5%", "--out",
                              str(tmp_path / "ball.hbc")]) == 0
    capsys.readouterr()
    assert cli_render.main([str(tmp_path / "ball.hbc"), "--zones", "3", "--size", "48x36",
                            "--out", str(tmp_path / "out")]) == 0
    line = capsys.readouterr().out.splitlines()[0]
    assert " billboards; " in line and not line.split(", ")[-1].startswith("0 billboards")


def test_a_missing_cost_model_is_named_before_rendering(tmp_path, capsys):
    """Before: 'cost model m.json: [Errno 2] No such file or directory: 'm.json''."""
    missing = tmp_path / "m.json"
    assert cli_render.main(["builtin:cyclic", "--quality", "auto", "--cost-model",
                            str(missing), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.strip() == (f"holo-render: error: --cost-model {missing}: no such file "
                           "(holo-bench quality --calibrate --model PATH writes one)")
    assert not (tmp_path / "out").exists()
