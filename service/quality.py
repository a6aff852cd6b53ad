"""``--quality auto``: the cheapest methods that keep a frame within an error budget.

Each frame the chooser predicts, from a *measured* cost model, what every candidate
would cost, and picks the cheapest whose predicted error fits the budget:

* **Occlusion.**  Every candidate it may pick is exact (equal to the z-buffer, bit
  for bit): the run-length method with pixel repair (its cost grows with the points
  the sort got wrong, so the count the last frame reported is part of the
  prediction: "runlength while the sort is consistent, pixel repair for a few bad
  points, the z-buffer past that"), the z-buffer, and BSP, a candidate only while the
  geometry stays the same as in the frame before (a static scene; its tree is then
  built once and reused, so its build cost is shared by the frames the geometry has
  stayed put so far).  The painter's order without repair is never picked: it
  costs as much as the repair and is wrong where the repair is right.
* **Specular.**  Light evaluated per polygon, per vertex or per point (the
  reference): the error of each against per-point light is measured on the centre
  zone of the frame (once per scene shape and display) and the cheapest within the
  budget is used.
* **Galilean order and update interval.**  From the measured table of the order x
  interval sweep (``holo-bench galilean``; error of refreshes against exact renders
  per kind of motion): the cheapest per refresh (render cost over the interval plus
  the refresh cost of the order) within the budget.

Errors are in the units of the Galilean benchmark: % of pixels whose largest colour
channel differs by more than :data:`service.lod.settings.COLOUR_LEVELS`
from the reference, or PSNR in dB.
The cost model is a least-squares fit of measured milliseconds (``holo-bench quality
--calibrate`` measures and writes it; ``service/lod/cost_model.json`` is the one
measured on the development machine, with its date and machine in ``meta``).  It is
:class:`service.lod.cost.CostModel`, the one cost model: level of detail's time
budget starts from it too.
"""

from __future__ import annotations

import hashlib
import math
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from service.base.errors import SettingsError
from service.display import DisplaySettings
from service.lod.cost import OCCLUSION, SPECULAR, CostModel
from service.lod.settings import COLOUR_LEVELS
from service.render.cull import CullSettings
from service.render.frame import Frame
from service.render.light import LightSettings, shade
from service.render.occlusion import Visibility
from service.render.pipeline import Renderer, RenderSettings
from service.render.projection import project
from service.render.scene import Scene, SceneArrays

MODES = ("fixed", "auto")


@dataclass(frozen=True)
class ErrorBudget:
    """How wrong a frame may be: % of pixels wrong, or a least PSNR (dB)."""

    max_pct: float | None = 0.5
    min_psnr: float | None = None

    def __post_init__(self) -> None:
        if (self.max_pct is None) == (self.min_psnr is None):
            raise SettingsError("an error budget is either a % of pixels or a PSNR in dB")
        if self.max_pct is not None and not 0.0 <= self.max_pct <= 100.0:
            raise SettingsError(f"max error must be 0-100 %, got {self.max_pct}")
        if self.min_psnr is not None and not self.min_psnr > 0.0:
            raise SettingsError(f"PSNR budget must be > 0 dB, got {self.min_psnr}")

    def allows(self, pct: float, psnr_db: float) -> bool:
        """Whether an error (% wrong, PSNR) fits."""
        if self.max_pct is not None:
            return pct <= self.max_pct
        return psnr_db >= self.min_psnr

    def as_dict(self) -> dict[str, float | None]:
        """``{"max_pct", "min_psnr"}`` (one of them None)."""
        return {"max_pct": self.max_pct, "min_psnr": self.min_psnr}


def parse_budget(text: str | float) -> ErrorBudget:
    """``"0.5"``, ``"0.5%"`` (% of pixels wrong) or ``"40dB"`` (least PSNR)."""
    if isinstance(text, int | float) and not isinstance(text, bool):
        return ErrorBudget(max_pct=float(text))
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*(%|db|dB|DB)?\s*", str(text))
    if m is None:
        raise SettingsError(f"max error must look like 0.5, 0.5% or 40dB, got {str(text)[:40]!r}")
    value = float(m.group(1))
    if (m.group(2) or "%").lower() == "db":
        return ErrorBudget(max_pct=None, min_psnr=value)
    return ErrorBudget(max_pct=value)


