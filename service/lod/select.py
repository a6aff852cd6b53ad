"""Per frame, the coarsest level of each object within the error budget (and the time budget)."""

from __future__ import annotations

import numpy as np

from service.display import DisplaySettings
from service.lod.settings import COLOUR_ANGLES, COLOUR_LEVELS


def pixels_per_unit(display: DisplaySettings) -> float:
    """Largest pixels per world unit of any zone's parallel projection (see module doc).

    Zone ``k`` maps a displacement ``d`` to ``(d_x - d_z t_k, d_y) / s``; its largest
    stretch is ``sqrt(1 + t_k^2) / s``, the same at every depth.
    """
    t = float(np.abs(display.shears()).max()) if display.zones else 0.0
    return float(np.sqrt(1.0 + t * t) / display.pixel_size)


def select_levels(
    errors: np.ndarray,
    ppu: np.ndarray | float,
    error_px: float,
    previous: np.ndarray | None = None,
    hysteresis: float = 0.25,
) -> tuple[np.ndarray, np.ndarray]:
    """Each object's level: the cheapest (last) whose predicted error is within budget.

    Levels are ordered by cost, dearest (the full mesh) first; their errors need not
    grow with the index.

    Parameters
    ----------
    errors : ndarray, shape (N, L), float64
        Geometric error of each object's levels in world units (mesh error x scale),
        ``errors[:, 0] == 0``; ``inf`` past a chain's end.
    ppu : float or ndarray, shape (N,)
        Pixels per world unit for each object.
    error_px : float
    previous : ndarray, shape (N,), int64, optional
        Last frame's levels (-1: none) for the hysteresis.
    hysteresis : float

    Returns
    -------
    level : ndarray, shape (N,), int64
    predicted : ndarray, shape (N,), float64
        Predicted screen error of the chosen level, pixels.
    """
    pred = errors * np.asarray(ppu, np.float64).reshape(-1, 1)
    n, width = pred.shape
    rows = np.arange(n)
    # the cheapest (last) level within the bound; level 0 (error 0) always is.  An
    # object with a level already coarsens only under the stricter bound; a new one
    # (no previous level) has nothing to flicker from and takes the whole budget
    fresh = np.ones(n, np.bool_) if previous is None else np.asarray(previous) < 0
    bound = np.where(fresh, error_px, error_px * (1.0 - hysteresis))
    within = pred <= bound[:, None]
    level = width - 1 - np.argmax(within[:, ::-1], axis=1)
    if previous is not None:
        prev = np.clip(previous, 0, pred.shape[1] - 1)
        keep = ~fresh & (prev > level) & (pred[rows, prev] <= error_px)
        level = np.where(keep, prev, level)
    return level.astype(np.int64), pred[rows, level]


def colour_angle(colours: np.ndarray, diffuse: np.ndarray, light: np.ndarray) -> np.ndarray:
    """Radians each object's light normal may turn before its colour may change.

    A change is :data:`COLOUR_LEVELS` levels in a channel.
    A diffuse channel ``rgb_c k_d sum_j E_j,c max(0, N.L_j)`` changes by at most
    ``rgb_c k_d sum_j E_j,c`` per radian the normal turns, so the angle is
    ``COLOUR_LEVELS / 255`` over the largest such gain (the specular term is left out).

    Parameters
    ----------
    colours : ndarray, shape (N, 3)
        Each object's material colour.
    diffuse : ndarray, shape (N,)
        Its ``k_d``.
    light : ndarray, shape (3,)
        The scene's lights' colours times intensities, summed.

    Returns
    -------
    ndarray, shape (N,), float64
        ``inf`` where the gain is 0 (no diffuse light: no normal changes a colour).
    """
    gain = (np.asarray(colours, np.float64) * np.asarray(light, np.float64)).max(axis=1)
    gain = gain * np.asarray(diffuse, np.float64)
    with np.errstate(divide="ignore"):
        return np.where(gain > 0, (COLOUR_LEVELS / 255.0) / np.maximum(gain, 1e-300), np.inf)


