"""holo-bench report: one self-contained page; its failure map names tests that exist."""

import base64
import json
import re
import signal
from pathlib import Path

import pytest

from service.bench import picks, report

ROOT = Path(__file__).resolve().parents[2]
PNG = b"\x89PNG\r\n\x1a\n"


def test_a_tiny_report_writes_every_section_with_valid_inline_images(tmp_path, capsys):
    out = tmp_path / "rep"
    status = report.main(["--quick", "--no-warmup", "--only", "light,decoders",
                          "--size", "32x24", "--out", str(out)])
    assert status == 0
    page = (out / "index.html").read_text()
    for section in ("light", "decoders", "failure-map"):
        assert f'id="{section}"' in page, section
    assert page.count("<h3>Stage table</h3>") == 2  # light and decoders ran
    # self-contained: every image inline, nothing fetched from elsewhere
    assert not re.search(r'(src|href)="(?!data:|#)', page)
    images = re.findall(r'<img alt="([^"]+)" src="data:image/png;base64,([^"]+)">', page)
    assert [name for name, _ in images] == ["light_bench.png"]
    for _, data in images:
        assert base64.b64decode(data, validate=True)[:8] == PNG
    # every chart has its sentence, and the light table its rows
    captions = re.findall(r"<figcaption><b>([^<]+)</b>: ([^<]+)</figcaption>", page)
    assert captions and all(len(text) > 40 for _, text in captions)
    assert "phong per polygon" in page and "against the best peer" in page
    meta = json.loads((out / "report.json").read_text())
    assert meta["benches"]["light"]["ran"] and meta["benches"]["decoders"]["ran"]
    assert "wrote" in capsys.readouterr().out


def test_a_benchmark_not_built_is_a_row_saying_so(tmp_path):
    from service.commands.holo_bench import BENCHES

    plan = report.Plan("no-such-bench", "Something not written yet", ((),), ((),))
    res = report.run_plan(plan, BENCHES, tmp_path, True, "32x24")
    assert not res.ok and res.reason.startswith("not built")
    page = report.page([res], {"what": "t", "wall_s": 0.0, "cpu_s": 0.0, "machine": "m"}, ROOT)
    assert "Not run: not built" in page and 'id="failure-map"' in page


def test_the_occlusion_table_sets_each_method_against_the_best_peer(tmp_path):
    rows = [{"scene": "game", "zones": 5, "method": "zbuffer", "ms": 4.0, "pct_differ": 0.0},
            {"scene": "cyclic", "zones": 1, "method": "bsp", "ms": 1.0, "pct_differ": 0.0}]
    peers = [{"scene": "game", "zones": 5, "peer": "llvmpipe", "peer_ms": 8.0},
             {"scene": "game", "zones": 5, "peer": "embree", "peer_ms": 40.0}]
    (tmp_path / "render_bench.json").write_text(json.dumps(rows))
    (tmp_path / "peers.json").write_text(json.dumps(peers))
    (tmp_path / "peers_status.json").write_text(json.dumps(
        {"not_started": {"embree": "embreex not installed"}}))
    table = report.render_table(tmp_path)
    assert [r[1] for r in table.rows] == ["game, 5 zones", "cyclic, 1 zone"]
    assert table.rows[0][-1] == "0.50 x llvmpipe"
    assert table.rows[1][-1] == "no peer measured"
    assert "embree: embreex not installed" in table.note


def test_every_test_the_failure_map_names_exists():
    named = [t for f in report.FAILURES for t in (*f.shown_by, *f.detected_by)]
    assert len(named) >= 8
    missing = [t for t in named if not report.test_exists(t, ROOT)]
    assert not missing, missing
    assert not report.test_exists("tests/render/test_pipeline.py::no_such_test", ROOT)
    assert not report.test_exists("tests/nowhere.py::test_x", ROOT)


def test_every_failure_the_issue_lists_has_a_row():
    methods = " ".join(f.method + " " + f.where for f in report.FAILURES).lower()
    for words in ("cyclic", "16 degrees", "g(1)", "rotation", "g(3)", "noisy", "sird",
                  "streaks", "billboard", "parallax"):
        assert words in methods, words


def test_every_registered_benchmark_has_a_plan():
    """A benchmark without one shows in the page as "not run" with no figures."""
    from service.commands.holo_bench import BENCHES

    planned = {n for p in report.PLANS for n in (p.bench, *report.ALIASES.get(p.bench, ()))}
    inside = {n for n, host in report.RUN_INSIDE.items() if host in planned}
    assert set(BENCHES) - {"report"} <= planned | inside


