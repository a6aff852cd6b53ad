"""The service's background compile takes only CPU time nothing else wants (``SCHED_IDLE``).

A real :class:`service.readiness.Warmup` starts a stand-in background child that
spins on one CPU.  Beside a program at normal priority on the same CPU it gets
next to nothing (niceness 10 alone would leave it about a tenth); once that
program ends it gets the CPU again; the service's stop ends it.  Nothing is ever
stopped (SIGSTOP), so nothing can be left stopped when a client dies.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from testkit import HANG_S, wait_until

pytestmark = pytest.mark.skipif(not hasattr(os, "SCHED_IDLE"), reason="Linux's SCHED_IDLE")

#: A job the session's warm cache has: the in-process step loads it.
JOB = "scenes: normals, triangulation"


def _ticks(pid: int) -> int:
    """CPU clock ticks (user + system) process ``pid`` has used."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return int(fields[11]) + int(fields[12])


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


def _spinner(cpu: int, pid_file: Path | None = None) -> str:
    """Python code that pins itself to ``cpu`` and spins (the background: not for --job)."""
    mark = f"open({str(pid_file)!r}, 'w').write(str(os.getpid()))\n" if pid_file else ""
    return ("import os, sys\n"
            "if any(a.startswith('--job=') for a in sys.argv[1:]):\n"
            "    sys.exit(0)\n"
            f"os.sched_setaffinity(0, {{{cpu}}})\n"
            f"{mark}"
            "while True:\n"
            "    pass\n")


@pytest.mark.timeout(150)
def test_the_background_compile_gets_only_idle_cpu_and_resumes_when_it_is_free(tmp_path):
    from service.readiness import Warmup

    cpu = min(os.sched_getaffinity(0))
    pid_file = tmp_path / "bg.pid"
    warmup = Warmup(child=(sys.executable, "-c", _spinner(cpu, pid_file)), trust_stamp=False,
                    jobs=(JOB,), first=(JOB,))
    warmup.start()
    hog = None
    try:
        assert warmup.ready.wait(100), warmup.as_dict()
        assert wait_until(lambda: pid_file.exists() and pid_file.read_text(), HANG_S)
        pid = int(pid_file.read_text())
        assert os.sched_getscheduler(pid) == os.SCHED_IDLE
        bg = warmup.background_dict()
        assert bg["phase"] == "compiling" and bg["priority"] == "idle", bg
        # a program at normal priority on the same CPU: the background gets next to nothing
        hog = subprocess.Popen([sys.executable, "-c", _spinner(cpu)])
        assert wait_until(lambda: _ticks(hog.pid) > 0, HANG_S)
        hog0, bg0 = _ticks(hog.pid), _ticks(pid)
        assert wait_until(lambda: _ticks(hog.pid) - hog0 >= 150, HANG_S)  # 1.5 s of its CPU
        hog_got, bg_got = _ticks(hog.pid) - hog0, _ticks(pid) - bg0
        # SCHED_IDLE's weight is 3 against 1024 (0.3 %); niceness 10 would get 10 %
        assert bg_got <= 0.03 * hog_got + 2, (bg_got, hog_got)
        hog.kill()
        hog.wait()
        assert not _alive(hog.pid)
        hog = None
        # the CPU is free again: the background compile goes on
        bg1 = _ticks(pid)
        assert wait_until(lambda: _ticks(pid) - bg1 >= 50, HANG_S), (_ticks(pid), bg1)
    finally:
        if hog is not None:
            hog.kill()
            hog.wait()
        warmup.stop()
    assert wait_until(lambda: not _alive(pid), HANG_S)  # ended with the service, never stopped


def test_idle_priority_of_a_process_that_has_gone_is_refused_quietly():
    from service.readiness import idle_priority

    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    assert idle_priority(proc.pid) is False
