"""``holo-warmup``'s command line: progress lines, the exit rule on a signal."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


#: Two cheap jobs: the signal lands while the second compiles (a few seconds of it, not
#: the render path's big kernels, which cannot be interrupted halfway).
_JOBS = ("scenes: normals, triangulation", "mesh files: repair")
#: A compile holds the interpreter until its kernel is done; the machine may be loaded.
SIGNAL_WAIT_S = 240


@pytest.mark.timeout(SIGNAL_WAIT_S + 120)
def test_sigint_while_compiling_is_one_line_and_130(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path), "PYTHONUNBUFFERED": "1"}
    p = subprocess.Popen([sys.executable, "-m", "service.cli_warmup", "--jsonl",
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
    p = subprocess.run([sys.executable, "-m", "service.cli_warmup", "--nope"], cwd=ROOT,
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and "error:" in p.stderr
