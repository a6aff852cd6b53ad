"""The seed's hardware SIRD variant on the CPU: floating-point offsets, interpolated samples.

The seed's shader reads the repetition to the right at a floating-point coordinate
and lets texture interpolation blend the two nearest pixels.  Here, per row, right
to left, with the unrounded separation ``sf(x) = separation_f(z(x))`` held in
fixed point (1/256 pixel) and ``p = x + sf(x)``::

    out[x] = ((256 - f) out[floor(p)] + f out[floor(p) + 1] + 128) / 256,
    f = 256 (p - floor(p))

and where ``floor(p) + 1`` falls off the row (the right-most repetition) the
pattern is sampled the same way at ``u = p * Wp / (E / 2)`` (mod ``Wp``), so the
background repeats every ``E / 2`` pixels.  There is no one-pixel layering: a
gentle slope moves the samples a fraction of a pixel per pixel instead of a whole
pixel every few pixels, so the duplicates ``row`` leaves (runs of one colour)
mostly vanish.  The costs: every fractional copy blurs a little, and where ``sf``
grows by exactly one pixel per pixel ``p`` still stands still (the seed: "they
still do exist under extreme circumstances").
"""

from __future__ import annotations

import numba as nb
import numpy as np

#: Fixed-point fraction bits of separations and blend weights.
FRAC_BITS = 8


@nb.njit(cache=True, parallel=True, nogil=True)
def fixed_separation_rows(depth: np.ndarray, far: float, inv_range: float, eye_sep: float,
                          mu: float, fsep: np.ndarray, counts: np.ndarray) -> None:
    """Unrounded ``s(z)`` in 1/256 pixel of every pixel into ``fsep`` (H, W) int32.

    NaN depths count into ``counts[:, 2]`` (their ``z`` is 0); ``counts[:, :2]`` are zeroed.
    """
    h, w = depth.shape
    e = np.float32(eye_sep * 256.0)
    m = np.float32(mu)
    f = np.float32(far)
    k = np.float32(inv_range)
    for y in nb.prange(h):
        drow = depth[y]
        srow = fsep[y]
        bad = 0
        for x in range(w):
            d = drow[x]
            bad += d != d
            z = (f - d) * k
            z = z if z > np.float32(0.0) else np.float32(0.0)
            t = m * (z if z < np.float32(1.0) else np.float32(1.0))
            srow[x] = np.int32((np.float32(1.0) - t) * e / (np.float32(2.0) - t) + np.float32(0.5))
        counts[y, 0] = 0
        counts[y, 1] = 0
        counts[y, 2] = bad


@nb.njit(cache=True)
def _blend_chain(o: np.ndarray, frow: np.ndarray, start: int, nc: int, unroll: bool) -> None:
    """Blend ``o[x]`` from ``o`` at ``x + frow[x] / 256``, x = start down to 0.

    ``unroll`` (grey only) does two pixels at once: it needs every separation >= 2.
    """
    x = start
    if nc == 1 and unroll:
        while x >= 1:
            p0 = (x << 8) + frow[x]
            p1 = ((x - 1) << 8) + frow[x - 1]
            i0 = p0 >> 8
            i1 = p1 >> 8
            f0 = p0 & 255
            f1 = p1 & 255
            v0 = (np.int32(o[i0]) * (256 - f0) + np.int32(o[i0 + 1]) * f0 + 128) >> 8
            v1 = (np.int32(o[i1]) * (256 - f1) + np.int32(o[i1 + 1]) * f1 + 128) >> 8
            o[x] = v0
            o[x - 1] = v1
            x -= 2
    while x >= 0:
        p = (x << 8) + frow[x]
        i = (p >> 8) * nc
        f = p & 255
        for c in range(nc):
            o[x * nc + c] = (np.int32(o[i + c]) * (256 - f)
                             + np.int32(o[i + nc + c]) * f + 128) >> 8
        x -= 1


@nb.njit(cache=True, parallel=True, nogil=True)
def interpolated_kernel(depth: np.ndarray, far: float, inv_range: float, eye_sep: float,
                        mu: float, pattern: np.ndarray, out: np.ndarray, fsep: np.ndarray,
                        counts: np.ndarray) -> None:
    """Draw a SIRD with floating-point offsets and linear interpolation, rows in parallel.

    Parameters
    ----------
    depth : ndarray, shape (H, W), float32
    far, inv_range, eye_sep, mu : float
        As :func:`service.autostereogram.row.row_kernel`.
    pattern : ndarray, shape (Hp, Wp, C), uint8
    out : ndarray, shape (H, W * C), uint8
        Written.
    fsep : ndarray, shape (H, W), int32
        Scratch: separation per pixel in 1/256 pixel.
    counts : ndarray, shape (H, 3), int64
        Written per row: constraints (blended copies), hidden (0), NaN depths.
    """
    h, w = depth.shape
    ph, pw, nc = pattern.shape
    fixed_separation_rows(depth, far, inv_range, eye_sep, mu, fsep, counts)
    scale = pw / (eye_sep / 2.0) / 256.0
    unroll = (1.0 - mu) * eye_sep / (2.0 - mu) >= 2.0
    x0 = min(w - 1, w - 3 - int(np.ceil(eye_sep / 2.0)))  # from here down, p + 1 < w
    for y in nb.prange(h):
        frow = fsep[y]
        prow = pattern[y % ph]
        o = out[y]
        ncons = x0 + 1
        for x in range(w - 1, x0, -1):
            p = (x << 8) + frow[x]
            if (p >> 8) + 1 < w:
                ncons += 1
                i = (p >> 8) * nc
                f = p & 255
                for c in range(nc):
                    o[x * nc + c] = (np.int32(o[i + c]) * (256 - f)
                                     + np.int32(o[i + nc + c]) * f + 128) >> 8
                continue
            u = p * scale
            u -= pw * np.floor(u / pw)  # u mod Wp in floating point: no integer division
            a = min(int(u), pw - 1)
            fu = int((u - a) * 256.0 + 0.5)
            b = a + 1 if a + 1 < pw else 0
            for c in range(nc):
                o[x * nc + c] = (np.int32(prow[a, c]) * (256 - fu) + np.int32(prow[b, c]) * fu
                                 + 128) >> 8
        _blend_chain(o, frow, x0, nc, unroll)
        counts[y, 0] = ncons
