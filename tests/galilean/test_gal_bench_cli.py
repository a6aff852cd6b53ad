import json

from service.bench.galilean_bench import main
from service.cli_bench import main as holo_bench


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
