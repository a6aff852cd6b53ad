"""Looking Glass output: a display calibration and the lenticular interleave of its views.

A Looking Glass shows many views through a slanted lenticular sheet; each subpixel of
its panel shows the view its calibration (``visual.json``, stored on the device) gives
it.  This module reads that calibration (:func:`load_calibration`), computes the view
of every subpixel once (:func:`view_table`) and interleaves a stack of views into the
panel image at the refresh rate (:func:`interleave`, a numba gather).

The convention is that of Looking Glass's own lenticular shader
(``HoloPlayCore/include/HoloPlayShaders.h`` in github.com/Looking-Glass/LookingGlassCoreSDK,
with the uniforms computed from the calibration as HoloPlay.js / the WebXR library do):

    x = (i + 0.5) / screenW,  y = (screenH - j - 0.5) / screenH    (y up, GL's texCoords)
    tilt  = screenH / (screenW * slope),    negated when flipImageX
    pitch = pitch_lpi * screenW / DPI * cos(atan(1 / slope))
    subp  = 1 / (3 * screenW)
    a_k   = (x + k * subp + y * tilt) * pitch - center,   k = 0, 1, 2
    f_k   = a_k - floor(a_k)
    view  = floor(f_k * N)          (N - 1 - that when invView)

for panel column ``i`` and row ``j`` (row 0 at the top).  Red shows ``k = 0``, green
``k = 1``, blue ``k = 2``; ``flipSubp`` swaps red's and blue's (the shader's
``ri``/``bi``).  View 0 is the leftmost camera (the quilt's first tile, our zone 0).
The shader samples the view at the same ``(x, y)``, fitted into the panel with black
bars where the aspects differ (``overscan`` 0); we take the nearest view pixel.
See docs/lookingglass.md for where this differs from the issue's wording.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numba as nb
import numpy as np

from service.base.errors import SettingsError
from service.warmup_job import HERE, Job, Kit

#: The ``--display`` value's prefix: ``lookingglass:CALIBRATION.json``.
DISPLAY_PREFIX = "lookingglass:"
#: Views when the calibration does not say (it stores none): the 5 x 9 quilt of a
#: 2560x1600 Looking Glass.
DEFAULT_VIEWS = 45
#: The calibration's numeric fields -> (least, most) accepted.
_FIELDS: dict[str, tuple[float, float]] = {
    "pitch": (1e-3, 1e4), "slope": (-1e4, 1e4), "center": (-1e4, 1e4),
    "viewCone": (0.0, 180.0), "invView": (0.0, 1.0), "DPI": (1.0, 1e5),
    "screenW": (1.0, 16384.0), "screenH": (1.0, 16384.0),
    "flipImageX": (0.0, 1.0), "flipSubp": (0.0, 1.0),
}
#: Fields a calibration may lack -> the value then.
_OPTIONAL = {"flipImageX": 0.0, "flipSubp": 0.0, "invView": 0.0}
#: Rows of the view table computed at once (bounds the float64 scratch to ~24 MB).
_ROWS_AT_ONCE = 256


@dataclass(frozen=True)
class Calibration:
    """A Looking Glass display calibration (the fields of its ``visual.json``).

    Attributes
    ----------
    pitch : float
        Lenticules per inch along the panel's width.
    slope : float
        The lenticules' slant (panel pixels down per pixel across); not 0.
    center : float
        Phase of the lenticular pattern at the panel's bottom-left corner.
    view_cone : float
        Degrees across which the views spread.
    inv_view, flip_image_x, flip_subp : bool
    dpi : float
    screen_w, screen_h : int
        Panel pixels.
    views : int
        Views to interleave (the calibration does not store it; :data:`DEFAULT_VIEWS`).
    """

    pitch: float
    slope: float
    center: float
    view_cone: float
    inv_view: bool
    dpi: float
    screen_w: int
    screen_h: int
    flip_image_x: bool = False
    flip_subp: bool = False
    views: int = DEFAULT_VIEWS

    def __post_init__(self) -> None:
        if self.slope == 0:
            raise SettingsError("slope is 0: the lenticules cannot be vertical in this model")
        if not 1 <= self.views <= 255:
            raise SettingsError(f"views must be 1 to 255, got {self.views}")

    @property
    def lens_pitch(self) -> float:
        """Lenticules across the panel, measured horizontally (the shader's ``pitch``)."""
        return self.pitch * self.screen_w / self.dpi * math.cos(math.atan(1.0 / self.slope))

    @property
    def tilt(self) -> float:
        """The shader's ``tilt``: phase shift per panel height, in panel widths."""
        t = self.screen_h / (self.screen_w * self.slope)
        return -t if self.flip_image_x else t

    @property
    def subp(self) -> float:
        """One subpixel in panel widths (the shader's ``subp``)."""
        return 1.0 / (3.0 * self.screen_w)


def calibration_from_dict(data: object, views: int = DEFAULT_VIEWS) -> Calibration:
    """A :class:`Calibration` from a parsed ``visual.json``.

    Each field is ``{"value": number}`` (a bare number is accepted too).

    Raises
    ------
    SettingsError
        One line naming the first missing, non-numeric or out-of-range field.
    """
    if not isinstance(data, dict):
        raise SettingsError("not a calibration: want a JSON object of {\"value\": n} fields")
    got: dict[str, float] = {}
    for name, (lo, hi) in _FIELDS.items():
        item = data.get(name, {"value": _OPTIONAL[name]} if name in _OPTIONAL else None)
        value = item.get("value") if isinstance(item, dict) else item
        if value is None:
            raise SettingsError(f"calibration has no {name}")
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise SettingsError(f"calibration {name} is {value!r}, not a number")
        if not (math.isfinite(value) and lo <= value <= hi):
            raise SettingsError(f"calibration {name} is {value}, want {lo:g} to {hi:g}")
        got[name] = float(value)
    for name in ("screenW", "screenH"):
        if got[name] != int(got[name]):
            raise SettingsError(f"calibration {name} is {got[name]}, not a whole number")
    return Calibration(
        pitch=got["pitch"], slope=got["slope"], center=got["center"],
        view_cone=got["viewCone"], inv_view=got["invView"] >= 0.5, dpi=got["DPI"],
        screen_w=int(got["screenW"]), screen_h=int(got["screenH"]),
        flip_image_x=got["flipImageX"] >= 0.5, flip_subp=got["flipSubp"] >= 0.5,
        views=views,
    )


def load_calibration(path: str | Path, views: int = DEFAULT_VIEWS) -> Calibration:
    """Read a ``visual.json`` calibration file.

    Raises
    ------
    SettingsError
        One line, naming the file: unreadable, not JSON, or a bad field.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise SettingsError(f"{path}: cannot read the calibration: {exc.strerror}") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise SettingsError(f"{path}: not a JSON calibration ({exc})".splitlines()[0]) from None
    try:
        return calibration_from_dict(data, views)
    except SettingsError as exc:
        raise SettingsError(f"{path}: {exc}") from None


def parse_display(text: str, views: int = DEFAULT_VIEWS) -> Calibration:
    """The calibration of a ``--display lookingglass:CALIBRATION.json`` value.

    Raises
    ------
    SettingsError
        When ``text`` does not start with ``lookingglass:`` or the file is bad.
    """
    if not text.startswith(DISPLAY_PREFIX) or len(text) == len(DISPLAY_PREFIX):
        raise SettingsError(f"--display {text!r}: want {DISPLAY_PREFIX}CALIBRATION.json")
    return load_calibration(text[len(DISPLAY_PREFIX):], views)


def view_table(cal: Calibration) -> np.ndarray:
    """The view each subpixel of the panel shows.

    Returns
    -------
    ndarray, shape (screen_h, screen_w, 3), uint8
        ``[j, i, c]``: the view (0 .. views - 1) of colour ``c`` (R, G, B) of the panel
        pixel in row ``j`` (0 at the top) and column ``i``; the formula is the module's.
    """
    w, h, n = cal.screen_w, cal.screen_h, cal.views
    x = (np.arange(w, dtype=np.float64) + 0.5) / w
    k = np.array([2, 1, 0] if cal.flip_subp else [0, 1, 2], np.float64)
    xk = x[:, None] + k[None, :] * cal.subp  # (W, 3)
    out = np.empty((h, w, 3), np.uint8)
    for j0 in range(0, h, _ROWS_AT_ONCE):
        j = np.arange(j0, min(j0 + _ROWS_AT_ONCE, h), dtype=np.float64)
        y = (h - j - 0.5) / h
        a = (xk[None, :, :] + (y * cal.tilt)[:, None, None]) * cal.lens_pitch - cal.center
        v = np.minimum(np.floor((a - np.floor(a)) * n), n - 1)
        out[j0:j0 + j.size] = (n - 1 - v) if cal.inv_view else v
    return out


def sample_maps(cal: Calibration, view_cols: int, view_rows: int) -> tuple[np.ndarray, ...]:
    """Which view pixel each panel row and column shows (nearest), -1 for a black bar.

    The view image is fitted into the panel keeping its aspect (the shader's
    ``overscan`` 0): black bars left and right of a narrower view, above and below a
    wider one.

    Returns
    -------
    rows : ndarray, shape (screen_h,), int32
    cols : ndarray, shape (screen_w,), int32
    """
    w, h = cal.screen_w, cal.screen_h
    display_aspect, view_aspect = w / h, view_cols / view_rows
    sx = display_aspect / view_aspect if display_aspect >= view_aspect else 1.0
    sy = 1.0 if display_aspect >= view_aspect else view_aspect / display_aspect
    u = ((np.arange(w) + 0.5) / w - 0.5) * sx + 0.5
    v = ((np.arange(h) + 0.5) / h - 0.5) * sy + 0.5  # from the top
    cols = np.floor(u * view_cols).astype(np.int64)
    rows = np.floor(v * view_rows).astype(np.int64)
    cols[(cols < 0) | (cols >= view_cols)] = -1
    rows[(rows < 0) | (rows >= view_rows)] = -1
    return rows.astype(np.int32), cols.astype(np.int32)


@nb.njit(cache=True, nogil=True, parallel=True)
def _gather(views: np.ndarray, table: np.ndarray, rows: np.ndarray, cols: np.ndarray,
            out: np.ndarray) -> None:  # pragma: no cover - numba
    h, w = table.shape[0], table.shape[1]
    for j in nb.prange(h):
        r = rows[j]
        for i in range(w):
            c = cols[i]
            if r < 0 or c < 0:
                out[j, i, 0] = 0
                out[j, i, 1] = 0
                out[j, i, 2] = 0
            else:
                out[j, i, 0] = views[table[j, i, 0], r, c, 0]
                out[j, i, 1] = views[table[j, i, 1], r, c, 1]
                out[j, i, 2] = views[table[j, i, 2], r, c, 2]


class Interleaver:
    """Interleaves stacks of views for one calibration (its tables made once).

    Parameters
    ----------
    cal : Calibration
    """

    def __init__(self, cal: Calibration) -> None:
        self.cal = cal
        self.table = view_table(cal)
        self._maps: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}

    @property
    def shape(self) -> tuple[int, int, int]:
        """The panel image's shape, (screen_h, screen_w, 3)."""
        return self.table.shape

    def __call__(self, views: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """The panel image of ``views``: each subpixel gathered from its view.

        Parameters
        ----------
        views : ndarray, shape (N, R, C, 3), uint8
            View 0 (leftmost camera) first; ``N`` the calibration's view count.
        out : ndarray, shape (screen_h, screen_w, 3), uint8, C order, optional
            Written in place when given.

        Returns
        -------
        ndarray, shape (screen_h, screen_w, 3), uint8

        Raises
        ------
        SettingsError
            When the stack's view count, shape or ``out`` does not fit.
        """
        views = np.asarray(views)
        if views.ndim != 4 or views.shape[3] != 3 or views.dtype != np.uint8:
            raise SettingsError(
                f"views must be (N, R, C, 3) uint8, got {views.shape} {views.dtype}")
        if views.shape[0] != self.cal.views:
            raise SettingsError(
                f"the calibration interleaves {self.cal.views} views, got {views.shape[0]}")
        if out is None:
            out = np.empty(self.shape, np.uint8)
        elif out.shape != self.shape or out.dtype != np.uint8 or not out.flags.c_contiguous:
            raise SettingsError(f"out must be {self.shape} uint8 in C order, got {out.shape}")
        key = (int(views.shape[2]), int(views.shape[1]))
        if key not in self._maps:
            self._maps[key] = sample_maps(self.cal, *key)
        rows, cols = self._maps[key]
        _gather(np.ascontiguousarray(views), self.table, rows, cols, out)
        return out


def _warm_interleave(kit: Kit) -> None:
    """The interleave kernel on a 3-view quilt (holo-render, ``--display lookingglass:``)."""
    cal = Calibration(pitch=50.0, slope=5.5, center=0.1, view_cone=40.0, inv_view=True,
                      dpi=300.0, screen_w=16, screen_h=10, views=3)
    Interleaver(cal)(np.zeros((3, 5, 8, 3), np.uint8))


#: This module's warm-up jobs (:data:`service.warmup.JOBS` gathers them).
WARMUP_JOBS: dict[str, Job] = {"looking glass interleave": Job(_warm_interleave, HERE)}
