"""A ``holo-service`` on an empty numba cache says it is warming up (``docs/protocol.md`` 1.8).

Real processes on 127.0.0.1 with a fresh ``NUMBA_CACHE_DIR``: while its warm-up
child compiles, the service keeps sending heartbeats (``status: warming_up`` with
the progress), answers ``hello`` / ``stats`` and refuses every other request with a
``warming_up`` reply, and stops cleanly (exit 143, child ended, no traceback) on
SIGTERM or at once on a ``shutdown`` request.  The tests stop it mid-compile, so
they never pay for a whole cold compile.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zmq
from testkit import HANG_S, ROOT, ServiceProcess, launch_service, raw_request, wait_until

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")

#: The protocol's rule: a subscriber that hears nothing for 3 s takes the service for gone.
SILENCE_S = 3.0


def _cold_service(tmp_path: Path) -> ServiceProcess:
    """A service on an empty numba cache, on ports of its own choosing, still warming up."""
    return launch_service("--scene", "game",
                          env={"NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")})


def _request(control: str, mtype: str, **fields) -> dict:
    got = raw_request(control, {"v": 1, "type": mtype, "id": 1, **fields}, (), 5000)
    assert got is not None, f"no reply to {mtype}"
    return got


def _alive(pid: int) -> bool:
    stat = Path(f"/proc/{pid}/stat")
    try:
        return stat.read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


class Heartbeats:
    """The frame stream's messages, with the longest silence between two."""

    def __init__(self, address: str) -> None:
        self.sock = zmq.Context.instance().socket(zmq.SUB)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.setsockopt(zmq.SUBSCRIBE, b"")
        self.sock.connect(address)
        self.heard: list[dict] = []
        self.last: float | None = None
        self.longest = 0.0

    def listen(self, seconds: float) -> list[dict]:
        """Every message header heard within ``seconds``."""
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            if self.sock.poll(int(left * 1000) + 1):
                topic, head, *_ = self.sock.recv_multipart()
                now = time.monotonic()
                if self.last is not None:
                    self.longest = max(self.longest, now - self.last)
                self.last = now
                self.heard.append({"topic": topic.decode(), **json.loads(head)})
        return self.heard

    def close(self) -> None:
        self.sock.close(0)


@pytest.mark.timeout(150)
def test_a_cold_service_keeps_its_heartbeats_says_warming_up_and_stops_on_sigterm(tmp_path):
    svc = _cold_service(tmp_path)
    proc, control, frames = svc.proc, svc.control, svc.frames
    hb = Heartbeats(frames)
    try:
        seen: list[dict] = []

        def past_starting() -> bool:
            got = raw_request(control, {"v": 1, "type": "hello", "id": 0}, (), 500)
            seen.extend([got] if got else [])
            return bool(got) and got.get("warmup", {}).get("phase") != "starting"

        # "starting" until the warm-up has looked at the cache (a hello right after the
        # bind can come first), then "compiling" on an empty cache
        assert wait_until(past_starting, HANG_S), seen
        assert all(h["ok"] and h["status"] == "warming_up" for h in seen), seen
        hello = seen[-1]
        assert hello["warmup"]["total"] > 0 and hello["warmup"]["phase"] == "compiling"
        child = wait_until(lambda: _request(control, "ping")["warmup"]["child_pid"], HANG_S)
        assert child and _alive(child)  # (hello may come before the child is started)
        # the heartbeats go on while the child compiles, and the progress moves
        def progressed() -> bool:
            hb.listen(1.0)
            return any(h.get("warmup", {}).get("done", 0) >= 1 for h in hb.heard)

        assert wait_until(progressed, 90, step_s=0), "no warm-up progress in heartbeats"
        hb.listen(1.5)
        assert hb.heard and all(h["topic"] == "hb" for h in hb.heard)
        assert all(h["status"] == "warming_up" for h in hb.heard)
        assert hb.longest < SILENCE_S, f"{hb.longest:.1f} s without a heartbeat"
        last = hb.heard[-1]["warmup"]
        assert last["phase"] == "compiling" and 1 <= last["done"] < last["total"], last
        # every request is answered: read-only ones as usual, the rest "warming up"
        assert _request(control, "ping")["status"] == "warming_up"
        stats = _request(control, "stats")
        assert stats["ok"] and stats["stats"]["status"] == "warming_up"
        for mtype, fields in (("load_scene", {"builtin": "game"}), ("render", {}),
                              ("set_display", {"zones": 3}),
                              ("update_objects", {"objects": [{"index": 0}]})):
            got = _request(control, mtype, **fields)
            assert not got["ok"] and got["error"]["code"] == "warming_up", got
            assert got["status"] == "warming_up" and got["warmup"]["done"] >= 1, got
            assert f"/{got['warmup']['total']}" in got["error"]["message"]
        # SIGTERM mid-compile: a clean stop, the child ended, the rule's status
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(HANG_S) == 128 + signal.SIGTERM
        err = svc.output()
        assert "Traceback" not in err and "LLVM" not in err and "stopped (SIGTERM)" in err, err
        assert wait_until(lambda: not _alive(child), 10), "the warm-up child outlived the service"
    finally:
        hb.close()
        svc.stop()


