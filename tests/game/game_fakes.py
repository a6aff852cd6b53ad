"""Test doubles of the game's renderer backend and device subscriber (no transport)."""

from __future__ import annotations

import numpy as np

from game.backends import FrameView
from service.display import DisplaySettings
from service.frame_settings import FrameSettings


class RecordingBackend:
    """Takes updates, hands out a grey frame per call; records everything."""

    def __init__(self, zones: int = 3) -> None:
        self.settings = FrameSettings(DisplaySettings(zones=zones, cols=32, rows=24))
        self.connected = True
        self.updates: list[list[dict]] = []
        self.explosions: list[int] = []
        self.resumes = 0
        self.seq = 0

    def start(self, scene) -> None:
        self.scene = scene

    def update(self, records: list[dict]) -> None:
        self.updates.append(records)

    def explode(self, seed: int = 0) -> None:
        self.explosions.append(seed)

    def resume(self) -> None:
        self.resumes += 1

    def frame(self, timeout_s: float = 0.0) -> FrameView:
        self.seq += 1
        d = self.settings.display
        grey = 40 * (np.arange(d.zones) + 1)[:, None, None, None]
        colour = np.broadcast_to(grey, (d.zones, d.rows, d.cols, 3)).astype(np.uint8)
        sird = np.broadcast_to(np.arange(d.cols, dtype=np.uint8) * 7, (d.rows, d.cols))
        return FrameView(colour, self.seq, len(self.updates), 0, None, 5.0, sird)

    def close(self) -> None:
        pass


class FakeDevices:
    """What GameClient reads from a DeviceSubscriber."""

    def __init__(self) -> None:
        self.queue: list = []
        self.pose = None
        self.pose_count = 0

    def poll(self, timeout_s: float = 0.0) -> int:
        return 0

    def take_events(self) -> list:
        out, self.queue = self.queue, []
        return out
