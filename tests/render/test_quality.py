"""--quality auto: budgets parsed, the cheapest method picked, measured error within budget."""

import json

import numpy as np
import pytest

from service.base.errors import SettingsError
from service.builtin_scenes import builtin_scene
from service.display import DisplaySettings
from service.lod.cost import CostModel
from service.quality import (
    ErrorBudget,
    QualityChooser,
    QualitySettings,
    cheapest_occlusion,
    parse_budget,
    render_auto,
)
from service.render.pipeline import Renderer
from service.scene_motion import advance_scene

SMALL = DisplaySettings(zones=5, angle_deg=16.0, cols=64, rows=48)


def test_budgets_parse_as_percent_or_psnr():
    assert parse_budget("0.5") == ErrorBudget(max_pct=0.5)
    assert parse_budget(" 2% ") == ErrorBudget(max_pct=2.0)
    assert parse_budget(1) == ErrorBudget(max_pct=1.0)
    assert parse_budget("40dB") == ErrorBudget(max_pct=None, min_psnr=40.0)
    for bad in ("3x", "-1", "150%", "", "dB", "0dB", True):
        with pytest.raises(SettingsError):
            parse_budget(bad)
    assert ErrorBudget(max_pct=1.0).allows(1.0, 0.0) and not ErrorBudget(1.0).allows(1.1, 99)
    assert ErrorBudget(None, 30.0).allows(50.0, 30.0) and not ErrorBudget(None, 30).allows(0, 29)


def test_measured_error_stays_within_the_budget_over_scenes():
    # the shipped (measured) cost model; error against ray casting + per-point light
    from service.bench.quality_bench import check

    rows = check(CostModel.load(), (64, 48), zones=5, frames=2,
                 budgets=("0.1%", "2%", "30dB"))
    assert {r["scene"] for r in rows} == {"game", "sphere-torus", "cyclic", "threaded", "demo"}
    for r in rows:
        assert r["within_budget"], r
        assert r["method"] in ("runlength", "zbuffer", "bsp"), r
    # a looser budget never buys a costlier light
    rank = {"polygon": 0, "vertex": 1, "point": 2}
    for scene in {r["scene"] for r in rows}:
        tight = [rank[r["specular"]] for r in rows if r["scene"] == scene and r["budget"] == "0.1%"]
        loose = [rank[r["specular"]] for r in rows if r["scene"] == scene and r["budget"] == "2%"]
        assert max(loose) <= min(tight), scene


def _model(runlength, zbuffer, bsp, build=(0.0, 0.0)):
    """A cost model with given occlusion coefficients (1, k tri-zones, M px-zones, k bad).

    The per-triangle term (:func:`service.lod.cost.occlusion_features`) is left at 0.
    """
    base = CostModel.load()
    occ = {m: [c[0], 0.0, *c[1:]] for m, c in
           (("runlength", runlength), ("zbuffer", zbuffer), ("bsp", bsp))}
    return CostModel(occ, list(build), base.light, base.galilean, {}, base.update_factor)


def _frames(scene_name, model, frames, moving=False, budget="2%"):
    chooser = QualityChooser(QualitySettings("auto", parse_budget(budget)), model)
    scene, r, out = builtin_scene(scene_name), Renderer(), []
    for k in range(frames):
        s = advance_scene(scene, 0.05 * k) if moving else scene
        if moving:  # builtin scenes may stand still: nudge every object
            for o in s.objects:
                o.transform.position[0] += 1e-3 * k
        out.append(render_auto(r, chooser, s, SMALL))
    return out


def test_a_sort_cycle_makes_it_leave_runlength():
    # a machine where the run-length kernel is the cheapest and each repaired point costs
    model = _model([0.0, 0.0, 1.0, 40.0], [0.0, 0.0, 5.0, 0.0], [0.0, 0.0, 50.0, 0.0])
    consistent = _frames("sphere-torus", model, 3)
    assert [f.stats["quality"]["method"] for f in consistent] == ["runlength"] * 3
    cyclic = _frames("cyclic", model, 3)
    assert cyclic[0].stats["quality"]["method"] == "runlength"  # nothing known yet
    assert cyclic[0].stats["occlusion"]["inconsistent_pixels"] > 0
    assert cyclic[0].stats["occlusion"]["fallback"] == "pixel"  # repaired, so still exact
    assert [f.stats["quality"]["method"] for f in cyclic[1:]] == ["zbuffer"] * 2


def test_a_static_scene_picks_bsp_when_it_is_cheapest_and_a_moving_one_never():
    # traversal cheapest, but its tree costs 3 frames of z-buffer to build
    model = _model([0.0, 0.0, 50.0, 0.0], [0.0, 0.0, 10.0, 0.0], [0.0, 0.0, 1.0, 0.0],
                   build=(3 * 10.0 * 0.01536, 0.0))
    static = [f.stats["quality"]["method"] for f in _frames("cyclic", model, 6)]
    assert static[0] == "zbuffer"  # not known to be static yet
    assert static[-1] == "bsp" and static.index("bsp") >= 2  # once the build is shared
    assert static[static.index("bsp"):] == ["bsp"] * (6 - static.index("bsp"))
    moving = [f.stats["quality"]["method"] for f in _frames("cyclic", model, 4, moving=True)]
    assert "bsp" not in moving
    measured = [f.stats["quality"]["method"] for f in _frames("cyclic", CostModel.load(), 2)]
    assert measured[0] != "bsp"  # the shipped model never builds a tree for one frame


