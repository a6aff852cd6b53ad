"""``--workers 0 --worker-address ADDR``: the broker waits for workers started elsewhere.

The "More machines" recipe of ``docs/service.md``: the service starts no local
worker, a worker started on its own connects to the address, and renders go to it.
Until one connects (and after the last one is gone) renders run in process.
"""

from __future__ import annotations

import subprocess
import sys

import pytest
from testkit import ROOT, free_port, wait_until

from service.net.client import FrameSubscriber, ServiceClient


def _worker_pids(c: ServiceClient) -> list[int]:
    return [w["pid"] for w in (c.stats()["workers"] or {}).get("workers", [])]


def _rendered_by(c: ServiceClient, pid: int) -> dict | None:
    header, _ = c.render_once()
    st = header["stats"]
    pids = {st.get("pid")} | {band.get("pid") for band in st.get("bands", [])}
    return header if pid in pids else None


def _frame_of(frames: FrameSubscriber, render_id: int) -> bool:
    got = frames.next(1.0)  # frames queued from before the render may come first
    return got is not None and got[0]["render_id"] >= render_id


def _start_worker(backend: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "service.net.worker", "--connect", backend, "--warm-up"]
    return subprocess.Popen(cmd, cwd=ROOT, stdin=subprocess.DEVNULL)


@pytest.mark.parametrize("split", ["frames", "bands"])
def test_workers_zero_with_a_worker_address_serves_remote_workers(service_factory, split):
    backend = f"tcp://127.0.0.1:{free_port()}"
    svc = service_factory(
        "--scene", "game", "--zones", "2", "--size", "32x24", "--split", split,
        "--workers", "0", "--worker-address", backend, "--refresh", "30", "--render-timeout", "2",
    )  # fmt: skip
    with ServiceClient(svc.control, timeout_s=30) as c, FrameSubscriber(svc.frames) as frames:
        st = c.stats()
        assert st["workers"] is not None, "no broker: remote workers could not connect"
        assert st["worker_pids"] == [] and st["split"] == "in_process"
        header, _ = c.render_once()  # no worker yet: rendered in process, no hang
        assert header["stats"]["mode"] == "in_process"

        worker = _start_worker(backend)
        try:
            assert wait_until(lambda: worker.pid in _worker_pids(c), 90), "worker never joined"
            assert c.stats()["split"] == split
            header = wait_until(lambda: _rendered_by(c, worker.pid), 30, 0.0)
            assert header, "renders never went to the remote worker"
            assert header["stats"]["mode"] == split
            st = c.stats()
            assert st["workers"]["dispatched"] >= 1 and st["worker_pids"] == []
            assert wait_until(lambda: _frame_of(frames, header["render_id"]), 20), "no frames"

            worker.kill()  # the only worker gone: back to rendering in process
            worker.wait(10)
            assert wait_until(lambda: c.stats()["split"] == "in_process", 30)
            header, _ = c.render_once()
            assert header["stats"]["mode"] == "in_process"
            assert wait_until(lambda: _frame_of(frames, header["render_id"]), 20), "no frames"
        finally:
            if worker.poll() is None:
                worker.kill()
                worker.wait(10)