def share_at(turned: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Each object's turned share per level at its own angle (linear between the table's).

    Parameters
    ----------
    turned : ndarray, shape (N, L, A)
        Shares at :data:`COLOUR_ANGLES` (one light evaluation's column of
        :attr:`service.lod.chain.LodChain.turned`).
    angle : ndarray, shape (N,)
        Radians (:func:`colour_angle`); below the first angle the first share is
        used, past the last the share is 0.

    Returns
    -------
    ndarray, shape (N, L)
    """
    deg = np.degrees(np.asarray(angle, np.float64))
    grid = np.asarray(COLOUR_ANGLES)
    pos = np.interp(deg, grid, np.arange(grid.size, dtype=np.float64))
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, grid.size - 1)
    w = (pos - lo)[:, None]
    rows = np.arange(turned.shape[0])
    out = turned[rows, :, lo] * (1.0 - w) + turned[rows, :, hi] * w
    return np.where((deg > grid[-1])[:, None], 0.0, out)


def colour_pixels(share: np.ndarray, area: np.ndarray, ppu: float) -> np.ndarray:
    """Pixels per zone predicted to change colour at each level of each object.

    An object's pixels per zone are taken as its surface area over 4 (a convex body's
    mean projected area, Cauchy), in pixels: more than a non-convex or hidden object
    shows, so the prediction errs high.

    Parameters
    ----------
    share : ndarray, shape (N, L), float64
        Share of each object's surface whose light normal turns past the colour angle
        at each level (:meth:`service.lod.chain.LodChain.colour_share`).
    area : ndarray, shape (N,), float64
        Each object's surface area in world units squared (mesh area x scale^2).
    ppu : float
        Pixels per world unit.

    Returns
    -------
    ndarray, shape (N, L), float64
    """
    return share * (area * ppu * ppu / 4.0)[:, None]


def limit_colour(level: np.ndarray, colour_px: np.ndarray, triangles: np.ndarray,
                 budget_px: float) -> np.ndarray:
    """Step objects to finer levels until the predicted colour change is within budget.

    Each round steps one level finer the objects that save the most colour pixels
    per triangle added, as few as cover the excess; a finer level never has more
    geometric error (the mesh levels' errors grow along the chain), so the error
    budget still holds.

    Parameters
    ----------
    level : ndarray, shape (N,), int64
        Levels chosen by the error budget.
    colour_px : ndarray, shape (N, L), float64
        :func:`colour_pixels`.
    triangles : ndarray, shape (N, L), int64
    budget_px : float
        Most pixels per zone predicted to change colour, all objects together.

    Returns
    -------
    ndarray, shape (N,), int64
    """
    level = level.copy()
    rows = np.arange(level.size)
    for _ in range(colour_px.shape[1]):
        now = colour_px[rows, level]
        excess = now.sum() - budget_px
        if excess <= 0:
            break
        finer = np.maximum(level - 1, 0)
        saving = now - colour_px[rows, finer]
        added = np.maximum(triangles[rows, finer] - triangles[rows, level], 1)
        order = np.argsort(-saving / added, kind="stable")
        order = order[saving[order] > 0]
        if order.size == 0:
            break
        need = np.searchsorted(np.cumsum(saving[order]), excess) + 1
        step = order[:need]
        level[step] = finer[step]
    return level


def degrade_to_budget(
    level: np.ndarray, triangles: np.ndarray, priority: np.ndarray, max_triangles: float,
    last: np.ndarray | None = None,
) -> np.ndarray:
    """Step objects to coarser levels, lowest ``priority`` first, until under a budget.

    Parameters
    ----------
    level : ndarray, shape (N,), int64
    triangles : ndarray, shape (N, L), int64
        Triangles of each object's levels; a chain's end repeats its last level.
    priority : ndarray, shape (N,)
        Lower is degraded first (small on screen, far).
    max_triangles : float
    last : ndarray, shape (N,), int64, optional
        Each object's coarsest allowed level (default the table's last column).

    Returns
    -------
    ndarray, shape (N,), int64
    """
    level = level.copy()
    rows = np.arange(level.size)
    last = np.full(level.size, triangles.shape[1] - 1) if last is None else last
    order = np.argsort(priority, kind="stable")
    for _ in range(triangles.shape[1]):
        total = triangles[rows, level].sum()
        if total <= max_triangles:
            break
        nxt = np.maximum(np.minimum(level + 1, last), level)
        saving = (triangles[rows, level] - triangles[rows, nxt])[order]
        need = np.searchsorted(np.cumsum(saving), total - max_triangles) + 1
        step = order[: min(need, order.size)]
        level[step] = nxt[step]
    return level