#: Run-length cheaper per frame, the z-buffer per triangle: they cross at 10k
#: triangle-zones; BSP's traversal cheapest of all, its tree 1 ms per k triangles.
BY_SIZE = ([0.0, 0.05, 0.0, 0.0], [0.3, 0.02, 0.0, 0.0], [0.0, 0.01, 0.0, 0.0], (0.0, 1.0))


def test_the_cheapest_method_by_scene_size_on_given_costs():
    model, px = _model(*BY_SIZE), 320 * 240
    pick = {t: cheapest_occlusion(model, t, 1, px)[0] for t in (1000, 8000, 10**5, 10**6)}
    assert pick == {1000: "runlength", 8000: "runlength", 10**5: "zbuffer", 10**6: "zbuffer"}
    assert cheapest_occlusion(model, 1000, 5, px)[0] == "runlength"  # 5k triangle-zones
    assert cheapest_occlusion(model, 4000, 5, px)[0] == "zbuffer"  # 20k
    method, ms = cheapest_occlusion(model, 10**6, 1, px)
    assert set(ms) == {"runlength", "zbuffer"}  # moving: no tree rebuilt every frame
    assert ms["zbuffer"] == pytest.approx(0.3 + 0.02 * 1000)
    # static: the tree's build is shared by the frames the geometry stayed put
    assert cheapest_occlusion(model, 10**5, 1, px, static_frames=60)[0] == "zbuffer"
    assert cheapest_occlusion(model, 10**5, 1, px, static_frames=60, tree_built=True)[0] == "bsp"
    assert cheapest_occlusion(model, 10**6, 1, px, static_frames=60)[0] == "zbuffer"
    assert cheapest_occlusion(model, 10**6, 1, px, static_frames=600)[0] == "bsp"
    # every point the sort got wrong costs the run-length method its repair
    assert cheapest_occlusion(_model([0.0, 0.05, 0.0, 100.0], *BY_SIZE[1:]), 1000, 1, px,
                              bad=10)[0] == "zbuffer"


def test_auto_picks_by_the_size_of_real_scenes():
    from service.bench.galilean_bench import complexity_scene

    model, d = _model(*BY_SIZE), DisplaySettings(zones=1, cols=64, rows=48)
    for extra, expected in ((0, "runlength"), (20_000, "zbuffer")):
        scene = complexity_scene(extra, d)
        chooser = QualityChooser(QualitySettings("auto"), model)
        frame = render_auto(Renderer(), chooser, scene, d)
        assert frame.stats["quality"]["method"] == expected, extra
        exact = Renderer().render(scene, d)  # the z-buffer's
        np.testing.assert_array_equal(frame.depth, exact.depth)


def test_choices_and_predictions_are_reported_per_frame():
    f = _frames("game", CostModel.load(), 1)[0]
    q = f.stats["quality"]
    assert q["painter_fallback"] == "pixel"
    assert set(q["predicted_ms"]) >= {"occlusion_runlength", "occlusion_zbuffer", "total"}
    assert "occlusion_bsp" not in q["predicted_ms"]  # not static yet
    assert q["predicted_ms"]["total"] > 0
    assert {"pct_wrong", "psnr", "occlusion_pct_wrong"} <= set(q["predicted_error"])
    assert q["predicted_error"]["pct_wrong"] <= 2.0
    json.dumps(q)  # plain JSON


def test_galilean_order_and_interval_fit_the_budget():
    model = CostModel.load()
    rows = [r for r in model.galilean if r["motion"] == "rotating-cube"]
    assert rows, "the shipped model carries the order x interval sweep"
    picks = {}
    for text in ("0.01%", "1%", "10%", "20dB"):
        chooser = QualityChooser(QualitySettings("auto", parse_budget(text)), model)
        g = chooser.galilean("rotating-cube", 5.0, SMALL)
        assert g is not None
        b = parse_budget(text)
        assert b.allows(g["predicted_pct_wrong"], g["predicted_psnr"])
        picks[text] = g
    assert picks["0.01%"]["interval"] <= picks["10%"]["interval"]
    assert picks["10%"]["interval"] > 1  # a loose budget lets refreshes stand in for renders
    still = QualityChooser(QualitySettings("auto"), model).galilean("none", 5.0, SMALL)
    assert still["predicted_pct_wrong"] == 0.0 and still["interval"] >= 8


