"""holo-view --web: a real service, the real command, and a real headless Chromium.

The page posts what it shows (its status line, the frame's size and a checksum of its
pixels, drawn from the MJPEG stream onto a canvas) to ``/seen`` once a second; the
tests read that back from ``/status.json``.  Without a Chromium the browser test skips,
saying so; the HTTP tests run everywhere.
"""

from __future__ import annotations

import contextlib
import json
import re
import shutil
import signal
import subprocess
import tempfile
import urllib.request

import pytest
from testkit import (
    HANG_S,
    SMALL_SERVICE,
    TINY_DISPLAY,
    Proc,
    launch_service,
    start_service,
    wait_until,
)

from service.net.client import ServiceClient
from service.web_view import LAYOUTS

BROWSERS = ("chromium", "chromium-browser", "google-chrome")
BROWSER = next((b for b in map(shutil.which, BROWSERS) if b), None)
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu",
                  "--disable-background-networking", "--disable-component-update",
                  "--disable-sync", "--no-first-run", "--disable-dev-shm-usage")


def _get(url: str) -> tuple[str, bytes]:
    with urllib.request.urlopen(url, timeout=10) as reply:
        return reply.headers.get("Content-Type", ""), reply.read()


def _status(base: str) -> dict:
    return json.loads(_get(base + "/status.json")[1])


@pytest.fixture
def service():
    svc = start_service(*SMALL_SERVICE, ready_timeout_s=HANG_S)
    yield svc
    svc.stop()


@contextlib.contextmanager
def web_view(svc):
    """``holo-view --web --port 0`` on ``svc``; yields its base URL."""
    proc = Proc("drivers.commands.holo_view", "--web", "--port", "0", "--service", svc.control,
                "--frames", svc.frames)
    found = {}

    def bound() -> bool:
        for line in proc.err:
            m = re.search(r"at (http://127\.0\.0\.1:\d+)/", line)
            if m:
                found["url"] = m.group(1)
        return "url" in found

    try:
        proc.wait_lines(bound, HANG_S)
        yield found["url"]
    finally:
        proc.signal(signal.SIGTERM)
        assert proc.finish(HANG_S) == 143


@pytest.fixture
def web(service):
    with web_view(service) as url:
        yield url


def test_a_warming_up_service_shows_its_progress(tmp_path):
    svc = launch_service("--scene", "game", *TINY_DISPLAY[:-2],
                         env={"NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")})
    try:
        with web_view(svc) as url:
            assert wait_until(lambda: _status(url)["status"] == "warming_up", HANG_S)
            status = _status(url)
            assert status["alive"] and {"done", "total"} <= set(status["warmup"] or {}), status
    finally:
        svc.stop()


def test_the_page_status_and_every_layout_are_served(web):
    kind, page = _get(web + "/")
    assert kind.startswith("text/html") and b"/stream.mjpg" in page
    assert wait_until(lambda: _status(web)["frames"] > 0 and _status(web)["stats"], HANG_S)
    status = _status(web)
    assert status["zones"] == 2 and status["stats"]["refreshes_per_s"] is not None
    for layout in LAYOUTS:
        kind, data = _get(f"{web}/frame.jpg?layout={layout}&zone=1")
        assert kind == "image/jpeg" and data[:2] == b"\xff\xd8", layout
    with urllib.request.urlopen(web + "/stream.mjpg?layout=strip", timeout=10) as stream:
        assert "multipart/x-mixed-replace" in stream.headers["Content-Type"]
        head = stream.read(200)
        assert b"--holoframe" in head and b"image/jpeg" in head


def test_the_viewer_pose_is_shown(service, web):
    with ServiceClient(service.control) as c:
        c.set_viewer(position=[0.25, 0.0, 1.5])
    assert wait_until(lambda: (_status(web)["viewer"] or {}).get("position"), HANG_S)
    assert _status(web)["viewer"]["position"] == pytest.approx([0.25, 0.0, 1.5])


def test_a_stopped_service_is_reported(service, web):
    wait_until(lambda: _status(web)["alive"], HANG_S)
    service.stop()
    assert wait_until(lambda: not _status(web)["alive"], HANG_S)


@pytest.mark.skipif(BROWSER is None, reason="no Chromium installed (Debian: apt-get install "
                    "chromium); the browser test needs a real one")
def test_a_headless_chromium_shows_the_moving_scene_and_the_stop(service, web):
    with tempfile.TemporaryDirectory() as profile:
        browser = subprocess.Popen(
            [BROWSER, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", web + "/?layout=zone"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            _check_in_browser(service, web)
        finally:
            browser.terminate()
            browser.wait(HANG_S)


def _check_in_browser(service, web: str) -> None:
    def seen() -> dict:
        return _status(web)["seen"]

    assert wait_until(lambda: (seen().get("width") or 0) > 0
                      and seen().get("status", "").startswith("live"), HANG_S), seen()
    with ServiceClient(service.control) as c:  # move the scene: the picture must change
        c.update_objects([{"index": 0, "velocity": [0.6, 0.2, 0.0]}])
    sums = set()
    assert wait_until(lambda: sums.add(seen().get("checksum")) or len(sums) >= 3, HANG_S), sums
    assert _status(web)["viewers"] >= 1
    service.stop()
    assert wait_until(lambda: "stopped" in seen().get("status", ""), HANG_S), seen()


def test_a_port_in_use_is_one_line_and_status_2():
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        proc = Proc("drivers.commands.holo_view", "--web", "--port", str(port))
        assert proc.finish(HANG_S) == 2
    assert len(proc.err) == 1 and proc.err[0].startswith(
        f"holo-view: error: cannot listen on 127.0.0.1:{port}"), proc.err
