"""The one exit-status rule, tool by tool: after a clean stop, 130 on SIGINT, 143 on SIGTERM.

Every test runs the real command in a subprocess and signals it once it is at work
(a line it printed, or its handler installed as /proc shows), never after a sleep.
holo-view and holo-up are tested in their own files.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest
import serial
from testkit import ROOT, SIGNALS, STATUS, catches, linux_only, posix_only, wait_for

from drivers.commands.holo_devices import log_devices
from drivers.protocols import hatire
from drivers.pty_link import DRAIN_TIMEOUT_S
from drivers.reader import ReaderSettings
from drivers.recording import LogHeader, LogWriter
from service.base.signals import Received, exit_status
from service.loaders import save_obj
from service.primitives import sphere


def test_exit_status_is_128_plus_the_signal():
    assert exit_status(None) == 0 and exit_status(None, 1) == 1
    assert exit_status(signal.SIGINT) == 130 and exit_status(signal.SIGTERM, 1) == 143
    assert Received(signal.SIGTERM).exit_status(2) == 143 and Received().exit_status(2) == 2
    assert Received(signal.SIGINT).name == "SIGINT" and Received().name == ""


# Output left in the buffers of stdout and stderr, a status, and an atexit
# handler that must not run (exit_now skips the interpreter's teardown).
EXIT_NOW_CHILD = """
import atexit, sys
from service.base.signals import exit_now
atexit.register(lambda: print("atexit ran"))
sys.stdout.write("kept out")
sys.stderr.write("kept err")
exit_now(3)
print("not reached")
"""


def test_exit_now_flushes_both_streams_and_keeps_the_status():
    p = subprocess.run([sys.executable, "-c", EXIT_NOW_CHILD], capture_output=True, text=True,
                       cwd=ROOT, timeout=60)
    assert (p.returncode, p.stdout, p.stderr) == (3, "kept out", "kept err")


# A main thread waiting on an event, stopped through stop_on_signals.
LOOP_CHILD = """
import sys, threading
from service.base.signals import stop_on_signals
stop = threading.Event()
with stop_on_signals(stop) as got:
    print("ready", flush=True)
    while not stop.wait(0.001):
        pass
sys.exit(got.exit_status())
"""
# A main thread computing, stopped through interruptible.
BUSY_CHILD = """
import sys
from service.base.signals import interruptible
def work():
    try:
        print("ready", flush=True)  # inside: the signal may come as print returns
        while True:
            sum(range(1000))
    finally:
        print("cleaned up", flush=True)
