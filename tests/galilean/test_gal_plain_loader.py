"""The stage loads the plain scatter kernel from numba's cache off its refresh thread."""

from __future__ import annotations

import json
import subprocess
import sys

from tests.testkit import HANG_S, ROOT

#: A fresh process on the session's warm cache (``holo-warmup`` cached the plain
#: kernel for the made-up maps' types): G(2) refreshes after a head turn (where the
#: plain kernel runs once it is there), each noting whether the kernel was loaded
#: before the refresh and whether the refresh ran it.
_CHILD = r"""
import json, threading, time
import numpy as np
from service.display import DisplaySettings
from service.galilean import GalileanSettings, GalileanStage
from service.galilean.scatter_bands import scatter_bands_plain
from service.galilean.stage import PLAIN_LOADER
from service.galilean.warmup_jobs import made_up_map
from service.render.scene import MotionState

stage = GalileanStage(DisplaySettings(zones=1, cols=64, rows=48),
                      GalileanSettings(order=2, refresh_hz=60.0))
rng = np.random.default_rng(7)
steps, loaders = [], set()
deadline = time.monotonic() + DEADLINE
while time.monotonic() < deadline and not (steps and steps[-1][1]):
    if len(steps) % 8 == 0:  # a graft, then a head turn: well within the map's use-by
        stage.submit(made_up_map(stage, rng), stage.index + 1, None, True,
                     (), None, None, MotionState())
        stage.refresh()
        stage.viewer(MotionState(velocity=[0.1, 0.0, 0.0], angular_velocity=[0.0, 0.2, 0.0]))
    before = len(scatter_bands_plain.overloads)
    stage.refresh()
    loaders |= {t.name for t in threading.enumerate() if t.name == PLAIN_LOADER}
    steps.append((before, stage._plain))
print(json.dumps({"steps": steps, "loaders": sorted(loaders),
                  "refresh_thread": threading.current_thread().name}))
"""


def test_plain_kernel_is_loaded_off_the_refresh_thread_then_used() -> None:
    """The switch to the plain kernel comes after its own thread loaded it.

    Loading it from the cache inside a refresh took 25-30 ms of CPU (a 70-100 ms
    hitch on a loaded machine): the first refreshes run the banded kernel while
    the loader thread works, and the refresh that first runs the plain kernel
    finds it loaded.
    """
    proc = subprocess.run([sys.executable, "-c", f"DEADLINE = {HANG_S}\n{_CHILD}"], cwd=ROOT,
                          capture_output=True, text=True, timeout=HANG_S + 120, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    got = json.loads(proc.stdout.splitlines()[-1])
    steps = got["steps"]
    assert steps[-1][1], f"the plain kernel never came into use: {steps[:3]}..{steps[-3:]}"
    assert steps[0] == [0, False], steps  # the first check starts the loader
    assert got["loaders"] == ["galilean-plain-loader"]
    first = next(i for i, (_, plain) in enumerate(steps) if plain)
    assert steps[first][0] == 1, "the refresh that switched loaded the kernel itself"
