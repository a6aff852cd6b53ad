"""--out: the tour of the display modes waits for the first frame."""

from __future__ import annotations

import numpy as np
import pygame
import pytest
from game_fakes import RecordingBackend

from game.capture import Capture
from game.client_loop import GameClient, LoopSettings
from game.display import MODES, GameWindow
from game.rules import GameSettings


class SlowBackend(RecordingBackend):
    """No frame until ``first`` calls have passed (a service still starting)."""

    def __init__(self, first: int) -> None:
        super().__init__()
        self.first, self.calls = first, 0

    def frame(self, timeout_s: float = 0.0):
        self.calls += 1
        return None if self.calls <= self.first else super().frame(timeout_s)


# 0.9: no tick in a mode's last quarter; 2.5: ticks longer than two dwells (a loaded
# machine), which once skipped modes: the tour is slower then, never shorter
@pytest.mark.parametrize("step", [0.05, 0.9, 2.5])
def test_mode_tour_starts_with_the_first_frame(pygame_headless, tmp_path, step):
    clock = [0.0]
    client = GameClient(
        SlowBackend(first=100),  # 5 s of clock without a frame
        GameWindow((320, 200)),
        LoopSettings(GameSettings(), mode="zone"),
        clock=lambda: clock[0],
    )
    capture = Capture(tmp_path, 0.0, dwell_s=1.0)
    while client.backend.calls <= 100:  # the service starting
        clock[0] += 0.05
        client.tick()
        capture(client)
    for _ in range(max(int((len(MODES) + 1) / step) + 1, len(MODES) + 2)):
        clock[0] += step
        client.tick()
        capture(client)
    shots = {p.name: p for p in capture.files}
    assert {f"mode-{m}.png" for m in MODES} <= set(shots)
    greys = {40, 80, 120}  # zones 0, 1, 2 of RecordingBackend's frames
    for mode, shown in (("head", {80}), ("zone", {120}), ("strip", greys)):
        rgb = pygame.surfarray.array3d(pygame.image.load(shots[f"mode-{mode}.png"]))
        assert greys & set(np.unique(rgb[..., 0][(rgb[..., 0] == rgb[..., 2])])) == shown
    assert client.mode == "zone"  # back to the mode the run asked for
