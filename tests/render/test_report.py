"""holo-bench report: one self-contained page; its failure map names tests that exist."""

import base64
import json
import re
from pathlib import Path

from service.bench import report

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
    from service.cli_bench import BENCHES

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
    from service.cli_bench import BENCHES

    planned = {n for p in report.PLANS for n in (p.bench, *report.ALIASES.get(p.bench, ()))}
    assert set(BENCHES) - {"report"} <= planned


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
