"""The service's ``autostereogram`` output: a SIRD of every refresh's depth.

:class:`SirdOutput` keeps what stays the same from one refresh to the next (the
settings, the seeded pattern, the scratch buffers), so each refresh pays only for
the kernel, and the dots stay put where the depth did not change.  Each refresh
gets a new output array (frames are published zero-copy, so a sent one is never
overwritten).
"""

from __future__ import annotations

import time

import numpy as np

from service.autostereogram.geometry import SirdSettings, default_eye_sep
from service.autostereogram.patterns import random_dots
from service.autostereogram.stage import SirdWorkspace, stereogram

#: Near and far planes as fractions of the display's width, in front of and behind it.
DEPTH_SPAN = 0.3


class SirdOutput:
    """SIRD frames of one display size.

    Parameters
    ----------
    cols, rows : int
        Display size; the eye separation defaults to :func:`default_eye_sep` of ``cols``.
    width : float
        Display width in world units; ``near, far = -/+ DEPTH_SPAN * width``.
    method : str
        ``row``, ``interpolated`` or ``tiw``.
    eye_sep : float, optional
        Eye separation in pixels (0 or None: the default).
    seed : int
        Seed of the grey dots.
    """

    def __init__(self, cols: int, rows: int, width: float, method: str = "tiw",
                 eye_sep: float | None = None, seed: int = 0) -> None:
        span = DEPTH_SPAN * width
        self.settings = SirdSettings(method=method, eye_sep=eye_sep or default_eye_sep(cols),
                                     near=-span, far=span)
        self.settings.check_width(cols)
        self.pattern = random_dots(self.settings.max_sep, seed=seed)
        self.work = SirdWorkspace(rows, cols, 1, keep_links=False)
        self.last_ms = 0.0

    def frame(self, depth: np.ndarray) -> np.ndarray:
        """The stereogram of one depth map (rows, cols), as a new (rows, cols) uint8 array.

        NaN depths (none come from the renderer or the Galilean stage) raise
        :class:`service.base.errors.SettingsError`.
        """
        t0 = time.perf_counter()
        self.work.fresh_output()
        image, _ = stereogram(depth, self.settings, self.pattern, self.work)
        self.last_ms = (time.perf_counter() - t0) * 1e3
        return image[:, :, 0]


def warm_up_sird(method: str) -> None:
    """Compile (or load from numba's cache) one method's kernels on a tiny grey frame.

    The first call in a process costs a few hundred milliseconds; a display thread
    should not pay it.
    """
    SirdOutput(64, 2, 2.0, method, eye_sep=20.0).frame(np.full((2, 64), np.inf, np.float32))
