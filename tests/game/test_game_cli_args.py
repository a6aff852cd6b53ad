"""holo-game checks its addresses and ``--out`` before it starts: a bad one is
one argparse error (status 2), never a traceback from zmq or a late errno line."""

from __future__ import annotations

import subprocess
import sys

import pytest
from testkit import ROOT


def _game(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "game.commands.holo_game", "--local", "--headless",
                           "--seconds", "1", *args], cwd=ROOT, text=True,
                          capture_output=True, timeout=120)


@pytest.mark.parametrize(("args", "words"), [
    (("--devices", "foo"), ("--devices", "not a ZeroMQ address")),
    (("--service", "tcp://127.0.0.1:99999"), ("--service", "99999", "not a port")),
    (("--frames", "tcp://:5556"), ("--frames",)),
])
def test_bad_address_is_a_usage_error(args, words):
    proc = _game(*args)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("holo-game: error: argument "), last
    for w in words:
        assert w in last, last


def test_out_that_is_a_file_is_a_usage_error(tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("mine")
    proc = _game("--out", str(afile))
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr and "Errno" not in proc.stderr
    assert proc.stderr.strip().splitlines()[-1] == (
        f"holo-game: error: --out {afile}: is a file, not a folder")
    assert afile.read_text() == "mine"
