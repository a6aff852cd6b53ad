"""The latency benchmark runs end to end and writes its files (no timing asserted)."""

from __future__ import annotations

import csv
import json
import sys

import pytest

from service.bench import latency_bench as bench_latency


@pytest.mark.parametrize("transport", [
    pytest.param("pty", marks=pytest.mark.skipif(sys.platform == "win32",
                                                 reason="pty pairs need POSIX")),
    "loop"])
def test_benchmark_writes_every_figure_for_each_wiring(tmp_path, transport, capsys):
    out = tmp_path / "bench"
    assert bench_latency.main(["--out", str(out), "--frames", "15", "--rate", "500",
                               "--transport", transport, "--wiring", "inline,hub"]) == 0
    report = json.loads((out / "latency.json").read_text())
    assert report["headline"] == "inline: arrival -> published"
    assert set(report["wirings"]) == {"inline", "hub"}
    for wiring, figs in report["wirings"].items():
        assert set(figs) == {"published", "received", "to_arrival", "total"}
        n = 15 - report["lost"][wiring]
        for s in figs.values():
            assert s["n"] == n and 0 < s["p50_ms"] <= s["p95_ms"] <= s["p99_ms"] <= s["max_ms"]
    assert report["bare_hop"]["n"] == 30 - report["lost"]["bare_hop"]
    assert isinstance(report["target_met"], bool)
    with (out / "latency.csv").open() as f:
        rows = list(csv.DictReader(f))
    frames = [r for r in rows if r["wiring"] != "bare_hop"]
    # (the subscriber may stamp its copy before the publishing thread is back from send)
    assert all(int(r["write_ns"]) <= int(r["arrival_ns"]) <= int(r["published_ns"])
               and int(r["arrival_ns"]) <= int(r["received_ns"]) for r in frames)
    assert (out / "latency.png").stat().st_size > 0
    assert "target: arrival -> published p99" in capsys.readouterr().out


@pytest.mark.skipif(sys.platform == "win32", reason="pty pairs need POSIX")
def test_opentrack_over_udp_and_native_over_a_pty_side_by_side(tmp_path, capsys):
    out = tmp_path / "bench"
    assert bench_latency.main(["--out", str(out), "--frames", "10", "--rate", "500",
                               "--protocol", "opentrack,native"]) == 0
    report = json.loads((out / "latency.json").read_text())
    assert report["headline"] == "opentrack inline: arrival -> published"
    assert report["settings"]["transport"] == "udp,pty"
    for label in ("opentrack inline", "native inline"):
        assert report["wirings"][label]["published"]["n"] == 10 - report["lost"][label]
    assert "opentrack over udp, native over pty" in capsys.readouterr().out


@pytest.mark.parametrize("argv", [["--protocol", "morse"], ["--protocol", "native,native"],
                                  ["--protocol", "native", "--transport", "udp"]])
def test_bad_protocols_are_usage_errors(tmp_path, argv):
    with pytest.raises(SystemExit) as exc:
        bench_latency.main(["--out", str(tmp_path), *argv])
    assert exc.value.code == 2


def test_unknown_wiring_is_a_usage_error(tmp_path):
    with pytest.raises(SystemExit):
        bench_latency.main(["--out", str(tmp_path), "--wiring", "inline,bogus"])