@pytest.mark.timeout(150)
def test_a_shutdown_request_while_warming_up_stops_at_once(tmp_path):
    svc = _cold_service(tmp_path)
    proc, control = svc.proc, svc.control
    try:
        hello = wait_until(lambda: raw_request(control, {"v": 1, "type": "hello", "id": 0}, (),
                                               500), 30)
        assert hello and hello["status"] == "warming_up"
        child = hello["warmup"]["child_pid"] or wait_until(
            lambda: _request(control, "ping")["warmup"]["child_pid"], 10)
        assert _request(control, "shutdown")["ok"]
        assert proc.wait(HANG_S) == 0
        assert "Traceback" not in svc.output()
        assert wait_until(lambda: not _alive(child), 10)
    finally:
        svc.stop()


@pytest.mark.timeout(120)
def test_a_failed_warmup_child_falls_back_to_the_service_process():
    """The child dies: the warm-up loads (here: from the warm cache) in process, says why."""
    from service.readiness import Warmup

    lines: list[str] = []
    warmup = Warmup(lines.append, child=(sys.executable, "-c", "import sys; sys.exit(3)"),
                    trust_stamp=False)
    warmup.start()
    try:
        assert warmup.ready.wait(100), warmup.as_dict()
        state = warmup.as_dict()
        assert state["phase"] == "ready" and state["done"] == state["total"] > 0
        assert "exited 3" in state["note"] and any("exited 3" in ln for ln in lines)
    finally:
        warmup.stop()


@pytest.mark.timeout(120)
def test_warmup_lines_say_loading_for_a_cached_job_and_compiling_for_a_compiled_one():
    """A job the child found in the cache was loaded, not compiled ("compiling ... (cached)")."""
    import json

    from service.readiness import Warmup

    events = [{"event": "kernel", "done": 1, "total": 2, "name": "a", "cached": True,
               "seconds": 0.1},
              {"event": "kernel", "done": 2, "total": 2, "name": "b", "cached": False,
               "seconds": 3.25}]
    script = "".join(f"print({json.dumps(json.dumps(ev))})\n" for ev in events)
    lines: list[str] = []
    warmup = Warmup(lines.append, child=(sys.executable, "-c", script), trust_stamp=False,
                    jobs=())
    warmup.start()
    try:
        assert warmup.ready.wait(100), warmup.as_dict()
    finally:
        warmup.stop()
    assert "warming up: loading 1/2 a (cached)" in lines, lines
    assert "warming up: compiling 2/2 b (3.2 s)" in lines, lines


@pytest.mark.timeout(120)
def test_a_cold_warmup_compiles_the_services_jobs_first_and_the_rest_in_the_background(
        tmp_path):
    """First frame first: the child gets ``--job`` for the service's jobs only; once ready
    a second child (every job, ``--nice``) runs in the background and ``compile`` says so."""
    from service.readiness import BACKGROUND_NICE, Warmup

    calls = tmp_path / "calls.jsonl"
    gate = tmp_path / "go"  # the background child waits for it: its progress is seen first
    os.mkfifo(gate)  # opening it to read blocks until the test opens it to write
    script = (
        "import json, sys\n"
        f"open({str(calls)!r}, 'a').write(json.dumps(sys.argv[1:]) + '\\n')\n"
        "if not any(a.startswith('--job=') for a in sys.argv[1:]):\n"
        f"    print(json.dumps({{'event': 'kernel', 'done': 1, 'total': 2, 'name': 'x',"
        " 'cached': False, 'seconds': 0.1}), flush=True)\n"
        f"    open({str(gate)!r}).read()\n"
    )
    job = "scenes: normals, triangulation"  # loads from the session's warm cache
    lines: list[str] = []
    warmup = Warmup(lines.append, child=(sys.executable, "-c", script), trust_stamp=False,
                    jobs=(job, "mesh files: repair"), first=(job,))
    warmup.start()
    try:
        assert warmup.ready.wait(100), warmup.as_dict()
        assert warmup.as_dict()["phase"] == "ready"
        assert wait_until(lambda: warmup.background_dict()["done"] == 1, HANG_S), \
            warmup.background_dict()
        assert warmup.background_dict()["phase"] == "compiling"
        gate.write_text("")
        assert wait_until(lambda: warmup.background_dict()["phase"] == "done", HANG_S), \
            warmup.background_dict()
    finally:
        warmup.stop()
    first, second = (json.loads(line) for line in calls.read_text().splitlines())
    assert first == [f"--job={job}"]  # the first frame's jobs, nothing else, before ready
    assert second == [f"--nice={BACKGROUND_NICE}"]  # every job, at low priority, after
    assert warmup.background_dict()["seconds"] is not None
    assert any("in the background" in ln for ln in lines), lines
    assert any("background compile done" in ln for ln in lines), lines


@pytest.mark.timeout(60)
def test_a_warm_start_has_no_background_compile():
    from service.readiness import Warmup

    warmup = Warmup(child=(sys.executable, "-c", "pass"), trust_stamp=False, jobs=(),
                    background=True)
    warmup.start()
    try:
        assert warmup.ready.wait(50), warmup.as_dict()
        assert warmup.background_dict()["phase"] == "none"
    finally:
        warmup.stop()


def test_the_server_is_handed_its_readiness_and_never_imports_the_warm_up():
    # the command builds the Warmup (service.commands.holo_service); the server takes it
    code = ("import sys, service.net.server; "
            "print(sorted(m for m in ('service.readiness', 'service.warmup') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"
