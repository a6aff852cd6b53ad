"""What level of detail is asked for: :class:`LodSettings`, its defaults and limits."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from service.base.errors import HoloError, SettingsError

#: Triangle fractions of the decimated levels (each level's target, of the full mesh).
DEFAULT_FRACTIONS = tuple(round(0.7 ** k, 4) for k in range(1, 15))
#: Billboard-cloud levels: EPS as fractions of the mesh's bounding-box diagonal.  None
#: by default: where LOD may choose a cloud (about 10 px across at EPS 1 %) it costs
#: 2-6x less than the full mesh but 2-4x more than the quadric level of the same
#: predicted error (holo-bench billboard part 4, docs/simplify.md "Cost"), and in the
#: crowd it saved no time while raising the image error; opt in with e.g. (0.01,).
DEFAULT_CLOUD_EPS: tuple[float, ...] = ()
#: Billboard texels are grown by this many EPS to close cracks (service.simplify).
CLOUD_DILATE = 0.5
#: A cloud's cost in triangles per quad: a quad covers many pixels, each with a texel
#: lookup, alpha and depth tests and its own light; holo-bench billboard part 4
#: measured a quad at about 60-130 triangles' worth of frame time (5 zones, 320x240,
#: bunny, torus and spiky attacker at 10 px).  Counting it as the two triangles it
#: is drawn as let LOD pick a cloud that cost 1.9x the quadric level beside it.
QUAD_TRIANGLES = 100
#: Bump when the chain's contents or file layout change (old cache files are rebuilt).
#: 9: quadric levels carry the full mesh's normals (``shading_faces_k``, ``shading_vertices_k``).
CHAIN_VERSION = 9
#: A pixel's colour differs when a channel changes by more than this many levels (of 255).
COLOUR_LEVELS = 32
#: Angles (degrees) at which a chain measures the share of its surface whose light
#: normal turns further (:attr:`service.lod.chain.LodChain.turned`); the selector
#: interpolates at each object's own angle (:func:`service.lod.select.colour_angle`).
COLOUR_ANGLES = (4.0, 6.0, 8.0, 11.0, 16.0, 22.0, 32.0, 45.0, 64.0, 90.0)
#: Default colour budget: % of the display's pixels predicted to change colour (issue
#: 31's target: <= 1 % of all pixels).  Measured on holo-bench lod's crowds with Blinn
#: per polygon: 0.86-1.48 % changed, against 3.6-4.0 % with colour not counted.
DEFAULT_COLOUR_PCT = 1.0
#: Largest colour budget a command line or the wire takes (all of the pixels).
COLOUR_PCT_MAX = 100.0
#: Environment variable naming the cache folder.
CACHE_ENV = "HOLO_LOD_CACHE"
#: An error this many times the finer level's is a jump whose plateau end is sought.
PLATEAU_JUMP = 1.5
#: Decimations spent seeking each such plateau end (bisection on the fraction).
PLATEAU_STEPS = 3
#: fast-simplification's aggressiveness for the chain's levels (its default is 7).  At
#: 4 the sampled error of the levels 70 % to 2 % measured 0.47-1.19x (mostly 0.6-0.9x)
#: that at 7 on the bunny, the torus and the spiky attacker, at about the same cost.
QUADRIC_AGG = 4
#: Dead band of the time budget, a fraction of it (:meth:`LodState._budget`).
BUDGET_BAND = 0.1
#: Levels smaller than this many triangles are not built.
MIN_TRIANGLES = 8

#: Chains a renderer keeps in memory by mesh hash (the least recently used go first).
CHAINS_KEPT = 64
#: Cache problems and failed builds a renderer keeps for its LOD report.
NOTES_KEPT = 4
#: Nice value a background chain build's process adds to its own (renders come first).
BUILD_NICE = 5
#: ``progress(done, planned)``: decimations done and planned of a chain's build.
Progress = Callable[[int, int], None]


class LodError(HoloError, ValueError):
    """A level-of-detail chain cannot be built or read."""


class LodCacheWarning(UserWarning):
    """The chain cache folder could not be written; the chain is used uncached."""


@dataclass(frozen=True)
class LodSettings:
    """Level-of-detail choices for a render.

    Attributes
    ----------
    error_px : float > 0
        Largest predicted screen error of a chosen level, in pixels (default 0.5).
    enabled : bool
        False renders every object with its full mesh (``--lod off``).
    budget_ms : float or None
        Optional frame-time budget; objects are degraded past ``error_px`` to meet it.
    hysteresis : float in [0, 1)
        Coarsen only when the coarser level predicts under ``(1 - hysteresis) x error_px``.
    fractions : tuple of float in (0, 1)
        Triangle fractions of the decimated levels.
    cloud_eps : tuple of float in (0, 1)
        Billboard-cloud levels (issue 13B), each with EPS this fraction of the mesh's
        bounding-box diagonal; () for none (the default, see ``DEFAULT_CLOUD_EPS``).
        Used only where billboards can be drawn (``Renderer.render``).
    texture_res : int
        Texels across the bounding-box diagonal of each cloud's textures.
    colour_pct : float >= 0 or None
        Most % of the display's pixels predicted to change colour by more than
        :data:`COLOUR_LEVELS` (:func:`service.lod.select.limit_colour`); objects are
        drawn finer until the prediction fits (default :data:`DEFAULT_COLOUR_PCT`).
        None: colour is not counted (levels by the geometric error alone).
    """

    error_px: float = 0.5
    enabled: bool = True
    budget_ms: float | None = None
    hysteresis: float = 0.25
    fractions: tuple[float, ...] = DEFAULT_FRACTIONS
    cloud_eps: tuple[float, ...] = DEFAULT_CLOUD_EPS
    texture_res: int = 256
    colour_pct: float | None = DEFAULT_COLOUR_PCT

    def __post_init__(self) -> None:
        if not (np.isfinite(self.error_px) and self.error_px > 0):
            raise SettingsError(f"LOD error must be a number of pixels > 0, got {self.error_px}")
        if self.budget_ms is not None and not (
            np.isfinite(self.budget_ms) and self.budget_ms > 0
        ):
            raise SettingsError(f"LOD budget must be > 0 ms, got {self.budget_ms}")
        if not 0 <= self.hysteresis < 1:
            raise SettingsError(f"LOD hysteresis must be in [0, 1), got {self.hysteresis}")
        if not self.fractions or not all(0 < f < 1 for f in self.fractions):
            raise SettingsError(f"LOD fractions must be in (0, 1), got {self.fractions}")
        if not all(0 < f < 1 for f in self.cloud_eps):
            raise SettingsError(f"LOD cloud EPS fractions must be in (0, 1), got {self.cloud_eps}")
        if self.colour_pct is not None and not (
            np.isfinite(self.colour_pct) and self.colour_pct >= 0
        ):
            raise SettingsError(f"LOD colour budget must be a % >= 0, got {self.colour_pct}")
        if not (isinstance(self.texture_res, int) and self.texture_res >= 1):
            raise SettingsError(f"LOD texture_res must be an integer >= 1, got {self.texture_res}")

    @property
    def recipe(self) -> str:
        """What the chain is built from, for its cache key."""
        fr = ",".join(f"{f:.6g}" for f in self.fractions)
        ce = ",".join(f"{f:.6g}" for f in self.cloud_eps)
        return f"q[{fr}]b[{ce}]t{self.texture_res}"


def lod_from(error_px: float | None, budget_ms: float | None,
             colour_pct: float | None = DEFAULT_COLOUR_PCT,
             colour_given: bool = False) -> LodSettings | None:
    """Settings from an error budget (px), a time budget (ms) and a colour budget (%).

    As the service's command line gives them: 0 or None means not set; no budget
    set: None (level of detail off); a time budget alone turns it on at the default
    0.5 px, as does a colour budget that was given (``colour_given``).
    ``colour_pct`` None: colour not counted.
    """
    error_px, budget_ms = float(error_px or 0.0), float(budget_ms or 0.0)
    if error_px <= 0 and budget_ms <= 0 and not colour_given:
        return None
    return LodSettings(error_px=error_px if error_px > 0 else LodSettings.error_px,
                       budget_ms=budget_ms if budget_ms > 0 else None, colour_pct=colour_pct)
