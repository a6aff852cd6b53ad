"""The measured cost model of a renderer's frames: ``fixed + per triangle`` (:class:`FrameCost`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class FrameCost:
    """Measured cost model of one renderer's frames: ``ms = fixed_ms + per_triangle x T``.

    Fitted by least squares to the last ``window`` frames' (triangles, milliseconds)
    as the renderer measured them (:meth:`observe`; :func:`fit_cost`): far outliers
    dropped (a frame slowed by another process), the fixed part at most the cheapest
    frame's cost.  Until the frames span triangle counts at least 25 % apart
    (or when the fit says triangles cost nothing) the model is proportional,
    ``ms = per_triangle x T`` with the median of the frames' ratios: with a time
    budget that changes the triangle count, so the next frames span a range.

    Attributes
    ----------
    window : int
        Frames kept.
    samples : list of (int, float)
        (triangles, ms) of the frames kept, oldest first.
    fixed_ms, per_triangle : float
        The fitted line (0 until a frame is observed).
    skip_first : bool
        Leave out the first frame observed: it pays one-off costs (first calls into
        the kernels, first touch of the buffers); in the service a first render of
        the bunny scene measured 12 us per triangle against 2-5 after it, and the
        budget degraded a frame for it.
    """

    window: int = 32
    samples: list = field(default_factory=list)
    fixed_ms: float = 0.0
    per_triangle: float = 0.0
    skip_first: bool = True

    @property
    def ready(self) -> bool:
        """Whether a frame has been measured."""
        return self.per_triangle > 0

    def observe(self, triangles: int, ms: float) -> None:
        """Add a frame's triangles and milliseconds and refit."""
        if not (triangles > 0 and np.isfinite(ms) and ms > 0):
            return
        if self.skip_first:  # a cold frame: first calls, first touch of its buffers
            self.skip_first = False
            return
        self.samples.append((int(triangles), float(ms)))
        del self.samples[:-self.window]
        self.fixed_ms, self.per_triangle = fit_cost(np.array(self.samples, np.float64))

    def predict(self, triangles: float) -> float:
        """Predicted milliseconds of a frame of ``triangles`` triangles."""
        return self.fixed_ms + self.per_triangle * triangles

    def max_triangles(self, budget_ms: float) -> float:
        """Most triangles a frame may have to take at most ``budget_ms`` (0 if none)."""
        return max(budget_ms - self.fixed_ms, 0.0) / self.per_triangle

    def as_dict(self) -> dict:
        """The model as the LOD report carries it."""
        return {"fixed_ms": round(self.fixed_ms, 3),
                "us_per_triangle": round(self.per_triangle * 1e3, 5),
                "frames": len(self.samples)}


def fit_cost(samples: np.ndarray) -> tuple[float, float]:
    """``(fixed_ms, ms_per_triangle)`` fitted to frames (see :class:`FrameCost`).

    A least-squares line; with 8 frames or more, those over three median deviations
    off it are dropped and it is fitted again.  The fixed part is then held to
    ``[0, the cheapest frame's ms]`` (no frame can cost less than the fixed part: on
    a loaded machine a few slow frames can otherwise tilt the line into a fixed cost
    larger than whole frames measured) and the slope refitted through it.

    Parameters
    ----------
    samples : ndarray, shape (N, 2), float64
        Triangles and milliseconds per frame, N >= 1, triangles > 0.
    """
    t, ms = samples[:, 0], samples[:, 1]
    if len(t) >= 2 and t.max() >= 1.25 * t.min():
        keep = np.ones(len(t), np.bool_)
        b, a = np.polyfit(t, ms, 1)
        if len(t) >= 8:  # enough frames to tell an outlier from the line
            resid = np.abs(ms - (a + b * t))
            new = resid <= 3.0 * 1.4826 * (float(np.median(resid)) or 1e-9)
            if new.sum() >= 6 and t[new].max() >= 1.25 * t[new].min():
                keep = new
                b, a = np.polyfit(t[keep], ms[keep], 1)
        a = min(max(float(a), 0.0), float(ms[keep].min()))
        b = float(((ms[keep] - a) * t[keep]).sum() / (t[keep] ** 2).sum())
        if b > 0 and _slope_known(t[keep], ms[keep], a, b):
            return a, b
    return 0.0, float(np.median(ms / t))


def _slope_known(t: np.ndarray, ms: np.ndarray, a: float, b: float) -> bool:
    """Whether the frames pin the slope down: its standard error under 25 % of it.

    Frames of nearly one triangle count on a busy machine give a line whose slope is
    noise (the service measured 9-12 us per triangle against 2 from a wider spread);
    the proportional model is right near the frames measured, which is where the
    budget's next choice lies, and the frames it causes widen the spread.
    """
    n = len(t)
    if n < 3:
        return True  # two frames 25 % apart: no noise estimate, take the line
    resid = ms - (a + b * t)
    spread = float(((t - t.mean()) ** 2).sum())
    se = float(np.sqrt((resid ** 2).sum() / (n - 2) / spread)) if spread > 0 else np.inf
    return se < 0.25 * b
