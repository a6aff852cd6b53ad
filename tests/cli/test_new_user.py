"""What a new user met following the README: outputs checked before the work, one-line
errors where tracebacks were, keys never overwritten.  Each test runs the real command
in a subprocess.
"""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import zmq
from testkit import ROOT, SIGNALS, STATUS, catches, posix_only, wait_for

from drivers.commands.holo_devices import log_devices
from drivers.protocols import hatire
from drivers.reader import ReaderSettings
from drivers.recording import LogHeader, LogWriter
from service.loaders import save_obj
from service.primitives import sphere


def _run(module: str, *args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", module, *args], cwd=ROOT, text=True,
                          capture_output=True, timeout=timeout)


def _one_line_error(proc: subprocess.CompletedProcess, prog: str, *words: str) -> str:
    """Status 2, one stderr line from ``prog`` holding ``words``, no traceback."""
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1 and lines[0].startswith(f"{prog}: "), proc.stderr
    assert "Traceback" not in proc.stderr
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]


def test_holo_render_refuses_an_out_that_is_a_file_before_rendering(tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("mine")
    proc = _run("service.commands.holo_render", "builtin:cyclic", "--size", "32x24",
                "--out", str(afile))
    _one_line_error(proc, "holo-render", "--out", "not a folder")
    assert afile.read_text() == "mine" and proc.stdout == ""


def test_holo_simplify_refuses_a_missing_out_folder_before_building(tmp_path):
    mesh = tmp_path / "ball.obj"
    save_obj(mesh, sphere(0.5, 12, 8))
    out = tmp_path / "no-such-folder" / "ball.hbc"
    proc = _run("service.commands.holo_simplify", str(mesh), "--error", "1%", "--out", str(out))
    _one_line_error(proc, "holo-simplify", "no folder")  # and no "building" line
    good = _run("service.commands.holo_simplify", str(mesh), "--error", "1%", "--method", "quadric",
                "--out", str(tmp_path / "low.obj"))
    assert good.returncode == 0, good.stderr
    assert good.stderr.startswith("holo-simplify: building quadric levels of ")  # progress
    assert (tmp_path / "low.obj").is_file()


def test_holo_sird_names_a_file_that_is_not_npy_or_missing(tmp_path):
    garbage = tmp_path / "garbage.npy"
    garbage.write_text("garbage\n")
    proc = _run("service.commands.holo_sird", str(garbage), "--out", str(tmp_path / "x.png"))
    line = _one_line_error(proc, "holo-sird", "not a .npy file")
    assert "pickle" not in line  # numpy's own message spoke of pickled data
    proc = _run("service.commands.holo_sird", str(tmp_path / "missing.npy"),
                "--out", str(tmp_path / "x.png"))
    _one_line_error(proc, "holo-sird", "missing.npy: cannot read the file")
    np.save(tmp_path / "depth.npy", np.ones((24, 32), np.float32))
    proc = _run("service.commands.holo_sird", str(tmp_path / "depth.npy"),
                "--out", str(tmp_path / "none" / "x.png"))
    _one_line_error(proc, "holo-sird", "no folder")


def test_holo_service_keys_never_overwrites_keys_and_errors_in_one_line(tmp_path):
    keys = tmp_path / "keys"
    first = _run("service.commands.holo_service", "--make-keys", str(keys))
    assert first.returncode == 0, first.stderr
    before = {p: p.read_bytes() for p in keys.rglob("*") if p.is_file()}
    assert len(before) == 5
    again = subprocess.run([sys.executable, "-c",
                            "from service.commands.holo_service import keys_main;"
                            f"raise SystemExit(keys_main([{str(keys)!r}]))"],
                           cwd=ROOT, text=True, capture_output=True, timeout=60)
    _one_line_error(again, "holo-service-keys", "already holds keys")
    assert {p: p.read_bytes() for p in keys.rglob("*") if p.is_file()} == before
    afile = tmp_path / "afile"
    afile.write_text("x")
    proc = _run("service.commands.holo_service", "--make-keys", str(afile))
    _one_line_error(proc, "holo-service", "not a folder")  # not mkdir's "File exists"
    assert afile.read_text() == "x"


def test_holo_service_says_in_one_line_that_its_port_is_taken():
    with zmq.Context() as ctx, ctx.socket(zmq.REP) as sock:
        port = sock.bind_to_random_port("tcp://127.0.0.1")
        proc = _run("service.commands.holo_service", "--control", f"tcp://127.0.0.1:{port}",
                    "--frames", "tcp://127.0.0.1:0", "--no-warmup", timeout=60)
    _one_line_error(proc, "holo-service", "cannot bind", "Address already in use")


def test_holo_up_names_a_file_that_is_not_utf8_in_one_line(tmp_path):
    rig = tmp_path / "rig.toml"
    rig.write_bytes(b"[devices]\npub = \"\xff\"\n")
    proc = _run("service.commands.holo_up", str(rig), "--dry-run", timeout=60)
    _one_line_error(proc, "holo-up", "not valid TOML", "UTF-8")


def test_holo_bench_without_a_name_is_bad_usage_and_an_unknown_one_is_one_line():
    proc = _run("service.commands.holo_bench", timeout=60)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.strip().splitlines()[-1] == "holo-bench: error: name a benchmark"
    proc = _run("service.commands.holo_bench", "nosuch", timeout=60)
    _one_line_error(proc, "holo-bench", "unknown benchmark 'nosuch'", "render, light")



def _tracker_log(tmp_path: Path, step_ns: int) -> Path:
    """A session log of 20 Hatire poses from one tracker, ``step_ns`` apart."""
    log = tmp_path / "s.hlog"
    header = LogHeader(log_devices([ReaderSettings("loop://", "hatire", "tracker")]),
                       start_monotonic_ns=0)
    with LogWriter(log, header) as w:
        for k in range(20):
            w.write("tracker", k * step_ns, hatire.encode_pose(k, float(k), 0.0, 0.0))
    return log

def test_holo_replay_passes_replays_that_many_times_without_loop(tmp_path):
    log = _tracker_log(tmp_path, 1_000_000)

    def poses(*extra: str) -> int:
        proc = _run("drivers.commands.holo_replay", str(log), "--as-fast-as-possible", "--dump",
                    *extra,
                    timeout=60)
        assert proc.returncode == 0, proc.stderr
        return sum('"kind":"pose"' in ln.replace(" ", "") for ln in proc.stdout.splitlines())

    once = poses()
    assert once == 20
    assert poses("--passes", "2") == 2 * once  # it was one pass: --passes needed --loop
    assert poses("--loop", "--passes", "3") == 3 * once


def test_holo_service_refuses_an_unknown_scene_before_binding():
    proc = _run("service.commands.holo_service", "--scene", "scene.toml", "--control",
                "tcp://127.0.0.1:0", "--frames", "tcp://127.0.0.1:0", timeout=60)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines()[-1] == (
        "holo-service: error: argument --scene: unknown scene 'scene.toml'; known: game, "
        "sphere-torus, cyclic, threaded, demo")
    assert "control tcp://" not in proc.stderr  # nothing was bound


@posix_only
@SIGNALS
def test_holo_sim_on_tcp_stopped_before_a_client_came_gives_the_signal_status(procs, signum):
    sim = procs("sim_devices.commands.holo_sim", "tracker", "--tcp", "0")
    sim.wait_lines(lambda: sim.out)  # socket://127.0.0.1:PORT: waiting for a client
    assert sim.out[0].startswith("socket://127.0.0.1:")
    wait_for(lambda: catches(sim.p.pid, signal.SIGTERM), what="signal handler installed")
    sim.signal(signum)
    assert sim.finish() == STATUS[signum]  # it said 2, "no client connected"
    assert '"frames": 0' in sim.out[-1] and not any("Traceback" in ln for ln in sim.err)


def test_holo_sird_names_a_pattern_file_that_is_not_a_png(tmp_path):
    bad = tmp_path / "dots.png"
    bad.write_bytes(b"GIF89a not a png")
    proc = _run("service.commands.holo_sird", "builtin:cyclic", "--size", "64x48", "--pattern",
                str(bad),
                "--out", str(tmp_path / "x.png"))
    _one_line_error(proc, "holo-sird", f"pattern {bad}: not a PNG file")
    assert not (tmp_path / "x.png").exists()


def test_holo_service_checks_its_addresses_and_keys_before_binding(tmp_path):
    cases = [
        (("--control", "tcp://127.0.0.1:99999"), "argument --control"),  # bound 34463
        (("--worker-address", "tcp://127.0.0.1:99999"), "argument --worker-address"),
        (("--devices", "foo"), "argument --devices"),  # taken, and never heard from
        (("--curve-keys", str(tmp_path / "nokeys")), "--curve-keys"),  # two zmq.auth lines
    ]
    for extra, word in cases:
        proc = _run("service.commands.holo_service", "--frames", "tcp://127.0.0.1:0", *extra,
                    "--no-warmup", timeout=60)
        assert proc.returncode == 2, (extra, proc.stderr)
        last = proc.stderr.strip().splitlines()[-1]
        assert last.startswith("holo-service: ") and word in last, last
        assert "control tcp://" not in proc.stderr and "Traceback" not in proc.stderr


def test_holo_replay_skip_past_the_end_says_so_and_exits_1(tmp_path):
    log = _tracker_log(tmp_path, 100_000_000)
    proc = _run("drivers.commands.holo_replay", str(log), "--skip", "100", "--dump", timeout=60)
    assert proc.returncode == 1 and proc.stdout == ""  # it said 0, printing nothing
    assert "--skip 100 s is past the last device event; the log spans 1.9 s" in proc.stderr
    proc = _run("drivers.commands.holo_replay", str(log), "--skip", "1", "--as-fast-as-possible",
                "--dump", timeout=60)
    assert proc.returncode == 0 and proc.stdout.count('"pose"') == 10, proc.stderr


def test_holo_simplify_names_a_negative_error_as_such(tmp_path):
    proc = _run("service.commands.holo_simplify", "mesh.ply", "--error", "-1%", "--out",
                str(tmp_path / "m.hbc"), timeout=60)
    assert proc.returncode == 2
    last = proc.stderr.strip().splitlines()[-1]
    assert last == "holo-simplify: error: argument --error: must be > 0, got -1%", last


def test_a_file_of_the_wrong_kind_names_every_kind_the_command_reads(tmp_path):
    """The loaders' own line named the mesh extensions only, not .toml, .npy or builtin:."""
    picture = tmp_path / "zone-02.png"
    picture.write_bytes(b"\x89PNG\r\n\x1a\n")
    line = _one_line_error(_run("service.commands.holo_render", str(picture)), "holo-render",
                           "not a file this reads", ".toml", ".hbc", ".ply", "builtin:NAME")
    assert ".npy" not in line
    _one_line_error(_run("service.commands.holo_sird", str(picture), "--out",
                         str(tmp_path / "s.png")),
                    "holo-sird", "not a file this reads", ".npy", ".toml", "builtin:NAME")


def test_a_missing_billboard_cloud_is_named_first_without_errno(tmp_path):
    """Before: 'holo-render: error: [Errno 2] No such file or directory: 'x.hbc''."""
    missing = tmp_path / "x.hbc"
    line = _one_line_error(_run("service.commands.holo_render", str(missing), "--out",
                                str(tmp_path / "out")), "holo-render")
    assert line == f"holo-render: error: {missing}: No such file or directory"
    line = _one_line_error(_run("service.commands.holo_sird", str(missing), "--out",
                                str(tmp_path / "s.png")), "holo-sird")
    assert line == f"holo-sird: error: {missing}: No such file or directory"


def test_holo_replay_names_a_missing_log_once(tmp_path):
    """Before: 'x.hlog: cannot open: [Errno 2] No such file or directory: 'x.hlog''."""
    missing = tmp_path / "x.hlog"
    proc = _run("drivers.commands.holo_replay", str(missing), "--dump")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines()[-1] == (
        f"holo-replay: {missing}: cannot open: No such file or directory")


def test_holo_game_refuses_times_and_rates_it_cannot_use():
    """Before: --seconds -1 played 'playing -1 s' and stopped at once, --wait -1 gave up
    before the first frame, --bot-gives-up -3 was taken, --refresh 0 was refused as
    'Galilean setting refresh_hz is out of range: 0.0' (no option named)."""
    from game.commands.holo_game import build_parser

    parser = build_parser()
    for argv, words in ((["--seconds", "-1"], "--seconds: must be > 0"),
                        (["--seconds", "0"], "--seconds: must be > 0"),
                        (["--wait", "-1"], "--wait: must be > 0"),
                        (["--bot-gives-up", "-3"], "--bot-gives-up: must be >= 0"),
                        (["--refresh", "0"], "--refresh: must be > 0"),
                        (["--zones", "100"], "--zones: must be from 1 to 64")):
        proc = _run("game.commands.holo_game", "--local", "--headless", *argv, timeout=60)
        line = _one_line_error_argparse(proc, "holo-game")
        assert words in line, (argv, line)
    text = parser.format_help()
    for words in ("(default tcp://127.0.0.1:5555)", "refresh rate, Hz (default 60)",
                  "the high-score table", "1: with --seconds, no frame came within --wait"):
        assert words in " ".join(text.split()), words


def _one_line_error_argparse(proc: subprocess.CompletedProcess, prog: str) -> str:
    """Status 2, argparse's usage and one 'PROG: error: ...' line, no traceback."""
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith(f"{prog}: error: "), proc.stderr
    return last


def test_the_demos_refuse_bad_values_before_starting_anything():
    """Before: make render-demo's --scene bogus and --repeats 0 were tracebacks, and
    make demo's --seconds -1 started every program before holo-game refused it."""
    for module, argv, words in (
            ("service.commands.render_demo", ["--scene", "bogus"],
             "--scene: unknown scene 'bogus'"),
            ("service.commands.render_demo", ["--repeats", "0"], "--repeats: must be >= 1"),
            ("game.commands.make_demo", ["--seconds", "-1"], "--seconds: must be > 0"),
            ("game.commands.make_demo", ["--gives-up", "-2"], "--gives-up: must be >= 0")):
        proc = _run(module, *argv, timeout=60)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
        assert words in proc.stderr.strip().splitlines()[-1], proc.stderr
        assert "starting" not in proc.stderr


def test_holo_game_without_a_service_says_what_to_start():
    """A newcomer's first 'holo-game' with no service: the line names holo-service and
    --local, and --wait ends the run with status 1."""
    import socket

    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = _run("game.commands.holo_game", "--service", f"tcp://127.0.0.1:{port}", "--headless",
                "--seconds", "1", "--wait", "2", timeout=60)
    assert proc.returncode == 1, proc.stderr
    assert "is holo-service running there? --local plays without it" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_holo_sim_names_a_pty_link_it_cannot_make(tmp_path):
    """Before: a FileNotFoundError traceback (status 1) once the pty was open."""
    link = tmp_path / "no-such-folder" / "tracker"
    proc = _run("sim_devices.commands.holo_sim", "tracker", "--pty", "--pty-link", str(link),
                "--seconds", "1", timeout=60)
    _one_line_error(proc, "holo-sim", "--pty-link", "no folder")
    assert proc.stdout == ""


def test_holo_replay_names_a_pty_link_it_cannot_make(tmp_path):
    """Before: a FileNotFoundError traceback (status 1) once the pty was open."""
    log = _tracker_log(tmp_path, 1_000_000)
    link = tmp_path / "no-such-folder" / "tracker"
    proc = _run("drivers.commands.holo_replay", str(log), "--to-pty", "--pty-link", str(link))
    _one_line_error(proc, "holo-replay", "--pty-link", "no folder")


def test_holo_devices_names_a_record_file_it_cannot_make_before_opening_ports(tmp_path):
    """Before: 'PATH: cannot create log: [Errno 17] File exists: 'PATH'' (and Errno 2)."""
    there = tmp_path / "s.hlog"
    there.write_bytes(b"mine")
    proc = _run("drivers.commands.holo_devices", "--tracker", "loop://", "--record", str(there))
    _one_line_error(proc, "holo-devices", "--record", "already exists", "never overwritten")
    assert there.read_bytes() == b"mine"
    proc = _run("drivers.commands.holo_devices", "--tracker", "loop://", "--record",
                str(tmp_path / "no-such-folder" / "s.hlog"))
    _one_line_error(proc, "holo-devices", "--record", "no folder")


def test_holo_service_names_the_option_of_a_bad_display(capsys):
    """Before: 'holo-service: zones must be an integer from 1 to 64, got 0', no option."""
    import pytest

    from service.commands.holo_service import build_parser

    for argv, words in ((["--zones", "0"], "argument --zones: must be from 1 to 64"),
                        (["--angle", "90"], "argument --angle: must be from 0 to 60")):
        with pytest.raises(SystemExit) as exc:
            build_parser().parse_args(argv)
        assert exc.value.code == 2
        assert words in capsys.readouterr().err


def test_holo_simplify_names_an_output_it_could_not_write_without_errno(tmp_path):
    """Before: 'holo-simplify: error: [Errno 2] No such file or directory: '/proc/x.ply''."""
    import os

    import pytest

    if not os.path.isdir("/proc/self") or not os.access("/proc", os.W_OK):
        pytest.skip("needs /proc that output_problem passes and open() refuses")
    mesh = tmp_path / "ball.obj"
    save_obj(mesh, sphere(0.5, 12, 8))
    proc = _run("service.commands.holo_simplify", str(mesh), "--error", "1%", "--method", "quadric",
                "--out", "/proc/holo-no-such.ply")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("holo-simplify: error: /proc/holo-no-such.ply: "), last
    assert "Errno" not in last
