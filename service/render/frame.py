"""Stage 6: the frame (colour + depth per view zone) and its image layouts and writers.

Layouts
-------
``zones``
    One PNG per zone (``zone-00.png`` ...) and its depth as ``depth-00.npy``
    (float32, +inf where empty).
``strip``
    Zones side by side on one row of images, zone 0 (the leftmost viewer) leftmost,
    optionally with a separator of ``sep`` pixels between them.
``quilt``
    The Looking Glass layout: a grid of ``cols x rows`` tiles, view 0 in the
    bottom-left tile, then left to right along the bottom row, then upward row by
    row; unused tiles are black.  Zone 0 is the leftmost viewer position, as
    Looking Glass's view 0 is its leftmost camera.  The file is named
    ``quilt_qs{cols}x{rows}a{aspect}.png`` (see :func:`quilt_name`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from service.base.errors import SettingsError
from service.png import write_png


@dataclass
class Frame:
    """One rendered frame for every view zone.

    Attributes
    ----------
    colour : ndarray, shape (Z, R, C, 3), uint8
    depth : ndarray, shape (Z, R, C), float32
        Depth (-z) of the visible surface, +inf where empty.
    settings : dict
        The settings the frame was rendered with (for records and benchmarks).
    stats : dict
        Per-stage counters and timings.
    """

    colour: np.ndarray
    depth: np.ndarray
    settings: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        c, d = np.asarray(self.colour), np.asarray(self.depth)
        if c.ndim != 4 or c.shape[3] != 3 or c.dtype != np.uint8:
            raise SettingsError(f"frame colour must be (Z, R, C, 3) uint8, got {c.shape} {c.dtype}")
        if d.shape != c.shape[:3]:
            raise SettingsError(f"frame depth must be {c.shape[:3]}, got {d.shape}")
        self.colour = c
        self.depth = d.astype(np.float32, copy=False)

    @property
    def zones(self) -> int:
        """Number of view zones Z."""
        return int(self.colour.shape[0])


def write_zones(frame: Frame, out_dir: str | Path) -> list[Path]:
    """Write ``zone-NN.png`` and ``depth-NN.npy`` for every zone.

    Parameters
    ----------
    frame : Frame
    out_dir : str or Path
        Created if missing.

    Returns
    -------
    list of Path
        The files written, PNG and depth for zone 0, then zone 1, ...
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for z in range(frame.zones):
        paths.append(write_png(out / f"zone-{z:02d}.png", frame.colour[z]))
        dpath = out / f"depth-{z:02d}.npy"
        np.save(dpath, np.ascontiguousarray(frame.depth[z], np.float32), allow_pickle=False)
        paths.append(dpath)
    return paths


def view_strip(colour: np.ndarray, sep: int = 0, sep_value: int = 0) -> np.ndarray:
    """Zones side by side, zone 0 leftmost.

    Parameters
    ----------
    colour : ndarray, shape (Z, R, C, 3) or (Z, R, C)
    sep : int
        Separator width in pixels between zones (0 for none).
    sep_value : int
        Grey level of the separator.

    Returns
    -------
    ndarray, shape (R, Z * C + (Z - 1) * sep[, 3]), same dtype
    """
    z, r, c = colour.shape[:3]
    out = np.full((r, z * c + (z - 1) * sep, *colour.shape[3:]), sep_value, colour.dtype)
    for k in range(z):
        x0 = k * (c + sep)
        out[:, x0 : x0 + c] = colour[k]
    return out


def write_strip(frame: Frame, path: str | Path, sep: int = 2) -> Path:
    """Write :func:`view_strip` of the frame's colour as a PNG; returns the path."""
    return write_png(path, view_strip(frame.colour, sep))