sys.exit(interruptible("busy", work))
"""


@posix_only
@SIGNALS
@pytest.mark.parametrize("child", [LOOP_CHILD, BUSY_CHILD], ids=["loop", "busy"])
def test_signals_helpers_give_the_rule(child, signum):
    p = subprocess.Popen([sys.executable, "-c", child], cwd=ROOT, text=True,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        assert p.stdout.readline().strip() == "ready"
        p.send_signal(signum)
        out, err = p.communicate(timeout=20)
    finally:
        p.kill()
    assert p.returncode == STATUS[signum]
    if child is BUSY_CHILD:
        assert out.strip() == "cleaned up"  # finally blocks ran
        assert err == f"busy: interrupted ({signal.Signals(signum).name})\n"
    else:
        assert err == ""


@posix_only
@SIGNALS
def test_holo_devices(procs, signum):
    live = procs("drivers.commands.holo_devices", "--tracker", "loop://", "--dump")
    live.wait_lines(lambda: live.out)  # the 'opened' status: the run loop is going
    live.signal(signum)
    assert live.finish() == STATUS[signum]
    assert '"stats"' in live.err[-1] and not any("Traceback" in ln for ln in live.err)


def _log(path, frames: int = 50) -> None:
    header = LogHeader(log_devices([ReaderSettings("loop://", "hatire", "tracker")]),
                       start_monotonic_ns=0)
    with LogWriter(path, header) as w:
        for k in range(frames):
            w.write("tracker", k * 10_000_000, hatire.encode_pose(k, float(k), 0.0, 0.0))


@posix_only
@SIGNALS
def test_holo_replay(procs, tmp_path, signum):
    _log(tmp_path / "s.hlog")
    replay = procs("drivers.commands.holo_replay", str(tmp_path / "s.hlog"), "--loop", "--dump")
    replay.wait_lines(lambda: len(replay.out) >= 3)
    replay.signal(signum)
    assert replay.finish() == STATUS[signum]
    assert not any("Traceback" in ln for ln in replay.err)


@posix_only
@SIGNALS
def test_holo_sim_stops_at_once_with_a_client_that_does_not_read(procs, signum):
    # frames queue in the pty; a stop by signal must not wait for the client to read
    # them (SIGINT used to take 10 s: the drain waited for a reader)
    sim = procs("sim_devices.commands.holo_sim", "tracker", "--pty", "--rate", "500", "--no-pace")
    sim.wait_lines(lambda: sim.out)
    port = serial.serial_for_url(sim.out[0], timeout=0.05)
    try:
        wait_for(lambda: port.in_waiting > 0, what="frames queued")
        t0 = time.monotonic()
        sim.signal(signum)
        assert sim.finish() == STATUS[signum]
        # a drain that waited for the client would take all of DRAIN_TIMEOUT_S
        assert time.monotonic() - t0 < DRAIN_TIMEOUT_S
    finally:
        port.close()
    assert '"frames"' in sim.out[-1]  # the summary still comes


def _interrupt_when_at_work(proc, signum: int) -> None:
    """Signal once the process is inside ``interruptible`` (its SIGTERM handler is set)."""
    proc.wait_lines(lambda: catches(proc.p.pid, signal.SIGTERM), timeout=60)
    proc.signal(signum)


def _one_line(proc, prog: str, signum: int) -> None:
    assert proc.finish(120) == STATUS[signum]
    assert proc.err[-1] == f"{prog}: interrupted ({signal.Signals(signum).name})"
    assert not any("Traceback" in ln or "KeyboardInterrupt" in ln for ln in proc.err)


@linux_only
@SIGNALS
def test_holo_bench_render(procs, tmp_path, signum):
    bench = procs("service.commands.holo_bench", "render", "--out", str(tmp_path))
    _interrupt_when_at_work(bench, signum)
    _one_line(bench, "holo-bench render", signum)


@linux_only
def test_holo_bench_galilean_sweep(procs, tmp_path):
    bench = procs("service.commands.holo_bench", "galilean", "--sweep", "--out", str(tmp_path))
    bench.wait_lines(lambda: any("galilean sweep" in ln for ln in bench.err), timeout=120)
    bench.signal(signal.SIGINT)
    _one_line(bench, "holo-bench galilean", signal.SIGINT)


@linux_only
@SIGNALS
def test_holo_render(procs, tmp_path, signum):
    mesh = tmp_path / "ball.obj"
    save_obj(mesh, sphere(0.5, 200, 400))  # some seconds to load and ray-cast
    render = procs("service.commands.holo_render", str(mesh), "--method", "raycast", "--size",
                   "640x480", "--out", str(tmp_path / "out"))
    _interrupt_when_at_work(render, signum)
    _one_line(render, "holo-render", signum)


@linux_only
@SIGNALS
def test_holo_game(procs, tmp_path, signum):
    game = procs("game.commands.holo_game", "--local", "--headless", "--bot", "--seconds", "300",
                 "--size", "40x30", "--highscores", str(tmp_path / "scores.json"))
    game.wait_lines(lambda: any("playing" in ln for ln in game.err), timeout=60)
    game.signal(signum)
    assert game.finish(60) == STATUS[signum], game.err[-5:]
    assert game.out and '"refreshes"' in game.out[-1]  # the stats still come
    assert game.err[-1] == f"holo-game: interrupted ({signal.Signals(signum).name})"
    assert not any("Traceback" in ln for ln in game.err)
