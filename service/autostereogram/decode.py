"""Reading a stereogram back: a separation decoder, its accuracy, and streaks.

Decoder
-------
For each pixel and each candidate separation ``s`` in ``[s_lo, s_hi]``, the pair
the method would have linked is compared (``row``/``interpolated``: ``(x, x + s)``,
the ``left`` convention; ``tiw``: ``(l, l + s)`` with ``l = x - (s + (s & y & 1)) / 2``,
the ``centre`` convention); pairs whose channels all differ by at most ``tol`` match.
The decoded separation is the ``s`` with most matches in a ``2 r + 1`` pixel window
along the row (ties: the smaller ``s``); 0 where fewer than ``r + 1`` match.  For
``interpolated`` (``sub = 4``) candidates go in quarter pixels and a pixel is compared
with the linear blend of its partner's two neighbours, the method's own constraint;
the result is rounded to whole pixels.

Accuracy is the fraction of pixels *away from depth edges* whose decoded separation
is within 1 of the expected ``s(z)``: a pixel is near an edge when the expected
separation jumps by more than 1 between neighbours anywhere within ``s_hi + r + 1``
pixels along its row, or when its pair window would leave the row.

Streaks
-------
:func:`streak_fraction`: the fraction of pixels in horizontal runs of at least
``min_run`` (default 3) pixels of one colour (every channel equal).  Random dots
make such runs by chance about ``2 / 256^2`` of the time for grey.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from service.autostereogram.geometry import SirdSettings, separation_map

#: Pair conventions: name -> code in the kernel.
CONVENTIONS: dict[str, int] = {"left": 0, "centre": 1}

#: The convention each method links pixels by.
METHOD_CONVENTION: dict[str, str] = {"row": "left", "interpolated": "left", "tiw": "centre"}
#: Decoder settings per method: (tolerance in grey levels, candidates per pixel).
METHOD_DECODE: dict[str, tuple[int, int]] = {"row": (0, 1), "interpolated": (2, 4), "tiw": (0, 1)}


def expected_separation(depth: np.ndarray, settings: SirdSettings) -> np.ndarray:
    """The separation each pixel's pair should decode to, shape (H, W) int32.

    ``row`` and ``tiw``: :func:`~service.autostereogram.geometry.separation_map` (``row``
    indexes a pair by its left pixel and reads the depth there; ``tiw``'s decoder
    indexes pairs by their centre).  ``interpolated`` indexes a pair by its left pixel
    ``L`` but takes the separation of the point at its centre: ``s(L + s(L) / 2)``.
    """
    sep = separation_map(depth, settings)
    if settings.method != "interpolated":
        return sep
    cols = np.minimum(np.arange(sep.shape[1]) + sep // 2, sep.shape[1] - 1)
    return np.take_along_axis(sep, cols, axis=1)


@nb.njit(cache=True)
def _pair_left(x: int, s: int, y: int, centre: int) -> int:
    if centre:
        return x - (s + (s & y & 1)) // 2
    return x


@nb.njit(cache=True)
def _match(img: np.ndarray, y: int, x: int, j: int, sub: int, centre: int, tol: int) -> int:
    """1 if pixel pair ``j / sub`` apart (the convention's) match within ``tol``, else 0."""
    w = img.shape[1]
    nc = img.shape[2]
    if sub == 1:
        a = _pair_left(x, j, y, centre)
        b = a + j
        if a < 0 or b >= w:
            return 0
        for c in range(nc):
            if abs(int(img[y, a, c]) - int(img[y, b, c])) > tol:
                return 0
        return 1
    p = x * sub + j  # blended partner at x + j / sub
    i = p // sub
    f = p - i * sub
    if i + 1 >= w:
        return 0
    for c in range(nc):
        v = (int(img[y, i, c]) * (sub - f) + int(img[y, i + 1, c]) * f) / sub
        if abs(v - int(img[y, x, c])) > tol + 0.5:
            return 0
    return 1


@nb.njit(cache=True, parallel=True)
def _decode_kernel(img: np.ndarray, s_lo: int, s_hi: int, sub: int, centre: int, r: int,
                   tol: int, out: np.ndarray) -> None:
    h, w, nc = img.shape
    for yp in nb.prange(h):
        y = np.int64(yp)  # one signature for _match (prange types its index twice)
        best = np.zeros(w, np.int32)
        match = np.zeros(w, np.int32)
        orow = out[y]
        orow[:] = 0
        for j in range(s_lo * sub, s_hi * sub + 1):
            for x in range(w):
                match[x] = _match(img, y, x, j, sub, centre, tol)
            acc = 0
            for x in range(min(r, w)):
                acc += match[x]
            for x in range(w):
                if x + r < w:
                    acc += match[x + r]
                if x - r - 1 >= 0:
                    acc -= match[x - r - 1]
                if acc > best[x] and acc >= r + 1:
                    best[x] = acc
                    orow[x] = (j + sub // 2) // sub


def decode(image: np.ndarray, s_lo: int, s_hi: int, *, convention: str = "left",
           radius: int = 3, tol: int = 0, sub: int = 1) -> np.ndarray:
    """Decoded separation per pixel.

    Parameters
    ----------
    image : ndarray, shape (H, W, C) or (H, W), uint8
    s_lo, s_hi : int
        Candidate separations (inclusive), e.g. ``s(1) - 2`` to ``s(0) + 2``.
    convention : {"left", "centre"}
        Which pixel pair a separation names (see the module notes).
    radius : int
        Half-width of the matching window.
    tol : int
        Largest channel difference that still matches (0 for copies).
    sub : int
        Candidate separations per pixel (``left`` only): with ``sub > 1`` a pixel is
        compared with the linear blend of its two neighbours at ``x + j / sub``, the
        ``interpolated`` method's own constraint.

    Returns
    -------
    ndarray, shape (H, W), int32
        Decoded separation, 0 where nothing matched.
    """
    img = np.asarray(image)
    if img.ndim == 2:
        img = img[:, :, None]
    out = np.zeros(img.shape[:2], np.int32)
    if sub > 1 and convention != "left":
        raise ValueError("sub-pixel decoding is for the left convention")
    _decode_kernel(np.ascontiguousarray(img), int(max(1, s_lo)), int(s_hi), int(sub),
                   CONVENTIONS[convention], int(radius), int(tol), out)
    return out


def edge_free(expected: np.ndarray, reach: int, convention: str = "left") -> np.ndarray:
    """Pixels whose pair window stays in the row and away from depth edges; (H, W) bool.

    Parameters
    ----------
    expected : ndarray, shape (H, W), int
        Expected separation per pixel.
    reach : int
        Half-width to keep clear of edges (``s_hi + radius + 1``).
    convention : {"left", "centre"}
    """
    h, w = expected.shape
    jump = np.zeros((h, w), bool)
    jump[:, 1:] = np.abs(np.diff(expected.astype(np.int64), axis=1)) > 1
    csum = np.concatenate([np.zeros((h, 1), np.int64), np.cumsum(jump, axis=1)], axis=1)
    cols = np.arange(w)
    lo = np.clip(cols - reach, 0, w)
    hi = np.clip(cols + reach + 1, 0, w)
    clear = (csum[:, hi] - csum[:, lo]) == 0
    inside = cols + reach < w
    if convention == "centre":
        inside &= cols - reach >= 0
    return clear & inside


def accuracy(decoded: np.ndarray, expected: np.ndarray, mask: np.ndarray) -> float:
    """Fraction of ``mask`` pixels decoded within 1 of ``expected`` (1.0 if ``mask`` is empty)."""
    n = int(mask.sum())
    if n == 0:
        return 1.0
    return float((np.abs(decoded - expected)[mask] <= 1).sum() / n)


@nb.njit(cache=True)
def _streak_count(img: np.ndarray, min_run: int) -> int:
    h, w, nc = img.shape
    total = 0
    for y in range(h):
        run = 1
        for x in range(1, w + 1):
            same = x < w
            if same:
                for c in range(nc):
                    if img[y, x, c] != img[y, x - 1, c]:
                        same = False
                        break
            if same:
                run += 1
            else:
                if run >= min_run:
                    total += run
                run = 1
    return total


def streak_fraction(image: np.ndarray, min_run: int = 3) -> float:
    """Fraction of pixels in horizontal runs of ``min_run`` or more equal colours."""
    img = np.asarray(image)
    if img.ndim == 2:
        img = img[:, :, None]
    if img.size == 0:
        return 0.0
    return _streak_count(np.ascontiguousarray(img), int(min_run)) / (img.shape[0] * img.shape[1])
