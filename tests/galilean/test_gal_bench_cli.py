import json
import math

import pytest

from service.bench.galilean_bench import main
from service.commands.holo_bench import main as holo_bench


def test_cli_json_falling(capsys):
    assert holo_bench(["galilean", "--case", "falling", "--order", "0", "--interval", "3",
                       "--frames", "10", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["case"] == "falling" and doc["order"] == 0 and doc["interval"] == 3
    assert doc["errors"] == [0, 1, 4, 0, 7, 16, 0, 13, 28, 0]
    assert doc["ms_per_refresh"] >= 0


def test_cli_text_rotating_square(capsys):
    assert main(["--case", "rotating-square", "--order", "1", "--interval", "4",
                 "--frames", "8"]) == 0
    out = capsys.readouterr().out
    assert "rotating-square" in out and len(out.splitlines()) == 8 + 3


def test_cli_scene_case(capsys):
    assert main(["--case", "scene", "--order", "2", "--interval", "2", "--frames", "3",
                 "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert len(doc["errors"]) == 3 and max(doc["errors"]) < 3.0


def test_cli_complexity(tmp_path, capsys):
    assert main(["--complexity", "--time-size", "64x48", "--complexity-counts", "0,300,3000",
                 "--complexity-repeats", "2", "--out", str(tmp_path)]) == 0
    doc = json.loads(capsys.readouterr().out)
    for name in ("galilean_complexity.json", "galilean_complexity.csv",
                 "galilean_complexity.png"):
        assert (tmp_path / name).stat().st_size > 0
    assert json.loads((tmp_path / "galilean_complexity.json").read_text()) == doc
    steps = doc["steps"]
    assert doc["size"] == "64x48" and len(steps) == 3
    assert len((tmp_path / "galilean_complexity.csv").read_text().splitlines()) == 1 + 3
    tris = [s["triangles"] for s in steps]
    assert tris == sorted(set(tris)) and tris[0] == 252 and tris[-1] > 3000
    for s in steps:
        ms = [s["render_ms"], s["render_with_motion_ms"], s["refresh_ms"]]
        assert all(math.isfinite(m) and m > 0 for m in ms)
        assert s["render_ratio"] == pytest.approx(s["render_ms"] / s["refresh_ms"])
        assert s["update_ratio"] == pytest.approx(s["render_with_motion_ms"] / s["refresh_ms"])
        assert s["polygons_drawn"] > 0 and s["moving_pct"] > 0
    assert steps[-1]["polygons_drawn"] > steps[0]["polygons_drawn"]
    for key, ratio in (("crossover_10x_render", "render_ratio"),
                       ("crossover_10x_update", "update_ratio")):
        first = next((s["triangles"] for s in steps if s[ratio] >= 10), None)
        assert key in doc and doc[key] == first


def test_cli_complexity_counts_rejected():
    with pytest.raises(SystemExit):
        main(["--complexity", "--complexity-counts", "10,-5"])


def test_cli_timing(tmp_path, capsys):
    """--timing: every order, serial and threaded, and a head turn that moves everything."""
    assert main(["--timing", "--time-size", "64x48", "--out", str(tmp_path)]) == 0
    doc = json.loads(capsys.readouterr().out)
    for name in ("galilean_timing.json", "galilean_timing.csv", "galilean_timing.png"):
        assert (tmp_path / name).stat().st_size > 0
    runs = doc["orders"]
    assert {"G0", "G1", "G2", "G3", "G2-all-threads", "G2-all-threads-head-motion"} <= set(runs)
    assert doc["render_with_motion_ms"] > 0
    for v in runs.values():
        assert math.isfinite(v["ms_per_refresh"]) and 0 < v["ms_min"] <= v["ms_per_refresh"]
        assert v["render_ratio"] == pytest.approx(v["render_ms"] / v["ms_per_refresh"])
        assert v["update_ratio"] == pytest.approx(
            doc["render_with_motion_ms"] / v["ms_per_refresh"])
    assert doc["shadow"]["shadow_depth_ms"] > 0


def test_targets_refresh_and_premise_rows_print(tmp_path):
    """The refresh and premise rows of holo-bench targets: side figures, and one line each."""
    from service.bench import targets_bench as tb

    rows = [tb.refresh_target((48, 36), 17)]  # past one re-update (every 15 refreshes)
    rows += tb.premise_target((48, 36), 2, counts=(0, 3000))
    ref, flat, tenx = rows
    assert ref["ms_moving_min"] <= ref["ms_moving"] and ref["cpu_ms_moving"] > 0
    # the row rounds the ratio to 3 decimals: half a step of 0.001 is more than 1 % of a
    # small ratio (one run under pytest -n 2: 0.026 against 0.02551)
    assert flat["ratio_cpu"] == pytest.approx(
        flat["refresh_cpu_ms"][-1] / flat["refresh_cpu_ms"][0], rel=0.01, abs=5e-4)
    assert len(flat["moving_pct"]) == 2 and tenx["ratio_cpu"] is None  # no 100k step
    lines = [tb.summary(r) for r in rows]
    assert lines[1].startswith("premise-flat") and "CPU time" in lines[1]
    met = [r["met"] for r in rows]
    assert "CPU" in lines[0] and [("NOT met" not in x) for x in lines] == met


def test_cli_starvation(tmp_path, capsys):
    """One render then none: held past the use-by, where it is the render itself."""
    assert main(["--starvation", "--starve-seconds", "0.5", "--size", "48x32",
                 "--out", str(tmp_path)]) == 0
    summary = json.loads(capsys.readouterr().out)
    for name in ("galilean_starvation.json", "galilean_starvation.csv",
                 "galilean_starvation.png"):
        assert (tmp_path / name).stat().st_size > 0
    doc = json.loads((tmp_path / "galilean_starvation.json").read_text())
    assert doc["summary"] == summary and doc["n_prop"] == 16
    rows = doc["rows"]
    assert {r["motion"] for r in rows} == {"linear", "falling", "rotating-cube", "head-turn"}
    by = {(r["motion"], r["way"], r["refreshes"]): r for r in rows}
    for (motion, way, k), r in by.items():
        assert r["held"] == (way == "hold" and k > 16)
        if r["held"]:  # the held frame is the render: scored as the render alone
            alone = by[(motion, "render-only", k)]
            assert (r["psnr"], r["pct_wrong"]) == (alone["psnr"], alone["pct_wrong"])
    assert max(k for _, _, k in by) == 30


def test_cli_starvation_refuses_a_bad_gap(capsys):
    with pytest.raises(SystemExit):
        main(["--starvation", "--starve-seconds", "0"])
    assert "--starve-seconds" in capsys.readouterr().err
