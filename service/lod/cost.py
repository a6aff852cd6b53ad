"""The one cost model of frames: calibrated per method (:class:`CostModel`), corrected online.

:class:`CostModel` holds coefficients measured on a development machine (``holo-bench
quality --calibrate``; :data:`DEFAULT_MODEL`): stages 1-4 per occlusion method and
the light stage per evaluation, from triangles, zones and pixels.  ``--quality
auto`` (:mod:`service.quality`) chooses methods by it.  :class:`FrameCost`, level of
detail's time budget, starts from the same model's prediction for the frame's
method and display (:func:`frame_prior`) and replaces it with a line fitted to the
frames this machine measured.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from service.base.errors import SettingsError
from service.display import DisplaySettings

#: The model measured on the development machine (see ``meta`` inside).
DEFAULT_MODEL = Path(__file__).with_name("cost_model.json")
#: Occlusion methods the model has coefficients for (``--quality auto``'s candidates;
#: "bsp" only for a static scene).
OCCLUSION = ("runlength", "zbuffer", "bsp")
#: Light evaluations it has coefficients for, cheapest first; "point" is the reference.
SPECULAR = ("polygon", "vertex", "point")


def occlusion_features(triangles: int, zones: int, pixels: int, bad: int) -> np.ndarray:
    """Regressors of an occlusion cost: 1, k triangles, k triangle-zones, M pixel-zones, k bad.

    Per triangle once (projection, cull, depth keys: every zone shares them) and per
    triangle and zone (the drawing, its set-up partly shared): with one term for
    both, a fit over 1k-1M triangles missed a million-triangle frame by 40 % at
    one zone and at five in opposite directions.
    """
    return np.array([1.0, triangles / 1e3, triangles * zones / 1e3, pixels * zones / 1e6,
                     bad / 1e3])


#: Coefficients per occlusion method: one per :func:`occlusion_features` term.
OCCLUSION_TERMS = 5


def light_features(triangles: int, covered: int) -> np.ndarray:
    """Regressors of a light cost: 1, k triangles, M covered pixels (all zones)."""
    return np.array([1.0, triangles / 1e3, covered / 1e6])


@dataclass(frozen=True)
class CostModel:
    """Measured cost coefficients (ms) and the Galilean error table.

    Attributes
    ----------
    occlusion : dict
        Method -> the :data:`OCCLUSION_TERMS` coefficients of :func:`occlusion_features`
        (stages 1-4, ms).
    bsp_build : list of float
        BSP tree build ms: ``[a, b]``, ``a + b * k triangles``.
    light : dict
        Evaluation -> coefficients of :func:`light_features` (light stage, ms).
    galilean : list of dict
        Rows ``{motion, order, interval, pct_wrong, psnr, ms_per_refresh, pixels}``.
    update_factor : float
        An update for the Galilean stage (``render_with_motion``: the render, its
        difference renders and the galpixmap) in renders' time.
    meta : dict
        Where and when it was measured.
    """

    occlusion: dict[str, list[float]]
    bsp_build: list[float]
    light: dict[str, list[float]]
    galilean: list[dict[str, Any]] = field(default_factory=list)
    meta: dict[str, Any] = field(default_factory=dict)
    update_factor: float = 1.0

    def occlusion_ms(self, method: str, triangles: int, zones: int, pixels: int,
                     bad: int = 0) -> float:
        """Predicted stages 1-4 ms of ``method`` (at least 0)."""
        c = np.asarray(self.occlusion[method], float)
        return max(0.0, float(c @ occlusion_features(triangles, zones, pixels, bad)))

    def light_ms(self, evaluation: str, triangles: int, covered: int) -> float:
        """Predicted light-stage ms of ``evaluation`` (at least 0)."""
        c = np.asarray(self.light[evaluation], float)
        return max(0.0, float(c @ light_features(triangles, covered)))

    def build_ms(self, triangles: int) -> float:
        """Predicted BSP build ms."""
        return max(0.0, self.bsp_build[0] + self.bsp_build[1] * triangles / 1e3)

    def to_json(self) -> str:
        """The model as the JSON :meth:`load` reads."""
        return json.dumps({"occlusion": self.occlusion, "bsp_build": self.bsp_build,
                           "light": self.light, "galilean": self.galilean,
                           "update_factor": self.update_factor, "meta": self.meta}, indent=1)

    @classmethod
    def load(cls, path: str | Path | None = None) -> CostModel:
        """Read a model written by :meth:`to_json` (default :data:`DEFAULT_MODEL`)."""
        path = Path(path) if path is not None else DEFAULT_MODEL
        try:
            d = json.loads(path.read_text())
            model = cls(d["occlusion"], d["bsp_build"], d["light"], d.get("galilean", []),
                        d.get("meta", {}), float(d.get("update_factor", 1.0)))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise SettingsError(f"cost model {path}: {exc}") from exc
        missing = [m for m in OCCLUSION if m not in model.occlusion]
        missing += [e for e in SPECULAR if e not in model.light]
        if missing:
            raise SettingsError(f"cost model {path}: no coefficients for {missing}")
        short = [m for m, c in model.occlusion.items() if len(c) != OCCLUSION_TERMS]
        if short:
            raise SettingsError(
                f"cost model {path}: {short} need {OCCLUSION_TERMS} occlusion coefficients "
                "(1, k triangles, k triangle-zones, M pixel-zones, k bad points); "
                "recalibrate with holo-bench quality --calibrate")
        return model


def fit(rows: list[tuple[np.ndarray, float]]) -> list[float]:
    """Least-squares coefficients of ``ms ~ features`` (non-negative slopes), by relative error.

    Each row's residual is taken relative to its milliseconds: the calibration spans
    scenes of 1k to 1M triangles, and in absolute terms the million-triangle frames
    would decide the line alone (a 1 ms miss on a 1 ms frame weighs what it should).
    """
    x = np.array([f for f, _ in rows])
    y = np.array([ms for _, ms in rows])
    w = 1.0 / np.maximum(y, 1e-3)  # relative residuals
    x, y = x * w[:, None], y * w
    coef = np.zeros(x.shape[1])
    free = np.ones(x.shape[1], bool)
    while free.any():  # more work never costs less, nothing costs less than nothing:
        c, *_ = np.linalg.lstsq(x[:, free], y, rcond=None)  # drop negative terms, refit
        coef[:] = 0.0
        coef[free] = c
        if (c >= 0).all():
            break
        free[np.flatnonzero(free)[np.argmin(c)]] = False
    return [round(float(c), 6) for c in coef]


def frame_prior(model: CostModel, method: str, evaluation: str, display: DisplaySettings,
                motion: bool = False) -> tuple[float, float]:
    """``(fixed_ms, ms per triangle)`` of a frame as the calibrated model predicts it.

    Stages 1-4 of ``method`` (the z-buffer's for a method the model does not cover)
    and the light stage of ``evaluation``, with a quarter of the pixels covered;
    ``motion``: an update for the Galilean stage, ``model.update_factor`` renders.
    """
    pixels = display.rows * display.cols
    covered = display.zones * pixels // 4
    occ = method if method in model.occlusion else "zbuffer"
    light = evaluation if evaluation in model.light else "polygon"

    def ms(triangles: int) -> float:
        return (model.occlusion_ms(occ, triangles, display.zones, pixels)
                + model.light_ms(light, triangles, covered))

    k = model.update_factor if motion else 1.0
    return k * ms(0), k * max((ms(100_000) - ms(0)) / 100_000, 1e-9)


@dataclass
class FrameCost:
    """Measured cost model of one renderer's frames: ``ms = fixed_ms + per_triangle x T``.

    Until a frame is measured it predicts ``prior``, the calibrated model's line for
    the frame's method and display (:func:`frame_prior`).  Then it is fitted by
    least squares to the last ``window`` frames' (triangles, milliseconds)
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
        The line predicted from: ``prior`` until a frame is observed, then fitted
        (0 with neither).
    prior : tuple of float or None
        ``(fixed_ms, per_triangle)`` from the calibrated model, None without one.
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
    prior: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if self.prior is not None and not self.samples:
            self.fixed_ms, self.per_triangle = self.prior

    @property
    def ready(self) -> bool:
        """Whether it predicts: a frame measured, or the calibrated model's line."""
        return self.per_triangle > 0

    @property
    def measured(self) -> bool:
        """Whether the line is fitted to frames measured here (not the prior)."""
        return bool(self.samples)

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
                "frames": len(self.samples),
                "from": "measured" if self.measured else "calibrated"}


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
