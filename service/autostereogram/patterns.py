"""Patterns an autostereogram repeats: seeded random dots (grey or colour) or an image tile.

A pattern is a (Hp, Wp, C) uint8 array, C = 1 (grey) or 3 (colour).  Its width
should be the far plane's separation ``s(0)`` (:attr:`SirdSettings.max_sep`) so the
background repeats seamlessly: :func:`make_pattern` makes it so.  The pattern is
fixed for a run (seeded), never redrawn per frame: every method indexes it by a
stable coordinate, so a pixel whose constraints did not change keeps its colour
from one animation frame to the next.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from service.base.errors import PngError, SettingsError
from service.png import read_png

#: Random pattern names -> channels.
RANDOM_KINDS: dict[str, int] = {"random": 1, "colour": 3}

#: Default pattern height (rows before it repeats vertically).
PATTERN_ROWS = 256


def random_dots(width: int, height: int = PATTERN_ROWS, *, colour: bool = False,
                seed: int = 0) -> np.ndarray:
    """Seeded random dots.

    Parameters
    ----------
    width, height : int
        Pattern size in pixels (width: ``s(0)``).
    colour : bool
        Three independent channels, else one grey channel.
    seed : int
        Seed of ``numpy.random.default_rng``.

    Returns
    -------
    ndarray, shape (height, width, 1 or 3), uint8
    """
    if width < 1 or height < 1:
        raise SettingsError(f"pattern must be at least 1x1, got {width}x{height}")
    rng = np.random.default_rng(seed)
    return rng.integers(0, 256, size=(height, width, 3 if colour else 1), dtype=np.uint8)


def image_tile(image: np.ndarray, width: int) -> np.ndarray:
    """An image resampled (nearest) to ``width`` columns, aspect kept; (Hp, width, C) uint8.

    Grey+alpha and RGBA drop their alpha channel.
    """
    img = np.asarray(image)
    if img.ndim == 2:
        img = img[:, :, None]
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[0] < 1 or img.shape[1] < 1:
        raise SettingsError(f"pattern image must be a non-empty uint8 image, got {img.shape}")
    img = img[:, :, :1] if img.shape[2] in (1, 2) else img[:, :, :3]
    h = max(1, round(img.shape[0] * width / img.shape[1]))
    rows = (np.arange(h) * img.shape[0] // h).clip(0, img.shape[0] - 1)
    cols = (np.arange(width) * img.shape[1] // width).clip(0, img.shape[1] - 1)
    return np.ascontiguousarray(img[rows][:, cols])


def make_pattern(kind: str, width: int, *, seed: int = 0) -> np.ndarray:
    """``random`` (grey dots), ``colour`` (colour dots) or a PNG file's path, ``width`` wide."""
    if kind in RANDOM_KINDS:
        return random_dots(width, colour=RANDOM_KINDS[kind] == 3, seed=seed)
    path = Path(kind)
    if not path.is_file():
        raise SettingsError(
            f"pattern must be one of {sorted(RANDOM_KINDS)} or a PNG file, got {kind!r}"
        )
    try:
        image = read_png(path)
    except PngError as exc:
        raise SettingsError(f"pattern {kind}: {exc}") from None
    return image_tile(image, width)
