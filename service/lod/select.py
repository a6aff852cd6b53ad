"""Per frame, the coarsest level of each object within the error budget (and the time budget)."""

from __future__ import annotations

import numpy as np

from service.display import DisplaySettings


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
