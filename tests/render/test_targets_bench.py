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


def test_floor_states_each_refresh_as_a_ratio_to_a_copy_of_its_map(tmp_path):
    rows = tb.floor_target((48, 36), 3)
    assert [r["target"] for r in rows] == ["floor-head-turn", "floor-still"]
    for r in rows:
        assert r["ms_copy"] > 0 and r["ms_refresh"] > 0 and r["map_mb"] > 0
        # ms are rounded to 1 us: a copy of this tiny map takes a few, so allow that
        slack = r["figure"] * (0.0005 / r["ms_copy"] + 0.0005 / r["ms_refresh"] + 0.01)
        assert abs(r["figure"] - r["ms_refresh"] / r["ms_copy"]) <= slack + 2e-3
        assert r["met"] == (r["figure"] <= r["goal"]) and r["ratio_cpu"] > 0
    assert rows[0]["ms_copy"] == rows[1]["ms_copy"]  # one copy, timed beside both
    assert "copy" in tb.summary(rows[0])
    assert tb.main(["--only", "floor", "--size", "48x36", "--repeats", "1", "--rounds", "1",
                    "--out", str(tmp_path)]) == 0
    got = json.loads((tmp_path / "targets.json").read_text())
    assert [r["target"] for r in got] == ["floor-head-turn", "floor-still"]


def test_median_round_keeps_the_median_rounds_row():
    """Each target's row is its median round's, whole; every round's figure is listed."""
    def row(target, figure, tag):
        return {"target": target, "figure": figure, "tag": tag, "met": False}

    rounds = [[row("refresh", 5.0, "a"), row("premise-10x", None, "a")],
              [row("refresh", 3.0, "b"), row("premise-10x", 9.0, "b")],
              [row("refresh", 4.0, "c"), row("premise-10x", 11.0, "c")]]
    refresh, tenx = tb.median_round(rounds)
    assert refresh["tag"] == "c" and refresh["figure"] == 4.0
    assert refresh["rounds"] == [5.0, 3.0, 4.0]
    assert tenx["tag"] == "c" and tenx["rounds"] == [None, 9.0, 11.0]  # no figure ranks last
    two = tb.median_round(rounds[:2])[0]  # an even count: the lower middle one
    assert two["tag"] == "b"
    assert "rounds 5.0, 3.0, 4.0" in tb.summary({**refresh, "what": "w", "goal": 4.0})


def test_targets_cli_rounds(tmp_path):
    """``--rounds 2``: the refresh row lists both rounds' figures and holds one of them."""
    assert tb.main(["--only", "refresh", "--size", "48x36", "--repeats", "2", "--rounds", "2",
                    "--out", str(tmp_path)]) == 0
    (row,) = json.loads((tmp_path / "targets.json").read_text())
    assert len(row["rounds"]) == 2 and row["figure"] == min(row["rounds"])
