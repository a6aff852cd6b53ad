"""holo-sim CLI in a separate process: pty path on the first line, decodable stream."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import pytest
import serial
from testkit import HANG_S

from drivers.events import PoseEvent
from drivers.protocols import hatire, make_decoder, native
from drivers.pty_link import DRAIN_TIMEOUT_S
from sim_devices.commands.holo_sim import build_parser, main

START = {"hatire": hatire.encode_command("start"), "native": native.encode_command("start")}
posix_only = pytest.mark.skipif(sys.platform == "win32", reason="pty pairs need POSIX")


def test_help_lists_every_option(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for opt in ("--protocol", "--pty", "--tcp", "--motion", "--faults", "--seconds", "--seed",
                "--no-pace"):
        assert opt in out


def test_bad_settings_exit_2(capsys):
    assert main(["tracker", "--motion", "moonwalk", "--seconds", "0"]) == 2
    assert "unknown motion" in capsys.readouterr().err
    assert main(["tracker", "--faults", "corrupt=7", "--seconds", "0"]) == 2
    assert "corrupt must be in 0..1" in capsys.readouterr().err
    assert build_parser().parse_args(["dials"]).protocol is None  # main makes it hatire
    assert main(["tracker", "--udp", "127.0.0.1:4242", "--protocol", "native"]) == 2
    assert main(["dials", "--udp", "127.0.0.1:4242"]) == 2
    assert main(["tracker", "--protocol", "opentrack", "--tcp", "0"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert "opentrack poses go over UDP" in err[0] and "--udp is for the tracker" in err[1]
    assert "--protocol opentrack does not fit" in err[2]


@pytest.mark.parametrize(("name", "reason"), [("missing", "No such file or directory"),
                                             (".", "Is a directory")])
def test_an_unreadable_replay_file_is_one_line_and_status_2(tmp_path, name, reason):
    """It printed ``[Errno 2] No such file or directory: '/missing'`` (Python's text)."""
    path = tmp_path / name
    proc = subprocess.run(
        [sys.executable, "-m", "sim_devices.commands.holo_sim", "tracker", "--tcp", "0",
         "--seconds", "1",
         "--motion", f"replay:file={path}"],
        capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.splitlines() == [
        f"holo-sim: {path}: cannot read the replay file: {reason}"], proc.stderr


@posix_only
@pytest.mark.parametrize("protocol", ["hatire", "native"])
def test_pty_across_processes(protocol):
    proc = subprocess.Popen(
        [sys.executable, "-m", "sim_devices.commands.holo_sim", "tracker", "--pty", "--protocol",
         protocol,
         "--rate", "200", "--seconds", "1", "--seed", "3", "--faults", "burst=0.05,seed=1",
         "--wait-start"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        path = proc.stdout.readline().strip()
        assert path.startswith("/dev/")
        # opening flushes the input, so the device waits for the start command
        port = serial.serial_for_url(path, timeout=0.05)
        port.write(START[protocol])
        dec = make_decoder(protocol)
        poses: list[PoseEvent] = []
        deadline = time.monotonic() + HANG_S  # a hang guard: a loaded machine is slow
        while len(poses) < 200 and time.monotonic() < deadline:
            chunk = port.read(max(1, port.in_waiting))
            poses += [e for e in dec.feed(chunk, time.monotonic_ns())
                      if isinstance(e, PoseEvent)]
        port.close()
        out, err = proc.communicate(timeout=HANG_S)
    finally:
        proc.kill()
    assert [p.seq for p in poses] == list(range(200))
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["frames"] == 200 and summary["faults"]["burst"] > 0
    assert dec.stats.bytes_discarded > 0 and proc.returncode == 0, err


def _sim(*args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "sim_devices.commands.holo_sim", "tracker", "--pty", "--protocol",
         "native",
         "--rate", "200", "--seed", "3", "--wait-start", *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@posix_only
def test_pty_sim_waits_for_a_slow_reader_before_closing():
    # a reader seconds behind (a loaded machine) still gets every frame: closing the
    # pty would throw away what it has not read
    proc = _sim("--seconds", "0.25")
    try:
        port = serial.serial_for_url(proc.stdout.readline().strip(), timeout=0.05)
        port.write(START["native"])  # opening flushed the input: start the device now
        # the run sends its frames within 0.25 s; the reader then lags 3 s, past the
        # old 2 s drain limit: the simulator must still hold the pty open
        with pytest.raises(subprocess.TimeoutExpired):
            proc.wait(timeout=3.0)
        dec = make_decoder("native")
        data = port.read(port.in_waiting)
        poses = [e for e in dec.feed(data, 0) if isinstance(e, PoseEvent)]
        port.close()
        out, _ = proc.communicate(timeout=15)
    finally:
        proc.kill()
    summary = json.loads(out.strip().splitlines()[-1])
    assert len(poses) == summary["frames"] >= 50


@posix_only
def test_pty_sim_stopped_by_sigterm_does_not_wait_for_a_reader():
    proc = _sim("--seconds", "30")
    try:
        port = serial.serial_for_url(proc.stdout.readline().strip(), timeout=0.05)
        port.write(START["native"])
        with pytest.raises(subprocess.TimeoutExpired):  # frames queue, nobody reads them
            proc.wait(timeout=1.0)
        assert port.in_waiting > 0
        t0 = time.monotonic()
        proc.terminate()
        proc.communicate(timeout=HANG_S)
        # a drain that waited for the reader would take all of DRAIN_TIMEOUT_S
        assert time.monotonic() - t0 < DRAIN_TIMEOUT_S
        port.close()
    finally:
        proc.kill()
