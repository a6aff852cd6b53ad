"""holo-up: one TOML file starts simulators, holo-devices and holo-service, wired together."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys

import pytest
import zmq
from testkit import (
    ROOT,
    SIGNALS,
    STATUS,
    alive,
    children_of,
    linux_only,
    posix_only,
)

from service.commands import holo_up as cli_up

ANY = "tcp://127.0.0.1:0"
SIMS = """
[sim.tracker]
protocol = "native"
rate = 100

[sim.dials]
seconds = 600
seed = 2
"""
DEVICES = f"""
[devices]
pub = "{ANY}"
reset_wait = 0.3
"""
SERVICE = f"""
[service]
control = "{ANY}"
frames = "{ANY}"
worker_address = "{ANY}"
workers = 0
zones = 2
"""


def _config(tmp_path, text: str):
    path = tmp_path / "rig.toml"
    path.write_text(text)
    return path


def test_dry_run_shows_the_wiring(tmp_path, capsys):
    path = _config(tmp_path, SIMS + DEVICES + SERVICE)
    assert cli_up.main([str(path), "--dry-run"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [ln.split(":")[1].strip() for ln in lines] == [
        "holo-sim tracker", "holo-sim dials", "holo-devices", "holo-service"]
    assert "tracker --protocol native --rate 100 --pty" in lines[0]
    assert "dials --seconds 600 --seed 2 --pty" in lines[1]
    # holo-devices reads both simulators, in the tracker's protocol
    assert "--tracker-protocol native --tracker '<holo-sim tracker address>' --dials " \
           "'<holo-sim dials address>'" in lines[2]
    assert lines[3].endswith("--workers 0 --zones 2 --devices '<holo-devices address>'")


def test_a_simulated_opentrack_sender_is_wired_to_a_udp_listener(tmp_path, capsys):
    path = _config(tmp_path, '[sim.tracker]\nudp = "127.0.0.1:4242"\n' + DEVICES)
    assert cli_up.main([str(path), "--dry-run"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].endswith("tracker --udp 127.0.0.1:4242")  # no --pty beside it
    assert "--tracker '<holo-sim tracker address>'" in lines[1]  # its URL says opentrack


@linux_only
def test_up_runs_an_opentrack_sender_into_holo_devices(procs, tmp_path):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    text = f'[sim.tracker]\nudp = "127.0.0.1:{port}"\nrate = 100\n' + DEVICES
    up = procs("service.commands.holo_up", str(_config(tmp_path, text)))
    up.wait_lines(lambda: "holo-up: running; Ctrl-C stops everything" in up.out, 120)
    assert _where(up, "holo-sim tracker") == f"on opentrack-udp://127.0.0.1:{port}"
    publisher = _where(up, "holo-devices").split()[2]
    view = subprocess.run([sys.executable, "-m", "drivers.commands.holo_view", publisher, "--json",
                           "--count", "30", "--timeout", "30"], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)
    assert view.returncode == 0, view.stderr
    assert json.loads(view.stdout.splitlines()[-1])["pose"] is not None
    up.signal(signal.SIGTERM)
    assert up.finish(60) == STATUS[signal.SIGTERM]


def test_the_example_config_is_valid(capsys):
    assert cli_up.main([str(ROOT / "examples" / "holo-up.toml"), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "--pub tcp://127.0.0.1:5560" in out and "--control tcp://127.0.0.1:5555" in out


@pytest.mark.parametrize(("text", "words"), [
    ("[devices\n", "not valid TOML"),
    ("[sevice]\nx = 1\n", "unknown table [sevice]"),
    ("[sim.mouse]\n", "unknown table [sim.mouse]"),
    ("", "nothing to start"),
    ("[devices]\ntracker = 'loop://'\nbaud = 0\n", "[devices]: holo-devices: argument --baud"),
    ("[devices]\ntracker = 'loop://'\nspeed = 3\n", "unrecognized arguments: --speed 3"),
    ("[devices]\npub = 'tcp://127.0.0.1:99999'\ntracker = 'loop://'\n", "port '99999'"),
    ("[devices]\n", "give tracker and/or dials"),
    ("[sim.tracker]\n[devices]\ntracker = 'loop://'\n", "give tracker or [sim.tracker]"),
    ("[sim.tracker]\nmotion = {a = 1}\n", "want a string, number"),
    ("[sim.tracker]\nargs = '--fast'\n", "args must be a list of strings"),
    ("[sim.tracker]\n[up]\nstart_timeout = -1\n", "start_timeout must be a number > 0"),
    ("[sim.tracker]\n[up]\nwait = 1\n", "[up]: unknown key 'wait'"),
])
def test_bad_files_are_one_line_and_status_2(tmp_path, capsys, text, words):
    path = _config(tmp_path, text)
    assert cli_up.main([str(path)]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and str(path) in err and words in err, err


def test_missing_file(tmp_path, capsys):
    assert cli_up.main([str(tmp_path / "none.toml")]) == 2
    assert "none.toml: cannot read" in capsys.readouterr().err


def _where(up, name: str) -> str:
    line = next(ln for ln in up.out if ln.startswith(f"holo-up: {name} "))
    return line[len(f"holo-up: {name} "):]


@linux_only
@SIGNALS
def test_starts_wires_and_stops_everything(procs, tmp_path, signum):
    up = procs("service.commands.holo_up", str(_config(tmp_path, SIMS + DEVICES + SERVICE)))
    up.wait_lines(lambda: "holo-up: running; Ctrl-C stops everything" in up.out, 120)
    assert _where(up, "holo-sim tracker").startswith("on /dev/")
    assert _where(up, "holo-sim dials").startswith("on /dev/")
    publisher = _where(up, "holo-devices").split()[2]
    assert publisher.startswith("tcp://127.0.0.1:") and not publisher.endswith(":0")
    assert _where(up, "holo-service").startswith("control tcp://127.0.0.1:")
    # the simulated tracker reaches the publisher through holo-devices
    view = subprocess.run([sys.executable, "-m", "drivers.commands.holo_view", publisher, "--json",
                           "--count", "30", "--timeout", "30"], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)
    assert view.returncode == 0, view.stderr
    assert json.loads(view.stdout.splitlines()[-1])["pose"] is not None
    started = children_of(up.p.pid)
    assert len(started) == 4
    up.signal(signum)
    assert up.finish(60) == STATUS[signum]
    assert not any(alive(pid) for pid in started)
    assert any(ln.startswith("[holo-devices] {\"stats\"") for ln in up.err)


@posix_only
def test_a_program_that_fails_stops_the_others(procs, tmp_path):
    ctx = zmq.Context.instance()
    taken = ctx.socket(zmq.PUB)
    taken.bind(ANY)
    try:
        address = taken.getsockopt_string(zmq.LAST_ENDPOINT)
        text = SIMS + DEVICES.replace(ANY, address)
        up = procs("service.commands.holo_up", str(_config(tmp_path, text)))
        assert up.finish(60) == 1
    finally:
        taken.close(0)
    assert any(ln.startswith("holo-up: holo-sim dials on /dev/") for ln in up.out)
    failure = [ln for ln in up.err if ln.startswith("holo-up: ")]
    assert len(failure) == 1 and "holo-devices exited 2 while starting" in failure[0]
    assert "Address already in use" in failure[0] and "stopping the others" in failure[0]


@linux_only
def test_ctrl_c_at_the_terminal_stops_the_programs_in_order(tmp_path):
    """A terminal's Ctrl-C reaches its whole foreground process group at once.

    holo-up runs in a session of its own here, as a shell's foreground job, and the
    SIGINT goes to the group: the programs (each in a group of its own) are stopped by
    holo-up, holo-devices before the simulators, so no device is reported lost and
    the tracker gets its stop command.
    """
    import os
    import signal
    import threading

    p = subprocess.Popen([sys.executable, "-m", "service.commands.holo_up",
                          str(_config(tmp_path, SIMS + DEVICES))], cwd=ROOT, text=True,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         stdin=subprocess.DEVNULL, start_new_session=True)
    out: list[str] = []
    err: list[str] = []
    pumps = [threading.Thread(target=lambda s=s, k=k: k.extend(s), daemon=True)
             for s, k in ((p.stdout, out), (p.stderr, err))]
    for t in pumps:
        t.start()
    try:
        deadline = threading.Event()
        for _ in range(12000):  # up to 120 s for the ready line
            if any("running; Ctrl-C" in ln for ln in out) or p.poll() is not None:
                break
            deadline.wait(0.01)
        assert any("running; Ctrl-C" in ln for ln in out), err[-8:]
        started = children_of(p.pid)
        assert len(started) == 3
        os.killpg(p.pid, signal.SIGINT)  # what the terminal does on Ctrl-C
        assert p.wait(60) == 130
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait(10)
    for t in pumps:
        t.join(10)
    assert not any(alive(pid) for pid in started)
    lost = [ln for ln in err if ln.startswith("[holo-devices]") and ": error {" in ln]
    assert not lost, lost
    assert any(ln.startswith("[holo-devices] {\"stats\"") for ln in err)
