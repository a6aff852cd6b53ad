"""Fixed-point layout of galpixel motion (seed 002, section 3.1).

Bit budget
----------
For a display of linear size ``D`` pixels, a rated propagation time ``N_prop``
refreshes and a recognisability time ``N_recog`` refreshes, each of the x and y
components of a galpixel's motion needs (logs base 2, rounded up)

===================  ==================================  ==========================
quantity             bits                                why
===================  ==================================  ==========================
fractional position  ``log2 N_prop``                     a 1/N_prop px/refresh speed
                                                         moves 1 px in N_prop refreshes
fractional velocity  ``2 log2 N_prop - 1``               carries the acceleration's
fractional accel.    ``2 log2 N_prop - 1``               ``a N_prop^2 / 2 = 1 px``
integral velocity    ``log2 D - log2 N_recog + 2``       projectile across D in N_recog
integral accel.      ``log2 D - 2 log2 N_recog + 3``     the same projectile
===================  ==================================  ==========================

so ``N_bits = 2 log2 D + 5 log2 N_prop - 3 log2 N_recog + 3`` (31 for D = 1024,
N_prop = N_recog = 16).  The integral position (``log2 D`` bits) is the galpixel's
place in the pixmap matrix and is not counted.  G(3)'s jerk, which the paper does
not size, gets ``3 log2 N_prop - 2`` fractional bits (``j N_prop^3 / 6 = 1 px``);
a G(3) galpixmap keeps velocity, acceleration and jerk at that precision.

Arithmetic
----------
Positions are integers in units of ``2^-fp`` px, motion in units of ``2^-fm``
(``fp``, ``fm`` the fractional bits).  One refresh (equations 12-13, extended to
the jerk) adds to the position the *exact* step ``v + a/2 + j/6`` rounded half up
to ``fp`` bits (the paper's "add 0.00001000 and truncate"), then ``v += a + j/2``
(rounded half up to ``fm`` bits) and ``a += j``.

A position is shown at the pixel ``floor(x + 1/2)`` (symmetric rounding): the
fraction lives in ``[-1/2, 1/2)``, so a galpixel at 1/16 px/refresh moving right
jumps at refresh 8 and moving left at refresh 9.

Depth
-----
Depth is fixed point too: an int32 in units of ``2^-fz`` depth units (``fz`` =
:data:`Z_FRAC_BITS`, 16: steps of 1.5e-5, depths to +-32767), :data:`Z_EMPTY` for
"nothing there" (+inf in a render).  The paper gives z no fractional bits of its
own (it is not matricised); it asks for enough bits that the finest z motion
propagates over N_prop, and suggests "the same motional structure as x and y".
So z motion carries the same extra ``fm - fp`` fractional bits below the depth's
that x and y motion carry below the position's (units ``2^-(fz + fm - fp)``), and
one refresh advances z with exactly the position's arithmetic and rounding
(:func:`advance` with the same ``fp``, ``fm``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from service.base.errors import SettingsError

#: Fractional bits of depth (units of 2^-16 depth units).
Z_FRAC_BITS = 16
#: Depth of an empty pixel (+inf in a render); never moves (its z motion is 0).
Z_EMPTY = np.int32(2**31 - 1)
#: Largest finite depth magnitude the format holds, in fixed-point units.
Z_LIMIT = 2**31 - 2


def _log2_ceil(n: float, name: str) -> int:
    if not (np.isfinite(n) and n >= 1):
        raise SettingsError(f"{name} must be a finite number >= 1, got {n!r}")
    return int(math.ceil(math.log2(n) - 1e-12))


@dataclass(frozen=True)
class BitBudget:
    """Bits per x or y motion component (section 3.1).

    Attributes
    ----------
    display, n_prop, n_recog : int
        D, N_prop and N_recog the budget was computed for.
    frac_position, frac_velocity, frac_acceleration, frac_jerk : int
    int_position, int_velocity, int_acceleration : int
        ``int_position`` is held by the matrix address, not stored.
    """

    display: int
    n_prop: int
    n_recog: int
    frac_position: int
    frac_velocity: int
    frac_acceleration: int
    frac_jerk: int
    int_position: int
    int_velocity: int
    int_acceleration: int

    @property
    def total(self) -> int:
        """The paper's N_bits: stored bits of one component of a G(2) galpixel."""
        return (self.frac_position + self.frac_velocity + self.frac_acceleration
                + self.int_velocity + self.int_acceleration)