@dataclass(frozen=True)
class QualitySettings:
    """``mode``: "fixed" (the settings as given) or "auto"; ``budget``: the error budget."""

    mode: str = "fixed"
    budget: ErrorBudget = field(default_factory=ErrorBudget)

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise SettingsError(f"quality must be one of {MODES}, got {self.mode!r}")


def pct_wrong(a: np.ndarray, b: np.ndarray) -> float:
    """% of pixels of two (..., 3) uint8 images whose largest channel difference > COLOUR_LEVELS."""
    d = np.abs(a.astype(np.int16) - b.astype(np.int16)).max(axis=-1)
    return 100.0 * float((d > COLOUR_LEVELS).mean())


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR in dB of two uint8 images (99 when identical)."""
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return 99.0 if mse == 0 else 10.0 * math.log10(255.0**2 / mse)


# --------------------------------------------------------------------- chooser
@dataclass
class Choice:
    """What the chooser picked for one frame, with its predictions."""

    method: str
    specular: str
    predicted_ms: dict[str, float]
    predicted_error: dict[str, float]
    reason: str
    galilean: dict[str, Any] | None = None

    def as_dict(self) -> dict[str, Any]:
        """The ``quality`` block of the render stats and of ``--json``."""
        return {"method": self.method, "painter_fallback": "pixel", "specular": self.specular,
                "predicted_ms": {k: round(v, 3) for k, v in self.predicted_ms.items()},
                "predicted_error": self.predicted_error, "reason": self.reason,
                "galilean": self.galilean}


class QualityChooser:
    """Picks methods frame by frame; remembers what the last frames showed."""

    def __init__(self, settings: QualitySettings, model: CostModel | None = None) -> None:
        self.settings = settings
        self.model = model or CostModel.load()
        self._last_geometry: bytes | None = None
        self._static = False
        self._static_frames = 0
        self._tree_built = False
        self._bad = 0
        self._light_errors: dict[tuple, dict[str, tuple[float, float]]] = {}
        #: Pixels the last frame covered (all zones); the light cost grows with them.
        self.covered: int | None = None

    # occlusion -------------------------------------------------------------
    def occlusion(self, arrays: SceneArrays, display: DisplaySettings,
                  moving: bool = False) -> tuple[str, dict, str]:
        """(method, predicted ms per candidate, reason) for this frame's geometry.

        ``moving``: the scene has motion (a service renders it at later times than
        its snapshot), so it is never static.
        """
        key = _geometry_key(arrays)
        self._static = key == self._last_geometry and not moving
        self._static_frames = self._static_frames + 1 if self._static else 0
        if not self._static:
            self._tree_built = False
        self._last_geometry = key
        t, z, px = arrays.triangles.shape[0], display.zones, display.rows * display.cols
        method, ms = cheapest_occlusion(self.model, t, z, px, self._bad,
                                        self._static_frames, self._tree_built)
        reason = (f"cheapest exact method ({'static' if self._static else 'moving'} geometry, "
                  f"{self._bad} points out of sort order last frame)")
        return method, ms, reason

    def observe(self, method: str, occlusion_stats: dict[str, Any],
                covered: int | None = None) -> None:
        """Feed back what a frame showed: its out-of-order points, its covered pixels."""
        if method == "runlength":
            self._bad = int(occlusion_stats.get("inconsistent_pixels", 0))
        if method == "bsp":
            self._tree_built = True
        if covered is not None:
            self.covered = covered

    # light -----------------------------------------------------------------
    def light_errors(self, scene: Scene, arrays: SceneArrays, display: DisplaySettings,
                     model: str, vis_fn) -> dict[str, tuple[float, float]]:
        """Measured (% wrong, PSNR) of each evaluation against per-point light.

        Measured on the centre zone once per scene shape, light model and display
        (``vis_fn(arrays, display)`` gives that zone's visibility).
        """
        key = (arrays.n_polygons, arrays.triangles.shape[0], model, display.cols,
               display.rows, display.angle_deg, len(scene.lights))
        if key not in self._light_errors:
            one = DisplaySettings(zones=1, angle_deg=0.0, cols=display.cols,
                                  rows=display.rows, width=display.width)
            vis = vis_fn(arrays, one)
            proj = project(arrays.vertices, one)
            ref = _shade(scene, arrays, proj, vis, one, LightSettings(model, "point"))
            errs = {}
            for ev in SPECULAR:
                img = _shade(scene, arrays, proj, vis, one, LightSettings(model, ev))
                errs[ev] = (pct_wrong(img, ref), psnr(img, ref))
            self._light_errors[key] = errs
        return self._light_errors[key]

    def specular(self, errors: dict[str, tuple[float, float]], triangles: int,
                 covered: int) -> tuple[str, dict[str, float]]:
        """The cheapest evaluation within the budget (per point always fits)."""
        ms = {ev: self.model.light_ms(ev, triangles, covered) for ev in SPECULAR}
        fits = [ev for ev in SPECULAR if ev == "point" or self.settings.budget.allows(*errors[ev])]
        return min(fits, key=ms.__getitem__), ms

    # galilean --------------------------------------------------------------
    def galilean(self, motion: str, render_ms: float,
                 display: DisplaySettings) -> dict[str, Any] | None:
        """Cheapest (order, interval) per refresh within the budget, from the table.

        A refresh's cost is the table's, scaled by the pixels (the table was measured
        at a small size); a render is shared by the ``interval`` refreshes it feeds.
        """
        if motion == "none":  # nothing moves: any refresh repeats the render exactly
            longest = max((r["interval"] for r in self.model.galilean), default=1)
            return {"motion": motion, "order": 0, "interval": longest,
                    "predicted_pct_wrong": 0.0, "predicted_psnr": 99.0,
                    "predicted_ms_per_refresh": None}
        render_ms *= self.model.update_factor
        rows = [_scored(r) for r in self.model.galilean if r["motion"] == motion]
        rows = [r for r in rows if self.settings.budget.allows(r["pct_wrong"], r["psnr"])]
        if not rows:
            return None

        def per_refresh(r: dict) -> float:
            scale = _pixels(display) / max(1, r.get("pixels", _pixels(display)))
            return render_ms / r["interval"] + r["ms_per_refresh"] * scale

        best = min(rows, key=per_refresh)
        return {"motion": motion, "order": best["order"], "interval": best["interval"],
                "predicted_pct_wrong": round(best["pct_wrong"], 4),
                "predicted_psnr": round(best["psnr"], 2),
                "predicted_ms_per_refresh": round(per_refresh(best), 3)}


def cheapest_occlusion(model: CostModel, triangles: int, zones: int, pixels: int,
                       bad: int = 0, static_frames: int = 0,
                       tree_built: bool = False) -> tuple[str, dict[str, float]]:
    """The exact occlusion method the cost model predicts cheapest for one frame.

    Parameters
    ----------
    model : CostModel
    triangles, zones, pixels : int
        The scene's triangles, the display's zones and pixels per zone.
    bad : int
        Points the run-length method's sort got wrong last frame (its repair's cost).
    static_frames : int
        Frames the geometry has stayed put so far (0: it moves, and BSP, whose tree
        would be rebuilt every frame, is no candidate).
    tree_built : bool
        The BSP tree of this geometry exists; else its build is shared by the
        ``static_frames`` frames.

    Returns
    -------
    method : str
        One of :data:`service.lod.cost.OCCLUSION`; ties go to the earlier one.
    ms : dict of str to float
        Predicted stages 1-4 ms of every candidate.
    """
    ms = {m: model.occlusion_ms(m, triangles, zones, pixels, bad if m == "runlength" else 0)
          for m in OCCLUSION}
    if static_frames <= 0:
        del ms["bsp"]
    elif not tree_built:
        ms["bsp"] += model.build_ms(triangles) / static_frames
    return min(ms, key=ms.__getitem__), ms


def render_auto(renderer: Renderer, chooser: QualityChooser, scene: Scene,
                display: DisplaySettings, light_model: str = "blinn",
                cull: CullSettings | None = None) -> Frame:
    """Render one frame with the methods the chooser picks for it.

    Returns
    -------
    Frame
        As :meth:`Renderer.render`, with ``stats["quality"]``: the choices, the
        predicted milliseconds of every candidate and the predicted error
        (``pct_wrong``, ``psnr`` of the light against per-point light; occlusion is
        exact), and the Galilean order and interval for the scene's motion.
    """
    choice = choose(chooser, scene, display, light_model)
    settings = RenderSettings(method=choice.method, cull=cull or CullSettings(),
                              light=LightSettings(light_model, choice.specular),
                              painter_fallback="pixel")
    frame = renderer.render(scene, display, settings)
    chooser.observe(choice.method, frame.stats["occlusion"],
                    int(np.isfinite(frame.depth).sum()))
    frame.stats["quality"] = choice.as_dict()
    return frame


def choose(chooser: QualityChooser, scene: Scene, display: DisplaySettings,
           light_model: str = "blinn") -> Choice:
    """The methods for the next frame of ``scene`` (then :meth:`QualityChooser.observe`)."""
    arrays = scene.flatten()
    kind = motion_kind(scene)
    method, occ_ms, reason = chooser.occlusion(arrays, display, moving=kind != "none")
    errors = chooser.light_errors(scene, arrays, display, light_model, _zbuffer_visibility)
    covered = chooser.covered if chooser.covered is not None else _pixels(display)
    spec, light_ms = chooser.specular(errors, arrays.triangles.shape[0], covered)
    predicted = occ_ms[method] + light_ms[spec]
    return Choice(
        method, spec,
        {**{f"occlusion_{m}": v for m, v in occ_ms.items()},
         **{f"light_{e}": v for e, v in light_ms.items()}, "total": predicted},
        {"pct_wrong": round(errors[spec][0], 4), "psnr": round(errors[spec][1], 2),
         "occlusion_pct_wrong": 0.0},
        reason,
        chooser.galilean(kind, predicted, display),
    )


def _zbuffer_visibility(arrays: SceneArrays, display: DisplaySettings) -> Visibility:
    return Renderer().visibility(arrays, display, RenderSettings("zbuffer"))[0]


def motion_kind(scene: Scene) -> str:
    """The sweep's motion a scene resembles: rotating, falling, linear, or none."""
    m = [o.motion for o in scene.objects]
    if any(np.any(x.angular_velocity) or np.any(x.angular_acceleration) for x in m):
        return "rotating-cube"
    if any(np.any(x.acceleration) for x in m):
        return "falling"
    return "linear" if any(np.any(x.velocity) for x in m) else "none"


def _geometry_key(arrays: SceneArrays) -> bytes:
    """A digest of the flattened geometry (same key: static since the last frame)."""
    h = hashlib.blake2b(digest_size=16)
    h.update(np.ascontiguousarray(arrays.vertices).tobytes())
    h.update(np.ascontiguousarray(arrays.triangles).tobytes())
    return h.digest()


def _shade(scene: Scene, arrays: SceneArrays, proj: np.ndarray, vis: Visibility,
           display: DisplaySettings, light: LightSettings) -> np.ndarray:
    return shade(arrays, proj, vis, display, scene.lights, scene.ambient, light)


def _scored(row: dict[str, Any]) -> dict[str, Any]:
    """A sweep row; interval 1 (a render every refresh) scores no refresh: exact."""
    if row.get("pct_wrong") is None:
        return {**row, "pct_wrong": 0.0, "psnr": 99.0}
    return row


def _pixels(display: DisplaySettings) -> int:
    """Pixels of every zone together."""
    return display.zones * display.rows * display.cols
