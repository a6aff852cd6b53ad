"""Each demo run gets a folder of its own; ``latest`` names the newest; nothing is removed."""

from __future__ import annotations

import os

import pytest

from game.commands import make_demo as full_demo
from game.run_folders import RunFolderError, new_run_folder, point_latest, read_latest

NOON = 1_795_000_000.0  # any fixed time


def test_runs_in_the_same_second_get_folders_of_their_own(tmp_path):
    first = new_run_folder(tmp_path / "demo-out", NOON)
    (first / "stats.json").write_text("{}")
    second = new_run_folder(tmp_path / "demo-out", NOON)
    assert second.name == first.name + "-2"
    assert (first / "stats.json").read_text() == "{}"
    later = new_run_folder(tmp_path / "demo-out", NOON + 61)
    assert sorted([first.name, second.name, later.name])[-1] == later.name  # time order


def test_latest_names_the_newest_run_and_is_replaced_not_removed(tmp_path):
    root = tmp_path / "demo-out"
    one, two = new_run_folder(root, NOON), new_run_folder(root, NOON + 1)
    assert read_latest(root) is None
    point_latest(root, one)
    assert read_latest(root) == one
    latest = point_latest(root, two)
    assert latest.is_symlink() and os.readlink(latest) == two.name  # relative: the tree moves
    assert read_latest(root) == two and one.is_dir()
    assert sorted(p.name for p in root.iterdir()) == sorted([one.name, two.name, "latest"])


def test_where_links_fail_latest_is_a_file_naming_the_run(tmp_path, monkeypatch):
    root = tmp_path / "demo-out"
    run = new_run_folder(root, NOON)

    def no_links(self, *args, **kwargs):
        raise OSError(1, "Operation not permitted")

    monkeypatch.setattr(type(run), "symlink_to", no_links)  # a file system without links
    latest = point_latest(root, run)
    assert latest.is_file() and latest.read_text() == run.name + "\n"
    assert read_latest(root) == run


def test_a_folder_called_latest_is_left_alone_with_a_clear_error(tmp_path):
    root = tmp_path / "demo-out"
    (root / "latest").mkdir(parents=True)
    (root / "latest" / "mine.txt").write_text("keep")
    with pytest.raises(RunFolderError, match="is a folder"):
        point_latest(root, new_run_folder(root, NOON))
    assert (root / "latest" / "mine.txt").read_text() == "keep"


def test_an_out_that_is_a_file_is_one_line_and_status_1(tmp_path, capsys):
    taken = tmp_path / "demo-out"
    taken.write_text("not a folder")
    assert full_demo.main(["--out", str(taken), "--headless"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot make a run folder" in err[0]
    assert taken.read_text() == "not a folder"


def test_stopped_runs_stats_say_why_and_keep_the_games_own(tmp_path):
    run = new_run_folder(tmp_path, NOON)
    (run / "mode-head.png").write_bytes(b"png")
    full_demo.mark_stopped(run, {"interrupted": "SIGINT"})  # the game wrote none
    assert '"interrupted": "SIGINT"' in (run / "stats.json").read_text()
    assert '"mode-head.png"' in (run / "stats.json").read_text()
    (run / "stats.json").write_text('{"refreshes": 7}')  # the game wrote its own
    full_demo.mark_stopped(run, {"interrupted": "SIGTERM"})
    text = (run / "stats.json").read_text()
    assert '"refreshes": 7' in text and '"interrupted": "SIGTERM"' in text
