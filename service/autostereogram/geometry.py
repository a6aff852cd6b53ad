"""One geometry for every autostereogram method (Thimbleby, Inglis and Witten 1994).

Depth to z
----------
A depth map as ``holo-render`` writes it holds, per pixel, the distance behind the
display plane (float, ``+inf`` where nothing was drawn).  It becomes a height
``z`` in [0, 1]::

    z = clip((far - depth) / (far - near), 0, 1)

so ``z = 1`` is the near plane, ``z = 0`` the far plane, and ``+inf`` gives 0.

Separation
----------
A point at height ``z`` is drawn as two equal pixels ``s(z)`` pixels apart::

    s(z) = floor((1 - mu z) E / (2 - mu z) + 0.5)

``E`` is the eye separation in pixels (:func:`default_eye_sep`: 2.5 inches at the
display's DPI), ``mu`` the depth of field (default 1/3): the near plane lies
``mu`` of the way from the far plane to the eyes, the image plane halfway between
the eyes and the far plane.  ``s(0) = E / 2`` is the largest separation, ``s(1)``
the smallest; ``s`` falls as ``z`` rises.  Eyes stop fusing when ``mu > 1/2`` or
``s(0) > width / 2``: :class:`SirdSettings` refuses both.

The ``row`` method (the seed's) speaks of ``RandW = s(0)`` and the shift
``h(x) = s(0) - s(z(x))``; ``interpolated`` uses the unrounded separation
:func:`separation_f`.  See ``docs/autostereogram.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from service.base.errors import SettingsError

#: Eye separation in inches (TIW's 2.5 in).
EYE_SEP_INCHES = 2.5


def default_eye_sep(width: int, dpi: float = 72.0) -> float:
    """Default eye separation in pixels: 2.5 inches at ``dpi``, at most ``width / 3``.

    The cap keeps at least three repetitions across a small window (the service's
    160x120 default), where 2.5 inches would not fuse.  Rounded down to an even
    number of pixels, so the far plane's separation ``E / 2`` is whole and
    ``interpolated`` copies the background without blending it.
    """
    return float(max(4, 2 * math.floor(min(EYE_SEP_INCHES * dpi, width / 3.0) / 2)))


@dataclass(frozen=True)
class SirdSettings:
    """Settings of the autostereogram stage.

    Attributes
    ----------
    method : {"row", "interpolated", "tiw"}
        Algorithm (:data:`service.autostereogram.stage.METHODS`).
    eye_sep : float
        Eye separation ``E`` in pixels, > 2.
    mu : float
        Depth of field, in (0, 1/2].
    near, far : float
        Depth (distance behind the display plane) of the near and far planes; ``near < far``.
    """

    method: str = "tiw"
    eye_sep: float = 180.0
    mu: float = 1.0 / 3.0
    near: float = 0.0
    far: float = 1.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.eye_sep) and self.eye_sep > 2.0):
            raise SettingsError(f"eye separation must be > 2 pixels, got {self.eye_sep}")
        if not (math.isfinite(self.mu) and 0.0 < self.mu <= 0.5):
            raise SettingsError(
                f"depth of field mu must be in (0, 0.5]; eyes do not fuse beyond 1/2, got {self.mu}"
            )
        if not (math.isfinite(self.near) and math.isfinite(self.far) and self.near < self.far):
            raise SettingsError(f"need finite near < far, got near={self.near}, far={self.far}")
        if separation(1.0, self.eye_sep, self.mu) < 1:
            raise SettingsError(f"eye separation {self.eye_sep} px is too small for mu={self.mu}")

    @property
    def max_sep(self) -> int:
        """``s(0)``, the far plane's separation (the seed's ``RandW``)."""
        return separation(0.0, self.eye_sep, self.mu)

    @property
    def min_sep(self) -> int:
        """``s(1)``, the near plane's separation."""
        return separation(1.0, self.eye_sep, self.mu)

    def check_width(self, width: int) -> None:
        """Raise :class:`SettingsError` unless an image ``width`` pixels wide can be fused."""
        if width < 1:
            raise SettingsError(f"image is empty (width {width})")
        if self.max_sep > width / 2:
            raise SettingsError(
                f"separation s(0)={self.max_sep} px is more than half the width ({width} px):"
                " eyes cannot fuse it; lower --eye-sep"
            )