def test_cost_model_files_are_checked(tmp_path):
    bad = tmp_path / "m.json"
    bad.write_text('{"occlusion": {}}')
    with pytest.raises(SettingsError, match="m.json"):
        CostModel.load(bad)
    good = tmp_path / "g.json"
    good.write_text(CostModel.load().to_json())
    assert CostModel.load(good).occlusion == CostModel.load().occlusion
    assert np.isfinite(CostModel.load().occlusion_ms("zbuffer", 1000, 5, 76800))
    # a model calibrated before the per-triangle term: told to recalibrate, not misread
    old = json.loads(CostModel.load().to_json())
    old["occlusion"] = {m: c[:1] + c[2:] for m, c in old["occlusion"].items()}
    (tmp_path / "old.json").write_text(json.dumps(old))
    with pytest.raises(SettingsError, match="recalibrate"):
        CostModel.load(tmp_path / "old.json")


def _render_json(capsys, *argv):
    from service.commands import holo_render as cli_render

    try:
        code = cli_render.main([*argv, "--json"])
    except SystemExit as exc:  # argparse's usage errors
        code = exc.code
    captured = capsys.readouterr()
    return code, (json.loads(captured.out) if code == 0 else captured.err)


def test_holo_render_quality_auto_reports_its_choice(tmp_path, capsys):
    code, rep = _render_json(capsys, "builtin:game", "--quality", "auto", "--max-error", "40dB",
                             "--size", "64x48", "--out", str(tmp_path))
    assert code == 0
    q = rep["quality"]
    assert rep["settings"]["quality"] == "auto"
    assert rep["settings"]["max_error"] == {"max_pct": None, "min_psnr": 40.0}
    assert rep["settings"]["method"] == q["method"] and rep["settings"]["specular"] == q["specular"]
    assert q["predicted_error"]["psnr"] >= 40.0
    code, rep = _render_json(capsys, "builtin:game", "--size", "64x48", "--out", str(tmp_path))
    assert rep["quality"] is None and rep["settings"]["quality"] == "fixed"
    code, err = _render_json(capsys, "builtin:game", "--max-error", "lots")
    assert code == 2 and "--max-error" in err


def test_scene_file_quality_table(tmp_path, capsys):
    scene = tmp_path / "s.toml"
    body = '[[object]]\nprimitive = "sphere"\n'
    scene.write_text('[quality]\nmode = "auto"\nmax_error = "1%"\n' + body)
    code, rep = _render_json(capsys, str(scene), "--size", "48x36", "--out", str(tmp_path))
    assert code == 0 and rep["settings"]["quality"] == "auto"
    assert rep["settings"]["max_error"]["max_pct"] == 1.0
    code, rep = _render_json(capsys, str(scene), "--quality", "fixed", "--size", "48x36",
                             "--out", str(tmp_path))
    assert rep["quality"] is None  # the command line wins
    for table, word in (('mode = "best"', "mode"), ('max_error = "x"', "max_error"),
                        ('speed = 1', "speed")):
        scene.write_text(f"[quality]\n{table}\n" + body)
        code, err = _render_json(capsys, str(scene), "--out", str(tmp_path))
        assert code == 2 and "s.toml" in err and word in err, err


def test_fit_recovers_costs_and_never_predicts_negative_work():
    from service.lod.cost import fit

    rng = np.random.default_rng(1)
    x = [np.array([1.0, *rng.uniform(0, 10, 3)]) for _ in range(40)]
    truth = np.array([0.5, 0.2, 3.0, 0.0])
    coef = fit([(f, float(f @ truth) + rng.normal(0, 1e-3)) for f in x])
    assert np.allclose(coef, truth, atol=0.01)
    # a cost that falls with the work (noise) gets no negative slope
    coef = fit([(f, 5.0 - 0.3 * f[1]) for f in x])
    assert min(coef) >= 0.0


def test_the_scaling_check_says_whether_auto_picks_the_fastest():
    from service.bench.quality_bench import scaling_check

    model = _model(*BY_SIZE)
    rows = [{"scene": "a", "triangles": 1000, "zones": 1, "size": "320x240", "pixels": 76800,
             "bad": 0, "runlength_ms": 0.04, "zbuffer_ms": 0.3, "bsp_ms": 0.02,
             "bsp_build_ms": 60.0},
            {"scene": "b", "triangles": 10**6, "zones": 1, "size": "320x240", "pixels": 76800,
             "bad": 0, "runlength_ms": 10.0, "zbuffer_ms": 30.0}]
    small, big = scaling_check(model, rows)
    assert (small["moving_pick"], small["moving_fastest"]) == ("runlength", "runlength")
    # static: BSP's traversal measured fastest, but not with its 60 ms build shared by
    # 60 frames; the model predicts a 1 ms build: the check shows the miss
    assert (small["static_pick"], small["static_fastest"]) == ("bsp", "runlength")
    assert small["zbuffer_predicted_ms"] == pytest.approx(0.3 + 0.02)
    assert (big["moving_pick"], big["moving_fastest"]) == ("zbuffer", "runlength")  # a miss
    assert "bsp_predicted_ms" not in big  # not timed past 100k triangles
