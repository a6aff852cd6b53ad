"""The seed's hardware SIRD variant on the CPU: floating-point offsets, interpolated samples.

The seed's shader reads the repetition to the right at a floating-point coordinate
and lets texture interpolation blend the two nearest pixels.  Here, per row, with the
unrounded separation ``sf(x) = separation_f(z(x))`` held in fixed point (1/256
pixel), every point ``x`` of the surface makes one **symmetric** constraint, as in
Thimbleby, Inglis and Witten (TIW), but with a floating-point partner::

    L = round(x - sf(x) / 2)       the left pixel
    R = L + sf(x)                  its partner, a floating-point coordinate
    out[L] = ((256 - f) out[floor(R)] + f out[floor(R) + 1] + 128) / 256,
    f = 256 (R - floor(R))

filled right to left.  Where two points name one left pixel the nearer (smaller
``sf``) keeps it; a pixel no point names is *free* and takes the pattern at a
stable coordinate, ``pattern[y mod Hp, L mod Wp]`` (TIW's free pixels); where
``floor(R) + 1`` falls off the row (the right-most repetition) the pattern is
sampled the same way at ``u = R * Wp / (E / 2)`` (mod ``Wp``), so the background
repeats every ``E / 2`` pixels.  There is no one-pixel layering: a gentle slope
moves the samples a fraction of a pixel per pixel.

Why symmetric.  The seed reads the separation at the left pixel, ``R = x + sf(x)``:
on a slope where ``sf`` shrinks by ``g`` pixels per pixel, ``R`` moves ``1 - g`` per
pixel and stands still at ``g = 1``, the seed's own streak case ("they still do
exist under extreme circumstances"); and every repetition to the left copies the
stretched blend again, so the blur compounds.  With the pair centred on its point,
left pixels move ``1 + g / 2`` per point and partners ``1 - g / 2``: on such a slope
every left pixel the points skip is free and gets a fresh dot, so no run of one
colour survives, and ``R`` never stands still before ``g = 2``, past what either
eye sees.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from service.numba_subroutine import subroutine

#: Fixed-point fraction bits of separations and blend weights.
FRAC_BITS = 8


@nb.njit(cache=True, inline="always")
def fixed_separation_row(drow: np.ndarray, far: float, inv_range: float, eye_sep: float,
                         mu: float, frow: np.ndarray) -> int:
    """Unrounded ``s(z)`` in 1/256 pixel of one row into ``frow``; returns its NaN count.

    No loop-carried dependence (inlined in the parallel loop's body, it vectorises).
    """
    e = np.float32(eye_sep * 256.0)
    m = np.float32(mu)
    f = np.float32(far)
    k = np.float32(inv_range)
    bad = 0
    for x in range(drow.shape[0]):
        d = drow[x]
        bad += d != d
        z = (f - d) * k
        z = z if z > np.float32(0.0) else np.float32(0.0)
        t = m * (z if z < np.float32(1.0) else np.float32(1.0))
        frow[x] = np.int32((np.float32(1.0) - t) * e / (np.float32(2.0) - t) + np.float32(0.5))
    return bad


@nb.njit(cache=True, parallel=True)
def fixed_separation_map(depth: np.ndarray, far: float, inv_range: float, eye_sep: float,
                         mu: float, fsep: np.ndarray) -> None:
    """Every row's :func:`fixed_separation_row` into ``fsep`` (H, W) int32 (tests, tools)."""
    for y in nb.prange(depth.shape[0]):
        fixed_separation_row(depth[y], far, inv_range, eye_sep, mu, fsep[y])


#: A left pixel no point names (its partner slot).
FREE = np.int32(2**31 - 1)


@subroutine(nrt=True)
def _pattern_sample(o: np.ndarray, x: int, r: int, prow: np.ndarray, nc: int,
                    scale: float, base: float) -> None:
    """``o[x]`` = the pattern blended at ``u = r * scale`` (mod Wp): the right-most repetition.

    ``base``, a multiple of Wp a little below every ``u`` of the row's right end,
    replaces a division per pixel by a subtraction or two.
    """
    pw = prow.shape[0]
    u = r * scale - base
    while u >= pw:
        u -= pw
    while u < 0.0:
        u += pw
    a = min(int(u), pw - 1)
    fu = int((u - a) * 256.0 + 0.5)
    b = a + 1 if a + 1 < pw else 0
    for c in range(nc):
        o[x * nc + c] = (np.int32(prow[a, c]) * (256 - fu) + np.int32(prow[b, c]) * fu
                         + 128) >> 8


@subroutine(nrt=True)
def _row(o: np.ndarray, frow: np.ndarray, part: np.ndarray, prow: np.ndarray, nc: int,
         scale: float) -> int:
    """One row, right to left; returns the constraints kept (blends inside the row).

    At each ``x`` the point ``x`` hands its left pixel ``L = round(x - sf / 2) < x`` the
    partner ``L * 256 + sf`` (the smaller where two points meet), then pixel ``x`` is
    filled: every point that names ``x`` lies to its right, so it is done.  A slot
    no point named stays :data:`FREE`, whose ``>> 8`` is past the row, so one test
    picks the blends; blends are ``a + ((b - a) f + 128) / 256`` (one multiply, the
    same rounding as ``((256 - f) a + f b + 128) / 256``).
    """
    w = part.shape[0]
    pw = prow.shape[0]
    for x in range(w):
        part[x] = FREE
    u0 = (w - 1) % pw  # x mod Wp, stepped down with x
    base = pw * np.floor((w - 1) * 256 * scale / pw)
    n = 0
    if nc == 1:  # grey: one byte a pixel, the loop LLVM can keep tight
        for x in range(w - 1, -1, -1):
            sx = frow[x]
            left = ((x << 8) - (sx >> 1) + 128) >> 8
            if left >= 0:
                part[left] = min(part[left], (left << 8) + sx)
            r = part[x]
            i = r >> 8
            if i + 1 < w:
                n += 1
                a = np.int32(o[i])
                o[x] = a + (((np.int32(o[i + 1]) - a) * (r & 255) + 128) >> 8)
            elif r == FREE:
                o[x] = prow[u0, 0]
            else:
                _pattern_sample(o, x, r, prow, nc, scale, base)  # nc == 1: one signature
            u0 = u0 - 1 if u0 > 0 else pw - 1
        return n
    for x in range(w - 1, -1, -1):
        sx = frow[x]
        left = ((x << 8) - (sx >> 1) + 128) >> 8
        if left >= 0:
            part[left] = min(part[left], (left << 8) + sx)
        r = part[x]
        i = r >> 8
        if i + 1 < w:
            n += 1
            f = r & 255
            for c in range(nc):
                a = np.int32(o[i * nc + c])
                o[x * nc + c] = a + (((np.int32(o[(i + 1) * nc + c]) - a) * f + 128) >> 8)
        elif r == FREE:
            for c in range(nc):
                o[x * nc + c] = prow[u0, c]
        else:
            _pattern_sample(o, x, r, prow, nc, scale, base)
        u0 = u0 - 1 if u0 > 0 else pw - 1
    return n


@nb.njit(cache=True, parallel=True, nogil=True)
def interpolated_kernel(depth: np.ndarray, far: float, inv_range: float, eye_sep: float,
                        mu: float, pattern: np.ndarray, out: np.ndarray, scratch: np.ndarray,
                        counts: np.ndarray) -> None:
    """Draw a SIRD with symmetric floating-point constraints and linear interpolation.

    Parameters
    ----------
    depth : ndarray, shape (H, W), float32
    far, inv_range, eye_sep, mu : float
        As :func:`service.autostereogram.row.row_kernel`.
    pattern : ndarray, shape (Hp, Wp, C), uint8
    out : ndarray, shape (H, W * C), uint8
        Written.
    scratch : ndarray, shape (threads, >= 2, W), int32
        Per-thread scratch: the row's separations in 1/256 pixel, and each left pixel's
        partner (1/256 pixel) or :data:`FREE`.
    counts : ndarray, shape (H, 3), int64
        Written per row: constraints (blended copies), hidden (0), NaN depths.
    """
    h, w = depth.shape
    ph, pw, nc = pattern.shape
    scale = pw / (eye_sep / 2.0) / 256.0
    for y in nb.prange(h):
        frow = scratch[nb.get_thread_id(), 0]
        counts[y, 2] = fixed_separation_row(depth[y], far, inv_range, eye_sep, mu, frow)
        counts[y, 0] = _row(out[y], frow, scratch[nb.get_thread_id(), 1], pattern[y % ph], nc,
                            scale)
        counts[y, 1] = 0
