"""``holo-warmup``'s command line: progress lines, the exit rule on a signal."""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from testkit import wait_until

ROOT = Path(__file__).resolve().parents[2]


#: Two cheap jobs: the signal lands while the second compiles (a few seconds of it, not
#: the render path's big kernels, which cannot be interrupted halfway).
_JOBS = ("scenes: normals, triangulation", "mesh files: repair")
#: A compile holds the interpreter until its kernel is done; the machine may be loaded.
SIGNAL_WAIT_S = 240


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    """One empty numba cache for the module (the second test finds job 1 compiled)."""
    return tmp_path_factory.mktemp("numba-cache")


def _env(cache: Path) -> dict[str, str]:
    return {**os.environ, "NUMBA_CACHE_DIR": str(cache), "PYTHONUNBUFFERED": "1"}


@pytest.mark.timeout(SIGNAL_WAIT_S + 120)
def test_sigint_while_compiling_is_one_line_and_130(cache):
    env = _env(cache)
    p = subprocess.Popen([sys.executable, "-m", "service.commands.holo_warmup", "--jsonl",
                          *(f"--job={j}" for j in _JOBS)], cwd=ROOT,
                         env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        first = json.loads(p.stdout.readline())  # blocks until the first job is done
        assert first["event"] == "kernel" and first["done"] == 1 and first["total"] == 2
        p.send_signal(signal.SIGINT)
        rc = p.wait(SIGNAL_WAIT_S)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    err = p.stderr.read().strip().splitlines()
    assert rc == 130
    assert err[-1] == "holo-warmup: interrupted (SIGINT)"
    assert "Traceback" not in "\n".join(err)


def test_bad_option_is_usage_error():
    p = subprocess.run([sys.executable, "-m", "service.commands.holo_warmup", "--nope"], cwd=ROOT,
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and "error:" in p.stderr


#: A parent that starts a warm-up's second process as ``warm_up`` does, prints its
#: pid, and passes its JSON lines through.
_PARENT = """
import os, subprocess, sys
child = subprocess.Popen([sys.executable, "-m", "service.commands.holo_warmup", "--jsonl",
                          "--processes", "1", f"--parent-pid={os.getpid()}",
                          *(f"--job={j}" for j in sys.argv[1:])])
print(child.pid, flush=True)
child.wait()
"""


def _gone(pid: int) -> bool:
    stat = Path(f"/proc/{pid}/stat")
    try:
        return stat.read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except (OSError, IndexError):
        return True


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="prctl(PR_SET_PDEATHSIG)")
@pytest.mark.timeout(SIGNAL_WAIT_S + 120)
def test_second_process_ends_when_its_parent_is_killed_mid_compile(cache):
    jobs = (_JOBS[0], "render runlength")  # the second compiles the render path: 20+ s
    parent = subprocess.Popen([sys.executable, "-c", _PARENT, *jobs], cwd=ROOT,
                              env=_env(cache), stdout=subprocess.PIPE, text=True)
    try:
        child = int(parent.stdout.readline())
        ended = os.pidfd_open(child)  # readable once the child ends (not our child: no wait)
        first = json.loads(parent.stdout.readline())  # job 1 done: job 2 compiles now
        assert first["event"] == "kernel" and first["done"] == 1
        parent.kill()  # no handler, no clean-up: only the kernel's death signal is left
        parent.wait(60)
        # the death signal is at once; job 2 takes longer than this to compile
        readable, _, _ = select.select([ended], [], [], 15)
        os.close(ended)
        assert readable and _gone(child), "the second process went on compiling without its parent"
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()
        if not _gone(child):
            os.kill(child, signal.SIGKILL)


def _reading_stdin(pid: int) -> bool:
    """True while ``pid``'s main thread sits in read(2) on fd 0 (x86-64 and arm64)."""
    try:
        words = Path(f"/proc/{pid}/task/{pid}/syscall").read_text().split()
    except OSError:
        return False
    return len(words) > 1 and words[0] in ("0", "63") and int(words[1], 16) == 0


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc/PID/syscall")
@pytest.mark.timeout(SIGNAL_WAIT_S + 120)
def test_second_process_holds_before_the_named_job_until_released(cache):
    """``--hold-before``: the Galilean child waits there while its parent compiles."""
    p = subprocess.Popen([sys.executable, "-m", "service.commands.holo_warmup", "--jsonl",
                          *(f"--job={j}" for j in _JOBS), f"--hold-before={_JOBS[1]}"],
                         cwd=ROOT, env=_env(cache), stdin=subprocess.PIPE,
                         stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        first = json.loads(p.stdout.readline())
        assert first["event"] == "kernel" and first["name"] == _JOBS[0]
        assert wait_until(lambda: _reading_stdin(p.pid), SIGNAL_WAIT_S), "it did not wait"
        assert select.select([p.stdout], [], [], 0)[0] == []  # job 2 has not run
        p.stdin.write("go\n")
        p.stdin.close()
        second = json.loads(p.stdout.readline())
        assert second["event"] == "kernel" and second["name"] == _JOBS[1]
        assert json.loads(p.stdout.readline())["event"] == "done"
        assert p.wait(SIGNAL_WAIT_S) == 0
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