def test_the_latency_table_gives_percentiles_per_leg_and_the_target(tmp_path):
    legs = {"published": {"p50_ms": 0.08, "p95_ms": 0.12, "p99_ms": 0.5, "max_ms": 3.0,
                          "n": 200},
            "total": {"p50_ms": 0.25, "p95_ms": 0.38, "p99_ms": 2.7, "max_ms": 3.8, "n": 200}}
    (tmp_path / "latency.json").write_text(json.dumps({
        "target_p99_ms": 2.0, "headline": "inline: arrival -> published", "target_met": True,
        "lost": {"inline": 0, "bare_hop": 1}, "wirings": {"inline": legs},
        "bare_hop": {"p50_ms": 0.14, "p95_ms": 0.2, "p99_ms": 3.3, "max_ms": 4.3, "n": 199}}))
    table = report.latency_table(tmp_path)
    assert table.headers[2:6] == ["p50 ms", "p95 ms", "p99 ms", "max ms"]
    assert table.rows == [["inline", "published", "0.080", "0.120", "0.500", "3.000", "200", "0"],
                          ["inline", "total", "0.250", "0.380", "2.700", "3.800", "200", "0"],
                          ["(reference)", "bare_hop", "0.140", "0.200", "3.300", "4.300", "199",
                           "1"]]
    assert "p99 <= 2.000 ms: met" in table.note


def test_the_filters_table_has_one_row_per_filter_setting(tmp_path):
    rows = [{"dataset": d, "filter": "alpha-beta", "line": "alpha-beta", "params": "theta=0.5",
             "ang_lag_ms": 32.0, "ang_rms_err": 0.119, "ang_vel_rms_err": None,
             "us_per_sample": 17.04} for d in ("still", "sway")]
    rows.append({"dataset": "still", "filter": "raw", "line": "raw", "params": "-",
                 "ang_rms_err": 0.149})
    (tmp_path / "results.json").write_text(json.dumps({"meta": {}, "rows": rows}))
    table = report.filters_table(tmp_path)
    assert table.headers[:4] == ["filter", "params", "lag ms", "jit deg"]
    assert [r[:4] for r in table.rows] == [["alpha-beta", "theta=0.5", "32", "0.119"],
                                           ["raw", "-", "-", "0.149"]]
    assert table.rows[0][5] == "-" and table.rows[0][-1] == "17.0"  # missing; us/sample


# ------------------------------------------------------------------ what to pick
def occ(scene, zones, method, ms, pct):
    return {"scene": scene, "zones": zones, "method": method, "ms": ms, "pct_differ": pct}


def test_picks_are_the_fastest_exact_and_the_cheapest_within_half_a_percent():
    rows = [occ("game", 5, "zbuffer", 1.3, 0.0), occ("game", 5, "bsp", 5.0, 0.0),
            occ("game", 5, "runlength", 0.9, 0.3), occ("game", 5, "sloppy", 0.2, 2.0),
            occ("cyclic", 1, "runlength", 0.1, 0.7)]
    game, cyclic = picks.occlusion_picks(rows)
    assert (game.case, game.exact, game.within) == ("game, 5 zones", ("zbuffer", 1.3),
                                                    ("runlength", 0.9, 0.3))
    assert cyclic.exact is None and cyclic.within is None  # nothing exact, nothing within
    assert picks.tally([game, cyclic]) == (
        "Occlusion: the fastest exact method is zbuffer in 1 of 2 cases; the cheapest within "
        "0.5 % error is runlength in 1 of 2 cases.")
    assert picks.tally([game, game, cyclic]).startswith(
        "Occlusion: the fastest exact method is zbuffer in 2 of 3 cases;")
    light = picks.light_picks([{"scene": "sphere", "zones": 1, "model": m, "evaluation": e,
                                "ms": ms, "error": err}
                               for m, e, ms, err in (("blinn", "point", 0.76, 0.0),
                                                     ("blinn", "vertex", 0.38, 0.004),
                                                     ("blinn", "polygon", 0.17, 0.033))])
    assert light[0].exact == ("blinn per point", 0.76)
    assert light[0].within == ("blinn per vertex", 0.38, 0.4)  # error in % of full intensity


def test_the_galilean_stage_pays_from_the_break_even_interval():
    step = {"triangles": 30204, "render_ms": 7.0, "refresh_ms": 1.0,
            "render_with_motion_ms": 55.0}
    # one update and k - 1 refreshes against k renders: 55 + (k - 1) < 7 k from k > 9
    assert picks.break_even_refreshes(step) == 9.0
    flat = {"triangles": 12, "render_ms": 0.5, "refresh_ms": 0.6, "render_with_motion_ms": 5.0}
    assert picks.break_even_refreshes(flat) == float("inf")
    sweep = [{"order": 2, "interval": i, "psnr": p} for i, p in ((1, None), (4, 31.0),
                                                                  (4, 29.0), (4, 30.0))]
    first, quality = picks.galilean_pays({"size": "160x120", "refresh_hz": 60.0,
                                          "steps": [flat, step]}, sweep)
    assert first.startswith("The Galilean stage pays soonest with 30,204 triangles: one "
                            "update serving 9 refreshes or more (an update every 0.15 s at "
                            "60 Hz)")
    assert "with 12 triangles never (a refresh costs as much as a render)" in first
    assert "30.0 dB with an update every 4 refreshes" in quality
    (never,) = picks.galilean_pays({"steps": [flat]}, [])
    assert never.startswith("The Galilean stage does not pay at any size measured")


