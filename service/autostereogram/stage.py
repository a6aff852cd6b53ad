"""The autostereogram stage: depth map in, SIRD image and its counts out.

:func:`stereogram` picks the method's kernel from :data:`METHODS`, runs it over
preallocated buffers (:class:`SirdWorkspace`, reused frame after frame so a refresh
allocates nothing) and checks the result's counts; :func:`broken_constraints`
verifies a drawn image against its own constraints (tests and ``--json``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numba as nb
import numpy as np

from service.autostereogram.geometry import SirdSettings
from service.autostereogram.interpolated import interpolated_kernel
from service.autostereogram.row import row_kernel
from service.autostereogram.tiw import tiw_kernel
from service.base.errors import SettingsError

#: Rows per chunk of the kernels' parallel loops, asked of numba around the call (a
#: kernel that sets it itself cannot be cached).  Where the threading layer hands
#: chunks out as threads come free, a thread that another process stalls leaves the
#: rest of the frame to the others.  Measured 2026-11-25 with numba 0.68.1 on the
#: omp and workqueue layers (the pip wheels' layers; TBB not installed): no effect,
#: a 16-iteration ``prange`` ran iterations 0-7 on one thread and 8-15 on the other
#: at chunk sizes 0, 1 and 8 alike, the costlier first half included.
ROW_CHUNK = 8


class SirdWorkspace:
    """Buffers of one image size and channel count, reused across frames.

    Attributes
    ----------
    out : ndarray, shape (H, W, C), uint8
        The last stereogram.
    flat : ndarray, shape (H, W * C), uint8
        The same pixels, one flat row per image row (what the kernels write).
    sep : ndarray, shape (H, W), int32
        ``row``'s separations or ``tiw``'s links (``same[]``, when kept).
    heights : ndarray, shape (threads, W), float32
        ``tiw``'s per-thread row of heights.
    scratch : ndarray, shape (threads, 3, W), int32
        Per-thread rows: ``tiw``'s separations, where to search for occluders and the
        spans steep steps reach; ``interpolated``'s separations and partners.
    edges : ndarray, shape (threads, W rounded up to 8), uint8
        ``tiw``'s per-thread row of steep steps.
    counts : ndarray, shape (H, 3), int64
        Per row: constraints, hidden points, NaN depths.
    keep_links : bool
        Whether ``tiw`` keeps its links in :attr:`sep` (for :func:`broken_constraints`);
        without, it links each row in :attr:`thread_links`, a per-thread row that
        stays in cache (the service's choice).
    """

    def __init__(self, rows: int, cols: int, channels: int, keep_links: bool = True) -> None:
        self.out = np.zeros((rows, cols, channels), np.uint8)
        self.flat = self.out.reshape(rows, cols * channels)
        self.sep = np.zeros((rows, cols), np.int32)
        threads = nb.config.NUMBA_NUM_THREADS  # numba.get_thread_id() stays below it
        self.heights = np.zeros((threads, cols), np.float32)
        self.scratch = np.zeros((threads, 3, cols), np.int32)
        self.edges = np.zeros((threads, (cols + 7) // 8 * 8), np.uint8)
        self.keep_links = keep_links
        self.thread_links = np.zeros((threads, cols), np.int32)
        self.counts = np.zeros((rows, 3), np.int64)

    def fresh_output(self) -> None:
        """Give :attr:`out` a new array (the old one may still be in use elsewhere)."""
        self.out = np.empty_like(self.out)
        self.flat = self.out.reshape(self.out.shape[0], -1)

    def fits(self, rows: int, cols: int, channels: int) -> bool:
        """Whether the buffers have this shape."""
        return self.out.shape == (rows, cols, channels)


@dataclass(frozen=True)
class SirdStats:
    """Counts of one stereogram.

    Attributes
    ----------
    method : str
    constraints : int
        Pixel pairs made equal (``row``: every copied pixel; ``tiw``: visible in-row pairs).
    hidden : int
        Points dropped by hidden-surface removal (``tiw`` only; 0 otherwise).
    separation_px : tuple of 2 ints
        ``(s(1), s(0))``, the nearest and farthest separations.
    """

    method: str
    constraints: int
    hidden: int
    separation_px: tuple[int, int]


def _run_row(depth, args, pattern, work):
    row_kernel(depth, *args, pattern, work.flat, work.sep, work.counts)


def _run_interpolated(depth, args, pattern, work):
    interpolated_kernel(depth, *args, pattern, work.flat, work.scratch, work.counts)


def _run_tiw(depth, args, pattern, work):
    links = work.sep if work.keep_links else work.thread_links
    tiw_kernel(depth, *args, pattern, work.flat, links, work.keep_links, work.heights,
               work.scratch, work.edges, work.counts)


#: Method name -> runner (depth, kernel args, pattern, workspace).
METHODS: dict[str, Callable] = {
    "row": _run_row, "interpolated": _run_interpolated, "tiw": _run_tiw,
}


def check_pattern(pattern: np.ndarray) -> np.ndarray:
    """A (Hp, Wp, 1|3) uint8 C-contiguous pattern, or :class:`SettingsError`."""
    p = np.asarray(pattern)
    if p.dtype != np.uint8 or p.ndim != 3 or p.shape[2] not in (1, 3) or 0 in p.shape:
        raise SettingsError(f"pattern must be (Hp, Wp, 1|3) uint8, got {p.shape} {p.dtype}")
    return np.ascontiguousarray(p)


def stereogram(depth: np.ndarray, settings: SirdSettings, pattern: np.ndarray,
               work: SirdWorkspace | None = None) -> tuple[np.ndarray, SirdStats]:
    """A single-image random-dot stereogram of a depth map.

    Parameters
    ----------
    depth : ndarray, shape (H, W), float
        Distance behind the display plane, ``+inf`` where empty; converted to float32.
    settings : SirdSettings
    pattern : ndarray, shape (Hp, Wp, C), uint8
        C = 1 or 3 (:mod:`service.autostereogram.patterns`); Wp should be ``s(0)``.
    work : SirdWorkspace, optional
        Buffers to reuse; a fitting one is used as is, else a new one is made.

    Returns
    -------
    image : ndarray, shape (H, W, C), uint8
        ``work.out`` (overwritten by the next call with the same workspace).
    stats : SirdStats

    Raises
    ------
    SettingsError
        Unknown method, bad pattern, an image too narrow to fuse, or NaN depth.
    """
    if settings.method not in METHODS:
        raise SettingsError(f"method must be one of {sorted(METHODS)}, got {settings.method!r}")
    d = np.asarray(depth, np.float32)
    if d.ndim != 2 or d.shape[0] < 1:
        raise SettingsError(f"depth map must be a non-empty (H, W) array, got {d.shape}")
    settings.check_width(d.shape[1])
    pattern = check_pattern(pattern)
    if work is None or not work.fits(d.shape[0], d.shape[1], pattern.shape[2]):
        work = SirdWorkspace(d.shape[0], d.shape[1], pattern.shape[2])
    args = (float(settings.far), 1.0 / (settings.far - settings.near),
            float(settings.eye_sep), float(settings.mu))
    before = nb.set_parallel_chunksize(ROW_CHUNK)
    try:
        METHODS[settings.method](np.ascontiguousarray(d), args, pattern, work)
    finally:
        nb.set_parallel_chunksize(before)
    totals = work.counts.sum(axis=0)
    if totals[2]:
        raise SettingsError(f"depth map holds {int(totals[2])} NaN values")
    stats = SirdStats(settings.method, int(totals[0]), int(totals[1]),
                      (settings.min_sep, settings.max_sep))
    return work.out, stats


@nb.njit(cache=True)
def _broken_pairs(image: np.ndarray, partner: np.ndarray) -> int:
    """Pixels whose colour differs from their partner's (``partner[y, x] == x``: none)."""
    h, w, nc = image.shape
    n = 0
    for y in range(h):
        for x in range(w):
            k = partner[y, x]
            if k == x or k < 0 or k >= w:
                continue
            for c in range(nc):
                if image[y, x, c] != image[y, k, c]:
                    n += 1
                    break
    return n


def broken_constraints(image: np.ndarray, settings: SirdSettings, work: SirdWorkspace) -> int:
    """Constraints the last :func:`stereogram` with ``work`` does not keep.

    ``tiw``: every ``same[]`` link; ``row``: every ``out[x] == out[x + s(x)]`` of the
    second loop.  ``interpolated`` keeps blends, not equalities: its interpolated
    copies are recomputed by its own kernel, so 0 is reported.
    """
    if settings.method == "interpolated":
        return 0
    if settings.method == "tiw" and not work.keep_links:
        raise SettingsError("tiw's links were not kept (SirdWorkspace keep_links=False)")
    if settings.method == "tiw":
        return int(_broken_pairs(image, work.sep))
    w = image.shape[1]
    cols = np.arange(w, dtype=np.int32)
    partner = np.where(cols < w - settings.max_sep, cols + work.sep, cols).astype(np.int32)
    return int(_broken_pairs(image, partner))
