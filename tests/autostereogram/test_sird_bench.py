"""``holo-bench sird`` runs small, writes CSV, JSON and chart; bad values are usage errors."""

from __future__ import annotations

import csv
import json

import pytest

from service.commands import holo_bench as cli_bench


def test_a_small_run_writes_csv_json_and_chart(tmp_path, capsys):
    assert cli_bench.main(["sird", "--sizes", "200x60", "--scenes", "sphere,slope",
                           "--repeats", "1", "--service-size", "160x120",
                           "--out", str(tmp_path)]) == 0
    rows = list(csv.DictReader((tmp_path / "sird_bench.csv").open()))
    assert {(r["method"], r["scene"]) for r in rows} == {
        (m, s) for m in ("row", "interpolated", "tiw") for s in ("sphere", "slope")}
    assert all(r["broken"] == "0" for r in rows)
    data = json.loads((tmp_path / "sird_bench.json").read_text())
    assert [r["method"] for r in data["stability"]] == ["row", "interpolated", "tiw"]
    assert all(r["changed_per_frame"] < 0.05 for r in data["stability"])
    assert (tmp_path / "sird_bench.png").stat().st_size > 10_000
    service = list(csv.DictReader((tmp_path / "sird_service.csv").open()))
    assert [r["method"] for r in service] == ["row", "interpolated", "tiw"]
    assert all(0 < float(r["sird_ms_best"]) <= float(r["sird_ms_p50"]) for r in service)
    ratios = {(r["method"], r["scene"]): r["of_row"] for r in data["streak_ratios"]}
    assert ratios[("interpolated", "slope")] <= 0.1
    out = capsys.readouterr().out
    assert "stability tiw" in out and "service tiw" in out


@pytest.mark.parametrize("argv, words", [(["--methods", "nosuch"], "--methods: want one of"),
                                         (["--sizes", "0x3"], "--sizes")])
def test_bad_values_are_usage_errors(argv, words, capsys):
    with pytest.raises(SystemExit) as exc:
        cli_bench.main(["sird", *argv])
    assert exc.value.code == 2 and words in capsys.readouterr().err