def _ran(tmp_path, bench: str, files: dict) -> report.Outcome:
    folder = tmp_path / bench
    folder.mkdir()
    for name, data in files.items():
        (folder / name).write_text(json.dumps(data))
    plan = next(p for p in report.PLANS if p.bench == bench)
    return report.Outcome(plan, bench, folder, ok=True)


def test_the_page_opens_with_what_to_pick_and_no_empty_peer_table(tmp_path):
    not_started = {"llvmpipe": "moderngl not installed; pip install -e '.[peers]'"}
    render = _ran(tmp_path, "render", {
        "render_bench.json": [occ("game", 5, "zbuffer", 1.3, 0.0),
                              occ("game", 5, "runlength", 0.9, 0.3)],
        "peers_status.json": {"started": {}, "not_started": not_started}})
    galilean = _ran(tmp_path, "galilean", {"galilean_complexity.json": {"steps": [
        {"triangles": 30204, "render_ms": 7.0, "refresh_ms": 1.0,
         "render_with_motion_ms": 55.0}]}})
    meta = {"what": "t", "wall_s": 0.0, "cpu_s": 0.0, "machine": "m"}
    text = report.page([render, galilean], meta, ROOT)
    top = text.index('id="picks"')
    assert top < text.index('id="render"') and top < text.index('id="galilean"')
    picks_part = text[top:text.index('id="render"')]
    assert "fastest exact method is zbuffer in 1 of 1 cases" in picks_part
    assert "cheapest within 0.5 % error is runlength in 1 of 1 cases" in picks_part
    assert "Caution" not in picks_part  # no seconds measured: no caveat
    assert "Light: not measured in this run" in picks_part
    assert "pays soonest with 30,204 triangles" in picks_part
    # no peer ran: no peer table and no column of "no peer measured", one line why
    assert "ours / peer" not in text and "no peer measured" not in text
    assert text.count("moderngl not installed") == 2  # the occlusion table's note, the line
    assert "No peer ran, so there is no peer table: llvmpipe: moderngl not installed" in text


# ------------------------------------------------------------------ keep what the user had
def _old_report(out: Path) -> dict[str, bytes]:
    """A previous report's page and data in ``out`` plus a file no report wrote."""
    (out / "decoders").mkdir(parents=True)
    (out / "render").mkdir()
    (out / "index.html").write_text("<p>the previous page</p>")
    (out / "report.json").write_text(json.dumps({"benches": {"decoders": {}, "render": {}}}))
    (out / "decoders" / "decoder_throughput.json").write_text('{"old": 1}')
    (out / "render" / "render_bench.json").write_text("[]")
    (out / "mine.png").write_bytes(PNG)  # e.g. a chart of a benchmark run by hand
    return _snapshot(out)


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


def test_a_finished_report_replaces_the_previous_one_and_keeps_other_files(tmp_path):
    out = tmp_path / "bench-out"
    _old_report(out)
    assert report.main(["--no-warmup", "--only", "decoders", "--out", str(out)]) == 0
    files = _snapshot(out)
    assert files["mine.png"] == PNG  # not the report's: kept
    assert "render/render_bench.json" not in files  # the previous run's data: gone with it
    assert b"previous page" not in files["index.html"]
    assert "old" not in json.loads(files["decoders/decoder_throughput.json"])
    assert list(json.loads(files["report.json"])["benches"]) == ["decoders"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bench-out"]  # no staging left


@pytest.mark.timeout(240)
def test_an_interrupted_report_leaves_the_previous_page_and_data_together(procs, tmp_path):
    out = tmp_path / "bench-out"
    before = _old_report(out)
    run = procs("service.commands.holo_bench", "report", "--quick", "--no-warmup", "--only",
                "light,decoders", "--size", "32x24", "--out", str(out))
    # the first benchmark has begun writing into the staging folder beside OUT
    run.wait_lines(lambda: any(tmp_path.glob("bench-out.partial-*/light")), timeout=120)
    staged = [p for p in tmp_path.iterdir() if p.name.startswith("bench-out.partial-")]
    assert len(staged) == 1
    run.signal(signal.SIGINT)  # Ctrl-C in the middle of the first benchmark
    assert run.finish(120) == 130
    assert _snapshot(out) == before  # the previous page and its data, untouched
    assert run.err[-2:] == [
        f"holo-bench report: {out} left as it was; what ran so far is in {staged[0]}",
        "holo-bench report: interrupted (SIGINT)"]
    assert staged[0].is_dir()  # what was written so far is kept, not deleted


def test_speed_picks_from_a_busy_machine_say_so(tmp_path):
    render = _ran(tmp_path, "render", {"render_bench.json": [occ("game", 1, "zbuffer", 1.3, 0)]})
    render.seconds, render.cpu_s = 109.0, 5.2  # other programs had the cores
    (line, *_), _ = report.recommendations([render])
    assert line.endswith("Caution: holo-bench render got 5 s of CPU in 109 s of wall time "
                         "(the machine was busy), so these speed picks may be wrong; run it "
                         "again on a quiet machine before trusting them.")
    render.cpu_s = 80.0
    assert "Caution" not in report.recommendations([render])[0][0]