def default_grid(n: int) -> tuple[int, int]:
    """A quilt grid (cols, rows) for ``n`` views.

    Among grids no more than twice as wide as tall (or tall as wide) that hold ``n``
    tiles, pick the fewest unused tiles, then the squarest, then the wider.  This
    gives Looking Glass Portrait's 8 x 6 for 48 views, 3 x 2 for 5 and 1 x 1 for 1.
    (Pass cols and rows explicitly for other devices' layouts, e.g. 5 x 9.)

    Raises
    ------
    SettingsError
        If ``n`` < 1.
    """
    if n < 1:
        raise SettingsError(f"a quilt needs at least one view, got {n}")

    def score(cr: tuple[int, int]) -> tuple[int, int, int]:
        cols, rows = cr
        return cols * rows - n, abs(cols - rows), -cols

    grids = [(-(-n // rows), rows) for rows in range(1, n + 1)]
    grids += [(rows, cols) for cols, rows in grids]
    fit = [g for g in grids if g[0] * g[1] >= n and max(g) <= 2 * min(g)]
    return min(fit, key=score)


def quilt(colour: np.ndarray, cols: int, rows: int) -> np.ndarray:
    """Arrange views in the Looking Glass quilt layout.

    Parameters
    ----------
    colour : ndarray, shape (N, R, C, 3) or (N, R, C)
        View 0 first.
    cols, rows : int
        Tiles across and down; ``cols * rows >= N``.

    Returns
    -------
    ndarray, shape (rows * R, cols * C[, 3]), same dtype
        View ``i`` in tile column ``i % cols`` and tile row ``i // cols`` counted
        from the bottom; unused tiles are zero (black).

    Raises
    ------
    SettingsError
        If the grid has fewer tiles than views.
    """
    n, r, c = colour.shape[:3]
    if cols < 1 or rows < 1 or cols * rows < n:
        raise SettingsError(f"a {cols}x{rows} quilt cannot hold {n} views")
    out = np.zeros((rows * r, cols * c, *colour.shape[3:]), colour.dtype)
    for i in range(n):
        y0 = (rows - 1 - i // cols) * r
        x0 = (i % cols) * c
        out[y0 : y0 + r, x0 : x0 + c] = colour[i]
    return out


def format_aspect(aspect: float) -> str:
    """Aspect ratio as Looking Glass file names write it.

    Rounded to 3 decimals (round half to even, as Python's ``format``), trailing
    zeros dropped but one decimal kept: 0.75 -> ``"0.75"``, 4/3 -> ``"1.333"``,
    16/9 -> ``"1.778"``, 1 -> ``"1.0"``.
    """
    text = f"{aspect:.3f}".rstrip("0")
    return text + "0" if text.endswith(".") else text


def quilt_name(cols: int, rows: int, view_cols: int, view_rows: int, prefix: str = "quilt") -> str:
    """File name ``{prefix}_qs{cols}x{rows}a{aspect}.png``; aspect = view_cols / view_rows."""
    return f"{prefix}_qs{cols}x{rows}a{format_aspect(view_cols / view_rows)}.png"


def write_quilt(
    frame: Frame, out_dir: str | Path, cols: int | None = None, rows: int | None = None
) -> Path:
    """Write the frame's zones as a Looking Glass quilt PNG.

    Parameters
    ----------
    frame : Frame
    out_dir : str or Path
        Created if missing.
    cols, rows : int, optional
        Grid; :func:`default_grid` when either is missing.

    Returns
    -------
    Path
        ``out_dir / quilt_qs{cols}x{rows}a{aspect}.png``.
    """
    if cols is None or rows is None:
        cols, rows = default_grid(frame.zones)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    _, r, c = frame.colour.shape[:3]
    return write_png(out / quilt_name(cols, rows, c, r), quilt(frame.colour, cols, rows))


def depth_grey(
    depth: np.ndarray, near: float | None = None, far: float | None = None
) -> np.ndarray:
    """Depth as a greyscale picture: nearer is brighter, empty (+inf) is black.

    Finite depths map linearly from ``near`` (255) to ``far`` (48), clipped, so the
    farthest surface stays distinguishable from empty black.

    Parameters
    ----------
    depth : ndarray, any shape, float
    near, far : float, optional
        Default: the smallest and largest finite depth present.

    Returns
    -------
    ndarray, same shape, uint8
    """
    d = np.asarray(depth, np.float64)
    finite = np.isfinite(d)
    if not finite.any():
        return np.zeros(d.shape, np.uint8)
    lo = float(d[finite].min()) if near is None else float(near)
    hi = float(d[finite].max()) if far is None else float(far)
    t = np.clip((d - lo) / (hi - lo), 0.0, 1.0) if hi > lo else np.zeros(d.shape)
    grey = np.rint(255.0 - t * (255.0 - 48.0))
    return np.where(finite, grey, 0).astype(np.uint8)
