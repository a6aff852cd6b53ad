"""The service killed mid-game: the game shows "reconnecting" and resumes when it is back."""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import pytest
from real_service import attract_client
from testkit import HANG_S, free_port

from game.client_loop import GameClient
from game.display import GameWindow

BANNER = (255, 220, 90)


def start_service(control: str, frames: str) -> subprocess.Popen:
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "service.commands.holo_service",
            "--control",
            control,
            "--frames",
            frames,
            "--worker-address",  # of its own choosing: only control and frames are kept
            "tcp://127.0.0.1:*",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


def tick_until(client: GameClient, pred, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        client.tick()


def shows_banner(client: GameClient) -> bool:
    return bool(np.any(np.all(client.window.pixels() == BANNER, axis=-1)))


@pytest.mark.timeout(300)  # the waits below are hang guards (HANG_S)
def test_service_killed_mid_game_reconnecting_then_resumes(pygame_headless):
    control = f"tcp://127.0.0.1:{free_port()}"
    frames = f"tcp://127.0.0.1:{free_port()}"
    procs = [start_service(control, frames)]
    backend = None
    try:
        backend, client = attract_client(control, frames, GameWindow((320, 240)))
        tick_until(client, lambda: client.renders.count >= 2, HANG_S, "frames")
        assert not shows_banner(client)
        procs[0].kill()
        procs[0].wait(HANG_S)
        tick_until(client, lambda: not backend.connected, HANG_S, "the link to drop")
        client.tick()
        assert shows_banner(client)  # "reconnecting"
        paused_at = client.state.t
        client.tick()
        assert client.state.t == paused_at  # the game waits
        procs.append(start_service(control, frames))
        renders = client.renders.count
        tick_until(
            client,
            lambda: backend.connected and client.renders.count > renders + 1,
            HANG_S,
            "frames from the new service",
        )
        # a loaded machine may see the restarting service drop once more before it settles
        assert client.disconnects >= 1 and backend.reconnects >= 1
        tick_until(client, lambda: client.state.t > paused_at + 0.2, HANG_S, "the game to go on")
        assert not shows_banner(client)
    finally:
        if backend is not None:
            backend.close()
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait(10)
