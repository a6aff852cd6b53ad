"""``holo-sird``: the JSON report, the PNG, and one-line errors with status 2."""

from __future__ import annotations

import json

import numpy as np
import pytest

from service.autostereogram.depth_scenes import sphere
from service.commands.holo_sird import main
from service.png import read_png, write_png


def _npy(tmp_path, depth, name="depth.npy"):
    path = tmp_path / name
    np.save(path, depth)
    return str(path)


def test_json_report_and_png(tmp_path, capsys):
    src = _npy(tmp_path, sphere(320, 200))
    out = tmp_path / "sird.png"
    assert main([src, "--out", str(out), "--json", "--eye-sep", "90"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert set(report) >= {"method", "size", "eye_sep_px", "mu", "near", "far",
                           "separation_px", "ms", "constraints", "broken", "hidden"}
    assert report["method"] == "tiw" and report["size"] == [320, 200]
    assert report["separation_px"] == [36, 45] and report["broken"] == 0
    assert report["near"] == pytest.approx(0.0) and 0.9 < report["far"] <= 1.0  # finite range
    assert report["constraints"] > 0 and report["hidden"] > 0 and report["ms"] > 0
    assert read_png(out).shape == (200, 320)  # grey


def test_colour_and_image_patterns_and_size(tmp_path, capsys):
    src = _npy(tmp_path, sphere(160, 100))
    tile = tmp_path / "tile.png"
    write_png(tile, np.arange(20 * 30 * 3, dtype=np.uint8).reshape(20, 30, 3))
    for pattern, channels in (("colour", 3), (str(tile), 3)):
        out = tmp_path / "p.png"
        assert main([src, "--out", str(out), "--pattern", pattern, "--method", "row",
                     "--size", "320x200"]) == 0
        assert read_png(out).shape == (200, 320, channels)
    assert "row 320x200" in capsys.readouterr().out


@pytest.mark.parametrize("depth, extra, words", [
    (np.full((20, 200), np.nan, np.float32), [], "NaN"),
    (np.full((20, 200), np.inf, np.float32), [], "all empty"),
    (np.zeros((0, 0), np.float32), [], "empty"),
    (sphere(100, 20), ["--eye-sep", "180"], "half the width"),
    (np.zeros((3, 4, 5), np.float32), [], "2-D"),
])
def test_bad_input_is_one_line_and_status_2(tmp_path, capsys, depth, extra, words):
    out = tmp_path / "never.png"
    assert main([_npy(tmp_path, depth), "--out", str(out), *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("holo-sird: error:") and words in err and err.count("\n") == 1
    assert not out.exists()


@pytest.mark.parametrize("argv", [["--mu", "0.6"], ["--mu", "0"], ["--eye-sep", "-3"],
                                  ["--method", "magic"]])
def test_bad_options_are_usage_errors(tmp_path, argv):
    with pytest.raises(SystemExit) as exc:
        main([_npy(tmp_path, sphere(200, 20)), "--out", str(tmp_path / "x.png"), *argv])
    assert exc.value.code == 2


def test_not_a_depth_file(tmp_path, capsys):
    bad = tmp_path / "junk.npy"
    bad.write_bytes(b"not numpy at all")
    assert main([str(bad), "--out", str(tmp_path / "x.png")]) == 2
    assert "holo-sird: error:" in capsys.readouterr().err


@pytest.mark.parametrize(("old", "new", "words"), [
    ("(20, 200)", "(100000000000,)", "need 400000000000 bytes"),  # np.load: MemoryError
    ("'descr'", "'de(cr'", "not a readable .npy header"),  # np.load: TokenError
])
def test_a_damaged_npy_header_is_one_line_not_a_crash(tmp_path, capsys, old, new, words):
    path = _npy(tmp_path, sphere(200, 20).astype(np.float32))
    data = open(path, "rb").read()
    end = data.index(b"\n")
    head = data[:end].decode("latin1")
    assert old in head
    head = head.replace(old, new, 1).rstrip(" ")
    open(path, "wb").write(head.ljust(end).encode("latin1") + data[end:])
    assert main([path, "--out", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert "holo-sird: error:" in err and words in err and err.count("\n") == 1
