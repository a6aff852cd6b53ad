from __future__ import annotations

import json
import os

import pytest

from game.highscores import KEEP, HighScoreFileError, HighScores


def test_scores_ranked_kept_and_read_back(tmp_path):
    path = tmp_path / "scores.json"
    table = HighScores.load(path)
    assert table.scores == []
    assert table.add("ann", 50, 5.0, "easy") == 1
    assert table.add("bob", 80, 8.0, "easy") == 1
    assert table.add("cid", 60, 6.0, "hard") == 2
    again = HighScores.load(path)
    assert [e["name"] for e in again.scores] == ["bob", "cid", "ann"]
    for k in range(KEEP):
        again.add(f"p{k}", 100 + k, 1.0, "normal")
    assert len(again.scores) == KEEP and again.add("low", 1, 1.0, "easy") is None
    assert not again.qualifies(1) and again.qualifies(10_000)


def test_a_failed_save_leaves_the_old_file_whole(tmp_path, monkeypatch):
    path = tmp_path / "scores.json"
    table = HighScores.load(path)
    table.add("ann", 50, 5.0, "easy")
    before = path.read_bytes()

    def crash(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", crash)
    with pytest.raises(OSError):
        table.add("bob", 99, 9.0, "easy")
    assert path.read_bytes() == before  # the old table, whole
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scores.json"]  # no temp left


@pytest.mark.parametrize(
    "content",
    [
        b"{not json",
        b"\xff\xfe",
        b'{"version": 1, "scores": 3}',
        b'{"version": 9, "scores": []}',
        b"[]",
        b'{"version": 1, "scores": [{"name": 1, "score": "x"}]}',
    ],
)
def test_a_corrupt_file_is_backed_up_never_lost(tmp_path, content):
    path = tmp_path / "scores.json"
    path.write_bytes(content)
    with pytest.raises(HighScoreFileError) as info:
        HighScores.load(path)
    assert info.value.backup is not None and info.value.backup.read_bytes() == content
    assert str(info.value.backup) in str(info.value)
    table = HighScores.load(path, recover=True)
    assert table.scores == [] and table.recovered_from is not None
    assert table.recovered_from.backup.name == "scores.json.corrupt-2"  # a second copy
    table.add("ann", 5, 1.0, "easy")
    assert json.loads(path.read_text())["scores"][0]["name"] == "ann"
    assert info.value.backup.read_bytes() == content  # the first copy is still there
