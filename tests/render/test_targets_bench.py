"""holo-bench targets: each target a ratio measured side by side, written as JSON and CSV."""

import csv
import json

from service.bench import targets_bench as tb


def test_targets_rows_and_files(tmp_path):
    rows = [tb.zones_target((48, 36), 2, rounds=2), tb.refresh_target((48, 36), 2)]
    rows += tb.premise_target((48, 36), 2, counts=(0, 3000))
    assert [r["target"] for r in rows] == ["zones", "refresh", "premise-flat", "premise-10x"]
    z = rows[0]
    assert abs(z["figure"] - z["ms_5"] / z["ms_1"]) < 0.01 * z["figure"] + 2e-3
    moving = z["ms_5_moving"] / z["ms_1_moving"]
    assert abs(z["ratio_moving"] - moving) < 0.01 * moving + 2e-3 and z["ratio_moving_cpu"] > 0
    assert rows[1]["ms_moving"] > 0 and rows[1]["met"] == (rows[1]["figure"] <= 4.0)
    assert rows[2]["triangles"][0] < rows[2]["triangles"][1]
    assert rows[3]["figure"] is None and not rows[3]["met"]  # no step reached 100k
    tb.write(rows, tmp_path)
    assert json.loads((tmp_path / "targets.json").read_text()) == json.loads(json.dumps(rows))
    with (tmp_path / "targets.csv").open() as fh:
        got = list(csv.DictReader(fh))
    assert [r["target"] for r in got] == [r["target"] for r in rows]