def bit_budget(display: int, n_prop: int = 16, n_recog: int = 16) -> BitBudget:
    """Bits per component for display size D, rated N_prop and recognisability N_recog.

    Parameters
    ----------
    display : int
        Linear display size D in pixels (the larger of width and height).
    n_prop : int
        Rated propagation time in refreshes, >= 4.
    n_recog : int
        Recognisability time in refreshes, >= 1.

    Returns
    -------
    BitBudget

    Raises
    ------
    SettingsError
        For D < 1, N_prop < 4 or N_recog < 1.
    """
    ld = _log2_ceil(display, "display size")
    lp = _log2_ceil(n_prop, "n_prop")
    lr = _log2_ceil(n_recog, "n_recog")
    if n_prop < 4:
        raise SettingsError(f"n_prop must be >= 4 (two fractional position bits), got {n_prop}")
    return BitBudget(
        display=int(display), n_prop=int(n_prop), n_recog=int(n_recog),
        frac_position=lp, frac_velocity=2 * lp - 1, frac_acceleration=2 * lp - 1,
        frac_jerk=3 * lp - 2, int_position=ld,
        int_velocity=ld - lr + 2, int_acceleration=ld - 2 * lr + 3,
    )


@dataclass(frozen=True)
class FixedPoint:
    """The fixed-point format one galpixmap uses.

    Attributes
    ----------
    fp : int
        Fractional bits of position.
    fm : int
        Fractional bits of velocity, acceleration (and jerk for G(3)).
    v_max, a_max, j_max : float
        Largest magnitudes (px per refresh^n) the integral bits hold; larger
        values are clamped and flagged.
    fz : int
        Fractional bits of depth; z motion has ``fz + fm - fp``.
    """

    fp: int
    fm: int
    v_max: float
    a_max: float
    j_max: float
    fz: int = Z_FRAC_BITS

    @classmethod
    def for_order(cls, budget: BitBudget, order: int) -> FixedPoint:
        """The format of a G(``order``) galpixmap under ``budget``."""
        fm = budget.frac_jerk if order == 3 else budget.frac_velocity
        v_max = 2.0 ** budget.int_velocity
        a_max = 2.0 ** max(budget.int_acceleration, 0)
        return cls(budget.frac_position, fm, v_max, a_max, a_max)

    @property
    def shift(self) -> int:
        """``fm - fp``: bits dropped when a motion step becomes a position step."""
        return self.fm - self.fp

    def quantise(
        self, values: np.ndarray, limit: float, where: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Motion values (px per refresh^n) to int32 fixed point, round half up.

        Parameters
        ----------
        values : ndarray, any shape, float
        limit : float
            Magnitude bound; NaN, +-inf and values beyond it are clamped (NaN to 0).
        where : ndarray of bool, optional
            Shaped as the trailing axes of ``values``: where False the value is
            taken as 0 (e.g. pixels with nothing drawn).

        Returns
        -------
        fixed : ndarray, same shape, int32
        bad : ndarray, same shape, bool
            Where a value was non-finite or clamped.
        """
        return _to_fixed(values, 2.0**self.fm, float(limit), True, where)

    def to_float(self, fixed: np.ndarray) -> np.ndarray:
        """Fixed-point motion back to px per refresh^n (float64)."""
        return np.asarray(fixed, np.float64) / 2.0**self.fm

    @property
    def fzm(self) -> int:
        """Fractional bits of z motion: ``fz + fm - fp``."""
        return self.fz + self.fm - self.fp

    def depth_fixed(self, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Depths (depth units) to int32 fixed point, round half up.

        Parameters
        ----------
        depth : ndarray, any shape, float
            +inf and NaN are empty (:data:`Z_EMPTY`); -inf and finite values beyond
            the format are clamped and flagged.

        Returns
        -------
        fixed : ndarray, same shape, int32
        bad : ndarray, same shape, bool
        """
        d = np.asarray(depth)
        if d.dtype.kind != "f":
            d = d.astype(np.float64)
        flat = np.ascontiguousarray(d).reshape(-1)
        out = np.empty(flat.shape, np.int32)
        bad = np.empty(flat.shape, np.bool_)
        _depth_kernel(flat, 2.0**self.fz, out, bad)
        return out.reshape(d.shape), bad.reshape(d.shape)

    def depth_float(self, fixed: np.ndarray) -> np.ndarray:
        """Fixed-point depths back to float32 depth units (+inf where empty)."""
        f = np.asarray(fixed)
        return np.where(f == Z_EMPTY, np.inf, f / 2.0**self.fz).astype(np.float32)

    def zmotion_fixed(
        self, values: np.ndarray, where: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Z motion (depth units per refresh^n) to int32 fixed point, round half up.

        Non-finite values become 0, values beyond the format are clamped; both
        flagged.  ``where`` as in :meth:`quantise`.
        """
        return _to_fixed(values, 2.0**self.fzm, Z_LIMIT / 2.0**self.fzm, False, where)


@nb.njit(cache=True, inline="always", error_model="numpy")
def advance(x: int, v: int, a: int, j: int, order: int, fp: int, fm: int) -> tuple:
    """One refresh of one fixed-point component (equations 12-13 and their G(3) analogue).

    ``x`` is a position in units of ``2^-fp`` px; ``v``, ``a``, ``j`` are in units
    of ``2^-fm`` px/refresh^n.  Returns the new ``(x, v, a)`` (jerk is constant).
    """
    s = fm - fp
    if order == 1:
        x += (v + (1 << (s - 1))) >> s
    elif order == 2:
        x += (2 * v + a + (1 << s)) >> (s + 1)
        v += a
    elif order == 3:
        x += ((6 * v + 3 * a + j + (3 << s)) >> s) // 6  # = floor(. / (6 2^s)), no divide
        v += a + ((j + 1) >> 1)
        a += j
    return x, v, a


@nb.njit(cache=True, inline="always")
def pixel_of(x: int, fp: int) -> int:
    """Pixel shown for fixed-point position ``x``: ``floor(x + 1/2)`` (symmetric rounding)."""
    return (x + (1 << (fp - 1))) >> fp


@nb.njit(cache=True)
def propagate_points(
    x: np.ndarray, v: np.ndarray, a: np.ndarray, j: np.ndarray, order: int, fp: int, fm: int,
    steps: int,
) -> np.ndarray:
    """Propagate control points ``steps`` refreshes with the galpixel arithmetic.

    Parameters
    ----------
    x : ndarray, shape (N, K), int64
        Fixed-point positions (``2^-fp`` px), K components.
    v, a, j : ndarray, shape (N, K), int64
        Fixed-point motion (``2^-fm``).
    order, fp, fm, steps : int

    Returns
    -------
    ndarray, shape (steps + 1, N, K), int64
        Positions after 0, 1, ..., ``steps`` refreshes.
    """
    n, k = x.shape
    out = np.empty((steps + 1, n, k), np.int64)
    for i in range(n):
        for c in range(k):
            xi, vi, ai = x[i, c], v[i, c], a[i, c]
            out[0, i, c] = xi
            for t in range(steps):
                xi, vi, ai = advance(xi, vi, ai, j[i, c], order, fp, fm)
                out[t + 1, i, c] = xi
    return out


def points_fixed(
    position: np.ndarray, motion: np.ndarray, fixed: FixedPoint, order: int,
    subpixel: bool = False,
) -> tuple[np.ndarray, ...]:
    """Control points as a renderer paints them: pixel-centred, motion quantised.

    Parameters
    ----------
    position : ndarray, shape (N, K)
        Exact positions in px.
    motion : ndarray, shape (3, N, K)
        Velocity, acceleration, jerk in px per refresh^n (orders above ``order``
        are ignored).
    fixed : FixedPoint
    order : int
    subpixel : bool
        Keep the position's fraction (to ``fp`` bits) instead of painting the
        nearest pixel with fraction zero.

    Returns
    -------
    x, v, a, j : ndarray, shape (N, K), int64
        ``x`` is the nearest pixel (fraction zero), as an update paints it.
    """
    pos = np.asarray(position, np.float64)
    if subpixel:
        x = np.floor(pos * 2.0**fixed.fp + 0.5).astype(np.int64)
    else:
        x = (np.floor(pos + 0.5).astype(np.int64)) << fixed.fp
    lims = (fixed.v_max, fixed.a_max, fixed.j_max)
    out = []
    for n in range(3):
        q = fixed.quantise(motion[n], lims[n])[0].astype(np.int64)
        out.append(q if n < order else np.zeros_like(q))
    return (x, *out)


def _to_fixed(
    values: np.ndarray, scale: float, limit: float, inf_to_limit: bool,
    where: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``floor(clip(v) * scale + 1/2)`` as int32, and where ``v`` was non-finite or clamped.

    NaN becomes 0; +-inf becomes +-``limit`` when ``inf_to_limit``, else 0.  Where
    ``where`` (the trailing axes of ``values``) is False, 0 and not flagged.
    """
    v = np.asarray(values)
    if v.dtype.kind != "f":
        v = v.astype(np.float64)
    mask = np.ones(1, np.bool_) if where is None else np.asarray(where, np.bool_)
    if where is not None and mask.shape != v.shape[v.ndim - mask.ndim:]:
        raise ValueError(f"where has shape {mask.shape}, values {v.shape}")
    flat = np.ascontiguousarray(v).reshape(-1)
    out = np.empty(flat.shape, np.int32)
    bad = np.empty(flat.shape, np.bool_)
    _fixed_kernel(flat, np.ascontiguousarray(mask).reshape(-1), scale, limit, inf_to_limit,
                  out, bad)
    return out.reshape(v.shape), bad.reshape(v.shape)


@nb.njit(cache=True, nogil=True, parallel=True)
def _fixed_kernel(
    v: np.ndarray, mask: np.ndarray, scale: float, limit: float, inf_to_limit: bool,
    out: np.ndarray, bad: np.ndarray,
) -> None:
    """:func:`_to_fixed` on flat (N,) arrays, in float64 as numpy would.

    ``mask`` (M,) repeats along ``v`` (M divides N; M = 1 with True: no mask).
    """
    m = mask.size
    if m == 1:  # one flag for every value
        for i in nb.prange(v.size):
            out[i], bad[i] = _fixed_value(np.float64(v[i]) if mask[0] else 0.0, scale, limit,
                                          inf_to_limit)
        return
    for rep in range(v.size // m):  # one contiguous run of m values per repeat
        vr, o, b = v[rep * m : (rep + 1) * m], out[rep * m : (rep + 1) * m], bad[rep * m :]
        for j in nb.prange(m):
            x = np.float64(vr[j])
            o[j], b[j] = _fixed_value(x if mask[j] else 0.0, scale, limit, inf_to_limit)


@nb.njit(cache=True, nogil=True, inline="always")
def _fixed_value(x: float, scale: float, limit: float, inf_to_limit: bool) -> tuple:
    """One value of :func:`_to_fixed`: (int32 fixed point, flagged)."""
    b = False
    if np.isnan(x):
        x, b = 0.0, True
    elif np.isinf(x):
        x, b = (limit if x > 0 else -limit) if inf_to_limit else 0.0, True
    elif abs(x) > limit:
        x, b = min(max(x, -limit), limit), True
    return np.int32(np.floor(x * scale + 0.5)), b


@nb.njit(cache=True, nogil=True, parallel=True)
def _depth_kernel(d: np.ndarray, scale: float, out: np.ndarray, bad: np.ndarray) -> None:
    """:meth:`FixedPoint.depth_fixed` on flat (N,) arrays."""
    for i in nb.prange(d.size):
        x = np.float64(d[i])
        if np.isnan(x) or x == np.inf:
            out[i], bad[i] = Z_EMPTY, False
            continue
        q = np.floor(x * scale + 0.5)
        bad[i] = abs(q) > Z_LIMIT
        out[i] = np.int32(min(max(q, -Z_LIMIT), Z_LIMIT))
