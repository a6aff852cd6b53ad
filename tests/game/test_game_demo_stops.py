"""The whole-loop demo stops every process it started: on SIGTERM, SIGINT and errors.

Each test runs ``python -m game.commands.make_demo`` as a real process and watches its
process tree through ``/proc`` (each process's parent from ``/proc/<pid>/stat``;
``/proc/<pid>/task/*/children`` needs a kernel option that not every kernel has).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from game.display import headless_env
from game.run_folders import new_run_folder, read_latest

pytestmark = pytest.mark.skipif(
    not sys.platform.startswith("linux"), reason="reads the process tree from /proc"
)

ROOT = Path(__file__).resolve().parents[2]
#: The demo's children with the service: tracker, dials, holo-devices, service, game.
CHILDREN = 5


def stat(pid: int) -> tuple[str, int, int] | None:
    """(state, parent pid, start time) of ``pid``; None when it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2 :].split()
    return fields[0], int(fields[1]), int(fields[19])


def tree(root: int) -> dict[int, int]:
    """Every living descendant of ``root``: pid -> start time."""
    parents: dict[int, tuple[int, int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and (st := stat(int(entry.name))) and st[0] != "Z":
            parents[int(entry.name)] = (st[1], st[2])
    found, todo = {}, [root]
    while todo:
        parent = todo.pop()
        for pid, (ppid, start) in parents.items():
            if ppid == parent and pid not in found:
                found[pid] = start
                todo.append(pid)
    return found


def alive(pid: int, start: int) -> bool:
    """``pid`` is still the process that started at ``start`` and not a zombie."""
    st = stat(pid)
    return st is not None and st[0] != "Z" and st[2] == start


def cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def wait_until(cond: Callable[[], object], timeout: float, what: str) -> object:
    """``cond()``'s first true value, polled until ``timeout`` seconds pass."""
    deadline, tick = time.monotonic() + timeout, threading.Event()
    while time.monotonic() < deadline:
        value = cond()
        if value:
            return value
        tick.wait(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def start_demo(tmp_path: Path, *extra: str) -> tuple[subprocess.Popen, Path]:
    log = tmp_path / "demo.log"
    with log.open("w") as sink:
        demo = subprocess.Popen(
            [sys.executable, "-m", "game.commands.make_demo", "--headless", "--out",
             str(tmp_path / "out"),
             "--seconds", "120", *extra],
            cwd=ROOT, env=headless_env(), stdout=sink, stderr=subprocess.STDOUT, text=True,
        )  # fmt: skip
    return demo, log


def watch_until_exit(demo: subprocess.Popen, timeout: float) -> dict[int, int]:
    """Every descendant seen while ``demo`` runs (it must exit within ``timeout``)."""
    seen: dict[int, int] = {}

    def gone() -> bool:
        seen.update(tree(demo.pid))
        return demo.poll() is not None

    wait_until(gone, timeout, "the demo to exit")
    return seen


def assert_all_gone(procs: dict[int, int]) -> None:
    wait_until(lambda: not any(alive(p, s) for p, s in procs.items()), 15, "children to end")


def kill_all(demo: subprocess.Popen) -> None:
    """SIGKILL the demo and every process under it (a failed test must leave none behind).

    Killing the demo alone orphans its children: a run whose assertion failed
    before the signal left a simulated tracker running for an hour.
    """
    for pid, start in tree(demo.pid).items():
        if alive(pid, start):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
    demo.kill()
    demo.wait()


def running_game(demo: subprocess.Popen) -> dict[int, int]:
    """The demo's process tree once its children run the game, the service and holo-devices.

    A child counts once it runs its own program: between fork and exec its
    ``/proc/<pid>/cmdline`` is still the demo's (a loaded machine once showed the
    game's child there, as ``game.commands.make_demo``, after all five had forked).
    """

    def started() -> dict[int, int]:
        assert demo.poll() is None, "the demo ended early"
        kids = tree(demo.pid)
        direct = [p for p in kids if (st := stat(p)) and st[1] == demo.pid]
        programs = " ".join(cmdline(p) for p in kids)
        running = all(name in programs
                      for name in ("game.commands.holo_game", "service.commands.holo_service",
                                   "drivers.commands.holo_devices"))
        return kids if len(direct) >= CHILDREN and running else {}

    return wait_until(started, 120,
                      f"{CHILDREN} children running the game, the service and holo-devices")


def test_ctrl_c_keeps_what_was_written_and_every_earlier_run(tmp_path):
    out = tmp_path / "out"
    earlier = new_run_folder(out, when=0.0)  # a run of 1970: must outlive this one
    (earlier / "stats.json").write_text('{"refreshes": 1}')
    demo, log = start_demo(tmp_path, "--light", "ambient", "--size", "160x120")
    try:
        running_game(demo)
        run = wait_until(lambda: read_latest(out) if read_latest(out) != earlier else None,
                         30, "demo-out/latest to name this run")
        # the first screenshot: the game has played and written something
        wait_until(lambda: (run / "mode-head.png").exists(), 300, "the first screenshot")
        demo.send_signal(signal.SIGINT)
        assert demo.wait(90) == 130, log.read_text()
    finally:
        kill_all(demo)
    stats = json.loads((run / "stats.json").read_text())
    assert stats["interrupted"] == "SIGINT", stats
    assert stats["refreshes"] > 0  # the game's own stats, as far as it got
    assert (run / "mode-head.png").stat().st_size > 1000
    assert "mode-head.png" in stats["files"]
    assert (earlier / "stats.json").read_text() == '{"refreshes": 1}'
    assert sorted(p.name for p in out.iterdir()) == sorted([earlier.name, run.name, "latest"])


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_stops_every_process_the_demo_started(tmp_path, sig):
    demo, log = start_demo(tmp_path)
    try:
        kids = running_game(demo)
        demo.send_signal(sig)
        assert demo.wait(60) == 128 + sig, log.read_text()
        assert_all_gone(kids)
        assert f"{signal.Signals(sig).name}: stopping every process" in log.read_text()
    finally:
        kill_all(demo)


def test_a_service_that_fails_to_start_stops_the_others(tmp_path):
    demo, log = start_demo(tmp_path, "--service-arg=--no-such-option")
    try:
        seen = watch_until_exit(demo, 120)
        assert demo.returncode == 1
        text = log.read_text()
        assert "holo-service did not start" in text and "--no-such-option" in text
        names = " ".join(cmdline(p) for p in seen) + text
        assert len(seen) >= 3, names  # both simulators and holo-devices had started
        assert_all_gone(seen)
    finally:
        kill_all(demo)


def test_a_child_dying_mid_game_stops_the_others(tmp_path):
    demo, log = start_demo(tmp_path)
    try:
        kids = running_game(demo)
        (driver,) = [p for p in kids if "drivers.commands.holo_devices" in cmdline(p)]
        os.kill(driver, signal.SIGKILL)
        assert demo.wait(60) == 1
        assert "holo-devices exited -9 while holo-game ran" in log.read_text()
        assert_all_gone(kids)
    finally:
        kill_all(demo)
