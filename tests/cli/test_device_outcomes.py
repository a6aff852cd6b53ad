"""holo-devices and holo-replay say what happened and exit 1 when nothing useful was done."""

from __future__ import annotations

import json
import random

from drivers.commands import holo_devices as cli_devices
from drivers.commands import holo_replay as cli_replay
from drivers.commands.holo_devices import log_devices
from drivers.protocols import hatire
from drivers.reader import ReaderSettings
from drivers.recording import LogHeader, LogWriter


def test_devices_that_never_open_exit_1_naming_each(capsys):
    rc = cli_devices.main(["--tracker", "/dev/ttyNOPE", "--dials", "/dev/ttyNOPE2",
                           "--seconds", "0.3"])
    err = capsys.readouterr().err.splitlines()
    assert rc == 1
    assert err[-1] == "holo-devices: no device could be opened; nothing was read"
    assert err[-3].startswith("holo-devices: never opened tracker (/dev/ttyNOPE): ")
    assert "No such file" in err[-3]
    assert err[-2].startswith("holo-devices: never opened dials (/dev/ttyNOPE2): ")
    stats = json.loads(err[-4])["stats"]
    assert stats["tracker"]["opens"] == 0 and stats["tracker"]["open_failures"] >= 1


def test_one_device_open_is_a_run_and_the_other_is_named(capsys):
    rc = cli_devices.main(["--tracker", "loop://", "--dials", "/dev/ttyNOPE",
                           "--seconds", "0.3"])
    err = capsys.readouterr().err.splitlines()
    assert rc == 0
    assert err[-1].startswith("holo-devices: never opened dials (/dev/ttyNOPE): ")
    assert json.loads(err[-2])["stats"]["tracker"]["opens"] == 1


def _log(path, frames: list[bytes]) -> None:
    header = LogHeader(log_devices([ReaderSettings("loop://", "hatire", "tracker")]),
                       start_monotonic_ns=0)
    with LogWriter(path, header) as w:
        for k, frame in enumerate(frames):
            w.write("tracker", (k + 1) * 1_000_000, frame)


def test_replay_of_a_capture_that_frames_as_nothing_exits_2(tmp_path, capsys):
    noise = tmp_path / "random.bin"
    noise.write_bytes(random.Random(7).randbytes(3000).replace(b"\xaa", b"\x00"))
    rc = cli_replay.main([str(noise), "--protocol", "hatire", "--as-fast-as-possible",
                          "--dump"])
    out = capsys.readouterr()
    assert rc == 2 and out.out == ""  # refused before any work: --protocol is wrong
    assert out.err.splitlines()[-1] == (
        f"holo-replay: {noise}: does not frame as hatire: 3000 of its first 3000 bytes "
        "(100 %) rejected in 1 run; nor as any other protocol (a leading banner? "
        "--skip-bytes N drops it)")


def test_replay_of_a_log_whose_bytes_decode_to_nothing_exits_1(tmp_path, capsys):
    noise = random.Random(7).randbytes(3000).replace(b"\xaa", b"\x00")
    _log(tmp_path / "noise.hlog", [noise[k:k + 100] for k in range(0, 3000, 100)])
    rc = cli_replay.main([str(tmp_path / "noise.hlog"), "--as-fast-as-possible", "--dump"])
    out = capsys.readouterr()
    assert rc == 1
    assert out.err.splitlines()[-1] == (
        f"holo-replay: {tmp_path / 'noise.hlog'}: no pose, dial or button event decoded "
        "from 3000 bytes (read as hatire; is that the device's protocol?)")
    assert "tracker: the recorded bytes do not frame as hatire" in out.err
    assert all(json.loads(ln)["kind"] == "status" for ln in out.out.splitlines())


def test_replay_of_a_log_without_device_bytes_exits_1(tmp_path, capsys):
    _log(tmp_path / "empty.hlog", [])
    assert cli_replay.main([str(tmp_path / "empty.hlog"), "--dump"]) == 1
    assert "no device bytes in the file; nothing was replayed" in capsys.readouterr().err


def test_replay_without_an_output_option_dumps(tmp_path, capsys):
    frames = [hatire.encode_pose(k, float(k), 0.0, 0.0) for k in range(5)]
    _log(tmp_path / "s.hlog", frames)
    assert cli_replay.main([str(tmp_path / "s.hlog"), "--as-fast-as-possible"]) == 0
    out = capsys.readouterr()
    assert "no output option given: dumping JSON lines (--dump)" in out.err
    poses = [json.loads(ln) for ln in out.out.splitlines()]
    assert [p["seq"] for p in poses if p["kind"] == "pose"] == list(range(5))