@nb.njit(cache=True)
def separation(z: float, eye_sep: float, mu: float) -> int:
    """``s(z)`` in whole pixels (rounded half up), for a scalar ``z`` in [0, 1]."""
    t = mu * z
    return int(math.floor((1.0 - t) * eye_sep / (2.0 - t) + 0.5))


@nb.njit(cache=True)
def separation_f(z: float, eye_sep: float, mu: float) -> float:
    """``s(z)`` unrounded, in pixels."""
    t = mu * z
    return (1.0 - t) * eye_sep / (2.0 - t)


@nb.njit(cache=True)
def height(depth: float, far: float, inv_range: float) -> float:
    """``z`` of one depth value (``inv_range = 1 / (far - near)``); NaN gives 0.

    NaN must never reach a separation (it would index outside the row): kernels count
    NaN depths and the stage raises after the kernel.
    """
    z = (far - depth) * inv_range
    if not z > 0.0:
        return 0.0
    if z > 1.0:
        return 1.0
    return z


def depth_to_z(depth: np.ndarray, near: float, far: float) -> np.ndarray:
    """Heights ``z`` in [0, 1] of a depth map.

    Parameters
    ----------
    depth : ndarray, shape (H, W), float
        Distance behind the display plane, ``+inf`` where empty.
    near, far : float
        Depth of the near (z = 1) and far (z = 0) planes.

    Returns
    -------
    ndarray, shape (H, W), float32
    """
    with np.errstate(invalid="ignore"):
        z = (far - np.asarray(depth, np.float64)) / (far - near)
    return np.clip(z, 0.0, 1.0).astype(np.float32)


def separation_map(depth: np.ndarray, settings: SirdSettings) -> np.ndarray:
    """Expected separation ``s(z)`` of every pixel, shape (H, W) int32 (the kernels' own)."""
    d = np.ascontiguousarray(depth, np.float32)
    sep = np.empty(d.shape, np.int32)
    counts = np.zeros((d.shape[0], 3), np.int64)
    separation_rows(d, settings.far, 1.0 / (settings.far - settings.near), settings.eye_sep,
                    settings.mu, sep, counts)
    return sep


def finite_range(depth: np.ndarray) -> tuple[float, float]:
    """(near, far) = the finite depth range of a map, for ``--near/--far`` defaults.

    Raises :class:`SettingsError` when the map holds NaN or nothing finite; a flat map
    (one depth) gets ``far = near + 1``.
    """
    d = np.asarray(depth, np.float64)
    if d.size == 0:
        raise SettingsError("depth map is empty (0 pixels)")
    if np.isnan(d).any():
        raise SettingsError("depth map holds NaN")
    fin = d[np.isfinite(d)]
    if fin.size == 0:
        raise SettingsError("depth map is all empty (+inf): nothing to show")
    lo, hi = float(fin.min()), float(fin.max())
    return (lo, hi) if hi > lo else (lo, lo + 1.0)


@nb.njit(cache=True, parallel=True, nogil=True)
def separation_rows(depth: np.ndarray, far: float, inv_range: float, eye_sep: float,
                    mu: float, sep: np.ndarray, counts: np.ndarray) -> int:
    """``s(z)`` of every pixel into ``sep`` (H, W) int32; NaN counts into ``counts[:, 2]``.

    A pass with no loop-carried dependence, so it vectorises (float32 arithmetic,
    rounding half up by truncation of ``s + 0.5 > 0``).  Writes ``counts[:, 0]``: the
    row's pixels above the far plane (``z > 0``), ``counts[:, 1] = 0``.  Returns ``s(0)``.
    """
    h, w = depth.shape
    e = np.float32(eye_sep)
    m = np.float32(mu)
    f = np.float32(far)
    k = np.float32(inv_range)
    for y in nb.prange(h):
        drow = depth[y]
        srow = sep[y]
        bad = 0
        above = 0
        for x in range(w):
            d = drow[x]
            bad += d != d
            z = (f - d) * k
            z = z if z > np.float32(0.0) else np.float32(0.0)  # NaN and -inf -> 0
            above += z > np.float32(0.0)
            t = m * (z if z < np.float32(1.0) else np.float32(1.0))
            srow[x] = np.int32((np.float32(1.0) - t) * e / (np.float32(2.0) - t) + np.float32(0.5))
        counts[y, 0] = above
        counts[y, 1] = 0
        counts[y, 2] = bad
    return separation(0.0, eye_sep, mu)
