"""holo-bench: a bad value is a one-line usage error (exit status 2), before any work."""

from __future__ import annotations

import subprocess
import sys

import pytest
from testkit import ROOT

from service.commands import holo_bench as cli_bench

#: (benchmark, bad option and value, words of the message)
BAD = [
    ("light", ["--zones", "0"], "--zones: must be from 1 to 64"),
    ("light", ["--zones", "1,x"], "--zones: want an integer"),
    ("light", ["--size", "abc"], "--size: want WxH"),
    ("light", ["--scenes", "nosuch"], "unknown scene 'nosuch'; known: sphere, game"),
    ("light", ["--repeats", "0"], "--repeats: must be >= 1"),
    ("galilean", ["--size", "abc"], "--size: want WxH"),
    ("galilean", ["--time-size", "0x480"], "--time-size: width and height"),
    ("galilean", ["--interval", "0"], "--interval: must be >= 1"),
    ("galilean", ["--frames", "-3"], "--frames: must be >= 1"),
    ("galilean", ["--sweep-frames", "1"], "--sweep-frames: must be >= 2"),
    ("galilean", ["--complexity-repeats", "0"], "--complexity-repeats: must be >= 1"),
    ("galilean", ["--complexity-counts", "1,-2"], "counts must be >= 0"),
    ("galilean", ["--order", "7"], "--order: invalid choice"),
    ("service", ["--workers", "0,x"], "--workers: want an integer"),
    ("service", ["--seconds", "0"], "--seconds: must be > 0"),
    ("service", ["--rounds", "0"], "--rounds: must be >= 1"),
    ("filters", ["--out", "x", "--lead-ms", "-1"], "--lead-ms: must be >= 0"),
    ("latency", ["--out", "x", "--frames", "0"], "--frames: must be >= 1"),
    ("latency", ["--out", "x", "--rate", "0"], "--rate: must be > 0"),
    ("decoders", ["--out", "x", "--scale", "0"], "--scale: must be > 0"),
    ("decoders", ["--out", "x", "--chunk", "0"], "--chunk: must be >= 1"),
    ("decoders", ["--out", "x", "--repeat", "abc"], "--repeat: want an integer"),
]


@pytest.mark.parametrize(("bench", "argv", "words"), BAD,
                         ids=[f"{b}{' '.join(a)}" for b, a, _ in BAD])
def test_bad_values_are_usage_errors(bench, argv, words, capsys, tmp_path):
    with pytest.raises(SystemExit) as exc:
        cli_bench.main([bench, *argv])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"holo-bench {bench}: error: " in err and words in err, err
    assert "Traceback" not in err


@pytest.mark.parametrize("argv", [["light", "--zones", "0"], ["light", "--size", "abc"],
                                  ["render", "--scenes", "nosuch", "--quick"]],
                         ids=["light-zones", "light-size", "render-scenes"])
def test_as_a_user_runs_it(argv, tmp_path):
    r = subprocess.run([sys.executable, "-m", "service.commands.holo_bench", *argv, "--out",
                        str(tmp_path)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 2
    errors = [ln for ln in r.stderr.splitlines() if "error:" in ln]
    assert len(errors) == 1 and "Traceback" not in r.stderr, r.stderr
    assert "nosuch" in errors[0] or argv[-1] in errors[0]


def test_unknown_benchmark_and_the_help(capsys):
    assert cli_bench.main(["nosuch"]) == 2
    assert "unknown benchmark 'nosuch'" in capsys.readouterr().err
    assert cli_bench.main(["--help"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in cli_bench.BENCHES) and "130" in out


@pytest.mark.parametrize(("out", "words"), [
    ("/dev/null", "is a file, not a folder"),
    ("/dev/null/sub", "/dev/null is a file, not a folder"),
], ids=["a-file", "under-a-file"])
def test_an_unwritable_out_folder_is_refused_before_any_work(out, words, tmp_path):
    """The folder is checked before the benchmark starts (it used to end in an errno line)."""
    r = subprocess.run([sys.executable, "-m", "service.commands.holo_bench", "report", "--quick",
                        "--out", out], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [f"holo-bench report: error: --out {out}: {words}"]
    assert "Errno" not in r.stderr


def test_file_errors_are_named_without_errno():
    err = FileNotFoundError(2, "No such file or directory", "/x/y")
    assert cli_bench._message(err) == "/x/y: No such file or directory"
    assert cli_bench._message(OSError("plain")) == "plain"


def test_help_names_the_benchmarks_that_exit_1(capsys):
    """`quality` over its budget and `report` with nothing run exit 1: the help says so."""
    assert cli_bench.main(["--help"]) == 0
    text = capsys.readouterr().out
    assert "1: quality found a frame over its error budget, or report ran no benchmark" in text
